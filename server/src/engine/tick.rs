//! One tick: apply the queued edits on the workers, commit them (one
//! group commit, applying the next batch meanwhile when it is due), then
//! acknowledge, broadcast, stream snapshots and evict.

use std::collections::HashSet;
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use strata_protocol::{ChunkVersion, ErrorCode, ServerMessage};
use strata_terrain::ChunkPos;
use tracing::{error, info, warn};

use super::{fanout, now_ms, Engine, Inbox, SLOW_TICK_PERIODS};
use crate::metrics as m;
use crate::sequencer::{BuiltMeshes, PendingMeshes};

impl Engine {
    /// One tick: apply, commit, acknowledge, broadcast, stream. While the
    /// commit runs, safe commands from `rx` are served, and once the next
    /// tick is due the next batch is applied meanwhile (see
    /// [`MAX_CHAINED_COMMITS`]); its commit follows at once. Streaming and
    /// eviction run only after the last, when the world equals the store.
    pub(super) fn tick(&mut self, rx: Option<&Inbox>) -> anyhow::Result<()> {
        let started = Instant::now();
        let period = self.tick_period();
        let mut phase = Phases::new();
        self.follow_leases()?;
        let mut applied = self.apply_tick();
        phase.end("apply");
        if applied.out.lanes > 0 {
            phase.apply = applied.out.split;
        }
        // Cluster nodes never apply ahead: a fenced commit puts its chunks
        // back from the store, which a batch applied on top would undo.
        let chain = rx.is_some() && !self.store.clustered();
        let mut chained = 0;
        loop {
            let due = (chain && chained < MAX_CHAINED_COMMITS).then(|| applied.at + period);
            match self.commit_and_answer(applied, rx, due, &mut phase)? {
                Some(next) => {
                    metrics::counter!(m::TICKS_APPLIED_AHEAD).increment(1);
                    applied = next;
                    chained += 1;
                }
                None => break,
            }
        }
        self.stream_snapshots();
        phase.end("stream");
        self.evict_cold();
        self.drop_failed();
        phase.end("evict");
        let took = started.elapsed();
        metrics::histogram!(m::TICK_SECONDS).record(took.as_secs_f64());
        if took > period * (SLOW_TICK_PERIODS as u32) * (chained + 1) {
            warn!(ms = took.as_millis() as u64, phases = %phase.describe(), "slow tick");
        }
        Ok(())
    }

    /// The time between two ticks' starts.
    pub(super) fn tick_period(&self) -> Duration {
        Duration::from_millis(self.cfg.tick_ms.max(1))
    }

    /// Checks the sight of the edits still waiting for it, then applies the
    /// queued edits on the workers and starts their meshes; refusals are
    /// answered at once.
    pub(super) fn apply_tick(&mut self) -> Applied {
        let at = Instant::now();
        self.check_sighted();
        let pool = self.pool.clone();
        let idle = self.seq.queued() == 0;
        let seq = &mut self.seq;
        // Collision meshes build on the workers while the batch commits,
        // spawned while the workers are awake from applying it. An empty
        // queue leaves them asleep: an idle server's ticks touch no other
        // thread.
        let asked = Instant::now();
        let mut apply = || {
            let began = Instant::now();
            let (mut out, pending) = seq.tick_apply(now_ms());
            out.split.wait = began - asked;
            metrics::counter!(m::COLLISION_MESHES, "kind" => "changed")
                .increment(pending.changed() as u64);
            metrics::counter!(m::COLLISION_MESHES, "kind" => "rewarm")
                .increment(pending.rewarmed() as u64);
            (out, spawn_meshing(&pool, pending))
        };
        let (mut out, meshing) = if idle { apply() } else { pool.install(apply) };
        // The epochs the world was built under, before anything reloads.
        out.batch.epochs = self.batch_epochs(&out.batch);
        if out.lanes > 0 {
            let s = &out.split;
            for (part, d) in [
                ("wait", s.wait),
                ("prepare", s.prepare),
                ("lanes", s.lanes),
                ("merge", s.merge),
            ] {
                metrics::histogram!(m::APPLY_PART_SECONDS, "part" => part).record(d.as_secs_f64());
            }
        }
        metrics::counter!(m::COLLISION_MESHES, "kind" => "on_demand")
            .absolute(self.seq.collision().built_on_demand());
        let rewarms = self.seq.collision().rewarm_outcomes();
        metrics::counter!(m::COLLISION_REWARMS, "outcome" => "used").absolute(rewarms.used);
        metrics::counter!(m::COLLISION_REWARMS, "outcome" => "wasted").absolute(rewarms.wasted);
        for r in &out.rejected {
            metrics::counter!(m::EDITS_REJECTED, "reason" => m::reject_label(&r.reason))
                .increment(1);
            let msg = ServerMessage::EditRejected {
                client_edit_id: r.client_edit_id,
                reason: r.reason.clone(),
            };
            self.send_control(r.session_id, &msg);
        }
        Applied { out, meshing, at }
    }

    /// Commits `applied`, then acknowledges and broadcasts it. Returns the
    /// next tick if it was applied while this one committed (only once
    /// `due`, and never without `rx`).
    fn commit_and_answer(
        &mut self,
        applied: Applied,
        rx: Option<&Inbox>,
        due: Option<Instant>,
        phase: &mut Phases,
    ) -> anyhow::Result<Option<Applied>> {
        let Applied {
            mut out, meshing, ..
        } = applied;
        if out.batch.is_empty() {
            return Ok(None);
        }
        metrics::histogram!(m::TICK_LANES).record(out.lanes as f64);
        // After the previous batch is durable: pre-images are read from
        // the store.
        self.capture_preimages(&out.batch);
        let flush = Instant::now();
        // Nothing is acknowledged or broadcast unless this succeeds.
        let (batch, committed, next) = self.commit_serving(std::mem::take(&mut out.batch), rx, due);
        self.store_answered(&committed);
        out.batch = batch;
        let stats = match committed {
            Ok(stats) => stats,
            // A region lost mid-flight: the batch is abandoned, the node
            // goes on (cluster nodes apply nothing ahead).
            Err(e) if self.abandon_fenced(&out, &e) => {
                let _ = super::pool::help_until(&meshing);
                phase.end("commit");
                return Ok(next);
            }
            Err(e) => {
                error!(error = %e, "group commit failed; stopping without acknowledging");
                self.close_all();
                return Err(e.into());
            }
        };
        self.durable_seq = out.batch.last_seq;
        metrics::histogram!(m::FLUSH_SECONDS).record(flush.elapsed().as_secs_f64());
        metrics::histogram!(m::FSYNC_SECONDS).record(stats.fsync.as_secs_f64());
        metrics::counter!(m::STORE_BYTES, "kind" => "commit").increment(stats.bytes_written);
        phase.end("commit");
        phase.commit = Some((stats, out.batch.chunks.len()));
        let built = super::pool::help_until(&meshing)
            .map_err(|_| anyhow::anyhow!("collision meshing task panicked"))?;
        phase.end("mesh_wait");
        metrics::counter!(m::MESH_LAYERS, "how" => "meshed").increment(built.layers.meshed);
        metrics::counter!(m::MESH_LAYERS, "how" => "reused").increment(built.layers.reused);
        metrics::counter!(m::MESH_NEIGHBOURHOODS, "copied" => "layers")
            .increment(built.layers.partial_copies);
        metrics::counter!(m::MESH_NEIGHBOURHOODS, "copied" => "whole")
            .increment(built.layers.whole_copies);
        let ahead: HashSet<ChunkPos> = next
            .iter()
            .flat_map(|n| n.out.applied.iter())
            .flat_map(|a| a.changes.iter().map(|c| c.pos))
            .collect();
        self.seq.finish_tick(&mut out, built, &ahead);
        // Only raised: a cluster node may have reloaded a region past this
        // batch while it committed (another node wrote on after it).
        for e in &out.batch.entries {
            for &(pos, v) in &e.changes {
                let held = self.versions.entry(pos).or_insert(v);
                *held = (*held).max(v);
            }
        }
        for a in &out.applied {
            metrics::counter!(m::EDITS_ACCEPTED).increment(1);
            metrics::histogram!(m::EDIT_LATENCY_SECONDS)
                .record(a.queued_at.elapsed().as_secs_f64());
            let msg = ServerMessage::EditAccepted {
                client_edit_id: a.client_edit_id,
                seq: a.seq,
                changes: a
                    .changes
                    .iter()
                    .map(|c| ChunkVersion {
                        pos: c.pos,
                        version: c.to_version,
                    })
                    .collect(),
            };
            self.send_control(a.session_id, &msg);
        }
        phase.end("finish");
        let last_seq = out.batch.last_seq;
        if fanout::on_workers(self.peers.len()) {
            let pool = self.pool.clone();
            let (peers, holders) = (&mut self.peers, &mut self.holders);
            pool.install(|| fanout::broadcast(peers, holders, &out.applied, last_seq));
        } else {
            fanout::broadcast(&mut self.peers, &mut self.holders, &out.applied, last_seq);
        }
        phase.end("fanout");
        Ok(next)
    }

    fn drop_failed(&mut self) {
        let failed: Vec<u64> = self
            .peers
            .iter()
            .filter(|(_, p)| p.failed)
            .map(|(id, _)| *id)
            .collect();
        for id in failed {
            info!(session = id, "dropping a session whose queues overflowed");
            let why = "client too slow: a queue of its outgoing frames overflowed";
            self.end_session(id, ErrorCode::Internal, why);
        }
    }
}

/// Batches one `tick` may apply ahead (each while the one before it
/// commits) after its first, so at most this plus one commits back to back
/// before it streams snapshots and evicts (which need the world to equal
/// the store). An overloaded engine so keeps its workers busy during the
/// fsync and still streams every few commits.
pub const MAX_CHAINED_COMMITS: u32 = 3;

/// A tick applied (world changed, meshes building) but not yet durable.
pub(crate) struct Applied {
    out: crate::sequencer::TickOutput,
    meshing: Receiver<BuiltMeshes>,
    /// When it was applied: the next is due a tick period later.
    at: Instant,
}

/// Builds a tick's collision meshes on the workers (no jobs: at once,
/// here); the receiver yields them once done.
fn spawn_meshing(pool: &rayon::ThreadPool, pending: PendingMeshes) -> Receiver<BuiltMeshes> {
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    if pending.is_empty() {
        let _ = tx.send(pending.build());
    } else {
        // A panic would abort the process inside a spawned job: caught, it
        // drops `tx`, and the engine stops cleanly on the closed channel.
        // First in, first out: a tick applied ahead does not build before
        // the one waited for.
        pool.spawn_fifo(move || {
            let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| pending.build()));
            if let Ok(built) = built {
                let _ = tx.send(built);
            }
        });
    }
    rx
}

/// Times the phases of a tick into [`m::TICK_PHASE_SECONDS`], keeping
/// them for the slow-tick warning.
struct Phases {
    last: Instant,
    took: Vec<(&'static str, Duration)>,
    /// The tick's commit and how many chunks it wrote, if it had one.
    commit: Option<(crate::store::CommitStats, usize)>,
    /// The parts of its first apply.
    apply: crate::sequencer::ApplySplit,
}

impl Phases {
    fn new() -> Self {
        Self {
            last: Instant::now(),
            took: Vec::with_capacity(8),
            commit: None,
            apply: Default::default(),
        }
    }

    /// Records the time since the previous phase ended as `name`.
    fn end(&mut self, name: &'static str) {
        let now = Instant::now();
        let took = now - self.last;
        metrics::histogram!(m::TICK_PHASE_SECONDS, "phase" => name).record(took.as_secs_f64());
        self.took.push((name, took));
        self.last = now;
    }

    /// "apply=0.4ms commit=12.0ms ..." for a log line.
    fn describe(&self) -> String {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let mut parts: Vec<String> = self
            .took
            .iter()
            .map(|(n, d)| format!("{n}={:.1}ms", ms(*d)))
            .collect();
        let a = &self.apply;
        // Only a tick that applied edits has an apply to split.
        if *a != Default::default() {
            parts.push(format!(
                "(apply: wait={:.1}ms prepare={:.1}ms lanes={:.1}ms merge={:.1}ms)",
                ms(a.wait),
                ms(a.prepare),
                ms(a.lanes),
                ms(a.merge)
            ));
        }
        if let Some((c, chunks)) = &self.commit {
            parts.push(format!(
                "(encode={:.1}ms write={:.1}ms flush={:.1}ms fsync={:.1}ms chunks={chunks} bytes={})",
                ms(c.encode),
                ms(c.apply),
                ms(c.flush),
                ms(c.fsync),
                c.bytes_written
            ));
        }
        parts.join(" ")
    }
}
