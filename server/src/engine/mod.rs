//! The engine: one thread that owns the [`Sequencer`], the store handle and
//! every session's streaming state. It is the only writer of the world.
//!
//! Each tick: apply queued edits ([`Sequencer::tick`]), make them durable
//! with one group commit, and only then acknowledge them and fan their
//! deltas out; then stream snapshots to sessions under a byte budget. The
//! engine never blocks on a client: it `try_send`s encoded frames to each
//! connection's bounded writer, and a client whose queue is full loses its
//! pending deltas and gets fresh snapshots later.

pub mod admin;
mod command;
mod commit;
mod fanout;
mod generated;
mod holders;
mod inbox;
mod latest;
mod ops;
mod owners;
mod ownership;
mod peer;
mod pending;
mod position_refusal;
mod prebuild;
mod premesh;
mod residency;
pub mod snapshot;
mod stream;

pub use command::{Command, JoinReply, Kick};
pub use fanout::encode_control as fanout_control;
pub use inbox::{channel as inbox_channel, EngineHandle, Inbox};
pub use latest::LatestPosition;
pub use premesh::{
    DEFAULT_PREMESH_BACKLOG, DEFAULT_PREMESH_GENERATED_CHUNKS, DEFAULT_PREMESH_INFLIGHT,
    DEFAULT_PREMESH_RADIUS, DEFAULT_PREMESH_THREADS, MAX_PREMESH_RADIUS, MAX_PREMESH_THREADS,
};
pub use residency::{DEFAULT_RESIDENT_CHUNKS, MIN_RESIDENT_CHUNKS};
pub use stream::{DEFAULT_PATCH_BASE_CHUNKS, DEFAULT_SNAPSHOT_CACHE_ENTRIES};

use std::collections::{HashMap, HashSet};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use strata_protocol::{ChunkVersion, ErrorCode, Refusal, ServerMessage, WorldUpdate};
use strata_terrain::ChunkPos;
use tracing::{error, info, warn};

use crate::interest::{Anchor, Interest, InterestConfig};
use crate::metrics as m;
use crate::sequencer::{BuiltMeshes, PendingMeshes, Sequencer};
use crate::store::ChunkStore;
use crate::validate::bounds::WorldBounds;
use peer::Peer;

/// Default tick period.
pub const DEFAULT_TICK_MS: u64 = 10;
/// A tick longer than this many periods is logged with its phases.
pub const SLOW_TICK_PERIODS: u64 = 3;
/// Default microseconds of snapshot streaming per tick, for all sessions.
pub const DEFAULT_STREAM_US: u64 = 2_000;
/// Longest allowed streaming time per tick.
pub const MAX_STREAM_US: u64 = 1_000_000;
/// Longest allowed tick period.
pub const MAX_TICK_MS: u64 = 1000;
/// How often the positions of players who moved are stored (fsynced): a
/// crash loses at most this much of anyone's movement.
pub const POSITION_SAVE_EVERY: Duration = Duration::from_secs(1);
/// Default live sessions per player: a new login replaces the old one.
pub const DEFAULT_SESSIONS_PER_PLAYER: usize = 1;
/// Default capacity of the session-to-engine queue of players' traffic.
pub const DEFAULT_COMMAND_QUEUE: usize = 8192;
/// Default capacity of the queue of joins, leaves and admin requests,
/// which the engine serves first (see `inbox.rs`).
pub const DEFAULT_CONTROL_QUEUE: usize = 4096;
/// Largest allowed command or edit queue.
pub const MAX_COMMAND_QUEUE: usize = 1 << 20;
/// Largest allowed premesh backlog, generated-chunk cache or snapshot cache.
pub const MAX_ENGINE_CACHE: usize = 1 << 20;
/// Most worker threads `[engine] workers` may ask for.
pub const MAX_WORKERS: usize = 256;

/// Engine limits (`[engine]` in the config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EngineConfig {
    /// Milliseconds between ticks.
    pub tick_ms: u64,
    /// Microseconds of snapshot streaming per tick, for all sessions
    /// ([`DEFAULT_STREAM_US`]); the rest waits for later ticks.
    pub stream_us: u64,
    /// Player commands (edits, positions, subscriptions) queued from
    /// sessions before new ones are refused.
    pub command_queue: usize,
    /// Joins, leaves and admin requests queued ([`DEFAULT_CONTROL_QUEUE`]);
    /// served before any player command.
    pub control_queue: usize,
    /// Live sessions one player may have ([`DEFAULT_SESSIONS_PER_PLAYER`]);
    /// a new login past it ends the player's oldest session.
    pub sessions_per_player: usize,
    /// Chunks around each player meshed in the background ([`DEFAULT_PREMESH_RADIUS`]).
    pub premesh_radius: u8,
    /// Background mesh jobs in flight at most ([`DEFAULT_PREMESH_INFLIGHT`]).
    pub premesh_inflight: usize,
    /// Player chunks whose surroundings wait for the background mesher
    /// ([`premesh::DEFAULT_PREMESH_BACKLOG`]); past it the oldest are dropped.
    pub premesh_backlog: usize,
    /// Generated chunks the background mesher keeps for reuse
    /// ([`premesh::DEFAULT_PREMESH_GENERATED_CHUNKS`]).
    pub premesh_generated_chunks: usize,
    /// Threads building background meshes ([`DEFAULT_PREMESH_THREADS`]).
    pub premesh_threads: usize,
    /// Generated chunks kept as patch bases for the chunk stream
    /// ([`stream::DEFAULT_PATCH_BASE_CHUNKS`]).
    pub patch_base_chunks: usize,
    /// Encoded snapshot frames kept for reuse
    /// ([`stream::DEFAULT_SNAPSHOT_CACHE_ENTRIES`]).
    pub snapshot_cache_entries: usize,
    /// Chunks held in memory before cold ones are dropped ([`DEFAULT_RESIDENT_CHUNKS`]).
    pub resident_chunks: usize,
    /// Pre-images one online snapshot may hold when its request names no
    /// limit ([`snapshot::DEFAULT_SNAPSHOT_PREIMAGES`]).
    pub snapshot_preimages: usize,
    /// Threads that apply region lanes, mesh, encode for the store and fan
    /// deltas out; 0 means one per available core.
    pub workers: usize,
}

impl Default for EngineConfig {
    fn default() -> Self {
        Self {
            tick_ms: DEFAULT_TICK_MS,
            stream_us: DEFAULT_STREAM_US,
            command_queue: DEFAULT_COMMAND_QUEUE,
            control_queue: DEFAULT_CONTROL_QUEUE,
            sessions_per_player: DEFAULT_SESSIONS_PER_PLAYER,
            premesh_radius: DEFAULT_PREMESH_RADIUS,
            premesh_inflight: DEFAULT_PREMESH_INFLIGHT,
            premesh_backlog: premesh::DEFAULT_PREMESH_BACKLOG,
            premesh_generated_chunks: premesh::DEFAULT_PREMESH_GENERATED_CHUNKS,
            premesh_threads: DEFAULT_PREMESH_THREADS,
            patch_base_chunks: stream::DEFAULT_PATCH_BASE_CHUNKS,
            snapshot_cache_entries: stream::DEFAULT_SNAPSHOT_CACHE_ENTRIES,
            resident_chunks: DEFAULT_RESIDENT_CHUNKS,
            snapshot_preimages: snapshot::DEFAULT_SNAPSHOT_PREIMAGES,
            workers: 0,
        }
    }
}

/// How chunks are streamed to sessions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamPolicy {
    /// Snapshot bytes each session may be sent per tick (`net.send_budget_bytes_per_tick`).
    pub send_budget: usize,
    /// Clients can regenerate version-0 chunks from `Welcome`'s parameters;
    /// false for heightmap worlds, which then get full snapshots.
    pub regenerable: bool,
}

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Everything the engine thread owns.
pub struct Engine {
    seq: Sequencer,
    store: Arc<dyn ChunkStore>,
    cfg: EngineConfig,
    stream: StreamPolicy,
    interest: InterestConfig,
    bounds: WorldBounds,
    peers: HashMap<u64, Peer>,
    /// Which sessions hold each chunk: the fan-out visits only those.
    holders: holders::Holders,
    /// Durable version of every modified chunk (absent = version 0).
    versions: HashMap<ChunkPos, u64>,
    snapshots: stream::SnapshotCache,
    /// The session last streamed to; the next tick starts after it.
    stream_cursor: u64,
    patch_bases: generated::GeneratedCache,
    /// What a snapshot frame built ahead has cost lately.
    prebuild_cost: prebuild::PrebuildCost,
    premesh: premesh::Premesher,
    last_evict: Option<Instant>,
    /// Online snapshots in progress (their copy-on-write pre-images).
    snapshots_running: Vec<Arc<snapshot::PreImages>>,
    /// Commands that arrived during a commit and must wait for it.
    deferred: commit::Deferred,
    /// The commit thread (started with the engine's loop; `None` before,
    /// or if no thread could be had: then ticks commit inline).
    committer: Option<commit::Committer>,
    /// The last seq the store holds durably. The sequencer's own runs
    /// ahead of it while a commit is in flight; clients are told only this.
    durable_seq: u64,
    /// The `[engine] workers` threads.
    pool: Arc<rayon::ThreadPool>,
    /// Signs `RegionOwners` tickets (the cluster's shared auth secret).
    ticket_secret: Option<crate::auth::Secret>,
    /// When the sessions' region holders are next looked at.
    owners_due: Instant,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("peers", &self.peers.len())
            .finish_non_exhaustive()
    }
}

impl Engine {
    pub fn new(
        seq: Sequencer,
        store: Arc<dyn ChunkStore>,
        cfg: EngineConfig,
        stream: StreamPolicy,
        interest: InterestConfig,
        bounds: WorldBounds,
        versions: HashMap<ChunkPos, u64>,
    ) -> std::io::Result<Self> {
        let workers = match cfg.workers {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n.min(MAX_WORKERS),
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(workers)
            .thread_name(|i| format!("strata-worker-{i}"))
            .build()
            .map_err(std::io::Error::other)?;
        Ok(Self {
            pool: Arc::new(pool),
            premesh: premesh::Premesher::new(premesh::PremeshLimits {
                inflight: cfg.premesh_inflight,
                backlog: cfg.premesh_backlog,
                generated_chunks: cfg.premesh_generated_chunks,
                threads: cfg.premesh_threads,
            })?,
            durable_seq: seq.last_seq(),
            seq,
            store,
            cfg,
            stream,
            interest,
            bounds,
            peers: HashMap::new(),
            holders: Default::default(),
            versions,
            snapshots: stream::SnapshotCache::new(cfg.snapshot_cache_entries),
            stream_cursor: 0,
            patch_bases: generated::GeneratedCache::new(
                cfg.patch_base_chunks,
                generated::Use::PatchBase,
            ),
            prebuild_cost: Default::default(),
            last_evict: None,
            snapshots_running: Vec::new(),
            deferred: Default::default(),
            committer: None,
            ticket_secret: None,
            owners_due: Instant::now(),
        })
    }

    /// Signs the tickets `RegionOwners` carries with `secret`.
    pub fn with_ticket_secret(mut self, secret: crate::auth::Secret) -> Self {
        self.ticket_secret = Some(secret);
        self
    }

    /// Starts the engine thread. It stops on [`Command::Stop`] or when
    /// every handle is dropped, after flushing the batch in flight, or on a
    /// failed commit. `on_exit` runs when the thread ends, however it ends
    /// (a panic included).
    pub fn spawn(
        self,
        on_exit: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<(EngineHandle, std::thread::JoinHandle<anyhow::Result<()>>)> {
        let (tx, rx) = inbox::channel(self.cfg.command_queue, self.cfg.control_queue);
        let handle = std::thread::Builder::new()
            .name("strata-engine".into())
            .spawn(move || {
                let _exit = OnExit(Some(on_exit));
                self.run(rx)
            })?;
        Ok((tx, handle))
    }

    fn run(mut self, rx: Inbox) -> anyhow::Result<()> {
        match commit::Committer::spawn(self.store.clone(), self.pool.clone(), rx.waker()) {
            Ok(c) => self.committer = Some(c),
            Err(e) => warn!(error = %e, "no commit thread; ticks commit inline"),
        }
        let period = Duration::from_millis(self.cfg.tick_ms.max(1));
        let mut next_tick = Instant::now() + period;
        // When ticks overrun their period, commands already queued still
        // get until this (half a period after the last tick ended) before
        // the next tick: else a busy engine would take one command per tick
        // and submit edits only while commits run.
        let mut commands_until = Instant::now();
        let mut next_position_save = Instant::now() + POSITION_SAVE_EVERY;
        loop {
            let next = match self.deferred.pop() {
                Some(cmd) => Ok(cmd),
                None => self.next_command(&rx, next_tick),
            };
            let mut handled = false;
            match next {
                Ok(Command::Stop) | Err(RecvTimeoutError::Disconnected) => {
                    info!("engine stopping: final tick and flush");
                    self.tick(None)?;
                    self.close_all();
                    self.save_positions();
                    // Joins the commit thread once it has done every job
                    // queued: the last positions are stored, after the
                    // earlier ones.
                    drop(self.committer.take());
                    return Ok(());
                }
                Ok(cmd) => {
                    self.handle(cmd);
                    handled = true;
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            self.collect_premeshed();
            let now = Instant::now();
            if now >= next_tick && !(handled && now < commands_until) {
                self.tick(Some(&rx))?;
                // A fixed rate: a long tick shortens the wait for the next
                // one instead of adding to it (no catching up past now).
                next_tick = (next_tick + period).max(now);
                commands_until = Instant::now() + period / 2;
            }
            if now >= next_position_save {
                self.save_positions();
                next_position_save = now + POSITION_SAVE_EVERY;
            }
        }
    }

    /// The next command, waiting until `next_tick` at most. Edits awaiting
    /// their sight check are checked first if none is waiting, so the
    /// check runs while the engine would idle, not at the tick (which
    /// checks whatever arrived since).
    fn next_command(
        &mut self,
        rx: &Inbox,
        next_tick: Instant,
    ) -> Result<Command, RecvTimeoutError> {
        if self.seq.sighting() > 0 {
            match rx.recv_or_wake(Duration::ZERO) {
                Ok(Some(cmd)) => return Ok(cmd),
                Ok(None) => self.check_sighted(),
                Err(e) => return Err(e),
            }
        }
        rx.recv_timeout(next_tick.saturating_duration_since(Instant::now()))
    }

    /// Stores the positions of players who moved since the last save: on
    /// the commit thread (no commit runs now, so it goes next), or here
    /// without that thread. A failure is logged: positions are recoverable
    /// state (the next save retries), unlike edits.
    fn save_positions(&mut self) {
        let mut moved = self.seq.take_moved();
        if moved.is_empty() {
            return;
        }
        if let Some(committer) = &self.committer {
            match committer.save_positions(moved) {
                Ok(()) => return,
                Err(back) => moved = back,
            }
        }
        if let Err(e) = self.store.save_positions(&moved) {
            error!(error = %e, players = moved.len(), "saving player positions failed");
        }
    }

    fn handle(&mut self, cmd: Command) {
        let now = now_ms();
        match cmd {
            Command::Join {
                session,
                player,
                role,
                control,
                updates,
                reply,
                kick,
                position,
                capabilities,
            } => {
                // A new login replaces the player's oldest sessions past the cap.
                let mut older = self.sessions_of(&player);
                older.sort_unstable();
                let excess = (older.len() + 1).saturating_sub(self.cfg.sessions_per_player.max(1));
                for &id in &older[..excess] {
                    info!(session = id, %player, "replaced by a newer login");
                    self.end_session(id, ErrorCode::Kicked, "replaced by a newer login");
                }
                self.seq.session_joined(session, player, role);
                let start = self.seq.resume_position(session, now);
                metrics::counter!(m::SESSIONS_TOTAL).increment(1);
                let interest = Interest::new(self.interest, self.bounds);
                let mut peer = Peer::new(control, updates, interest, kick, position, start);
                peer.capabilities = capabilities;
                if let Some(old) = self.peers.insert(session, peer) {
                    old.unlist_all(&mut self.holders, session);
                }
                // A join may arrive mid-commit: name no seq a power cut could
                // still take back.
                let _ = reply.send(JoinReply {
                    last_seq: self.durable_seq,
                    start,
                });
            }
            Command::Leave { session } => {
                self.seq.session_left(session);
                if let Some(p) = self.peers.remove(&session) {
                    p.unlist_all(&mut self.holders, session);
                }
            }
            Command::Edit { session, request } => self.submit(session, request, now),
            Command::Position { session } => {
                let update = self.peers.get(&session).and_then(|p| p.position.take());
                if let Some(update) = update {
                    self.position(session, update, now);
                }
            }
            Command::Subscribe {
                session,
                center,
                radius,
            } => {
                // Admins may look anywhere; players only around themselves,
                // or before any position, around their start.
                let player = match self.seq.session(session) {
                    Some(s) if s.role == strata_protocol::Role::Admin => None,
                    Some(_) => Some(self.seq.position(session).map(|p| {
                        Anchor::Chunk(crate::validate::position::feet_voxel(p.feet).chunk())
                    })),
                    None => return,
                };
                let Some(p) = self.peers.get_mut(&session) else {
                    return;
                };
                let allowed = match player {
                    None => Ok(()),
                    Some(at) => {
                        let anchor = at.unwrap_or_else(|| p.start_anchor());
                        p.interest.check_centre(center, anchor)
                    }
                };
                match allowed {
                    Ok(()) => {
                        let change = p.interest.subscribe(center, radius);
                        self.apply_interest(session, change);
                    }
                    Err(max) => {
                        let refusal = Refusal::SubscribeTooFar { center, max };
                        self.send_control(session, &ServerMessage::RequestRefused(refusal));
                    }
                }
            }
            Command::Resync { session, pos } | Command::FullSnapshot { session, pos } => {
                let full = matches!(cmd, Command::FullSnapshot { .. });
                let Some(p) = self.peers.get_mut(&session) else {
                    return;
                };
                if p.interest.covers(pos) {
                    metrics::counter!(m::RESYNCS).increment(1);
                    if full {
                        p.full_data.insert(pos);
                    }
                    p.resend(pos);
                } else {
                    let refusal = Refusal::NotInInterest { pos };
                    self.send_control(session, &ServerMessage::RequestRefused(refusal));
                }
            }
            Command::Forget { session, chunks } => {
                if let Some(p) = self.peers.get_mut(&session) {
                    p.forget(&mut self.holders, session, &chunks);
                }
            }
            Command::Arrive {
                session,
                feet,
                issued_ms,
            } => {
                let msg = match self.seq.arrive(session, feet, issued_ms) {
                    Ok(start) => {
                        if let Some(p) = self.peers.get_mut(&session) {
                            p.start = start;
                        }
                        ServerMessage::Arrived { feet }
                    }
                    Err(reason) => ServerMessage::RequestRefused(Refusal::BadTicket { reason }),
                };
                self.send_control(session, &msg);
            }
            Command::Admin(c) => self.admin(c),
            Command::Stop | Command::Wake => {}
        }
        metrics::gauge!(m::QUEUE_DEPTH).set((self.seq.queued() + self.seq.sighting()) as f64);
    }

    fn submit(&mut self, session: u64, request: strata_protocol::EditRequest, now: u64) {
        let id = request.client_edit_id;
        // Every rule that reads no terrain first: a refused edit loads,
        // generates and meshes nothing.
        let result = self
            .seq
            .precheck(session, &request.edit, now)
            .and_then(|pre| {
                self.check_regions(session, &request.edit, now)?;
                let needed = self.seq.missing(pre.reads());
                if let Err(e) = self.make_resident(&needed) {
                    error!(error = %e, "store read failed");
                }
                // Line of sight is checked in a batch (`check_sighted`).
                self.seq.admit_prechecked(session, request, pre, now)
            });
        if let Err(reason) = result {
            self.refuse_edit(session, id, reason);
        }
        self.kick_refused();
    }

    fn refuse_edit(
        &mut self,
        session: u64,
        client_edit_id: u64,
        reason: strata_protocol::RejectReason,
    ) {
        metrics::counter!(m::EDITS_REJECTED, "reason" => m::reject_label(&reason)).increment(1);
        let msg = ServerMessage::EditRejected {
            client_edit_id,
            reason,
        };
        self.send_control(session, &msg);
    }

    /// Checks the line of sight of every edit admitted since the last
    /// check, on the workers, and answers those it refuses; the rest are
    /// queued for the tick.
    fn check_sighted(&mut self) {
        if self.seq.sighting() == 0 {
            return;
        }
        let pool = self.pool.clone();
        let seq = &mut self.seq;
        let refused = pool.install(|| seq.check_sighted(now_ms()));
        for r in refused {
            self.refuse_edit(r.session_id, r.client_edit_id, r.reason);
        }
        self.kick_refused();
    }

    /// Disconnects players out of rejection tokens.
    fn kick_refused(&mut self) {
        for s in self.seq.take_disconnects() {
            if let Some(p) = self.peers.get_mut(&s) {
                warn!(session = s, "disconnecting: too many refused edits");
                metrics::counter!(m::SESSIONS_KICKED, "reason" => "rejected_edits").increment(1);
                p.kick(ErrorCode::Kicked, "too many refused edits; slow down");
            }
        }
    }

    fn position(&mut self, session: u64, update: strata_protocol::PositionUpdate, now: u64) {
        // Stale, out of bounds or too fast: refused before any chunk is
        // loaded or generated.
        if let Err(reason) = self.seq.precheck_position(session, &update, now) {
            return self.refuse_position(session, update.seq, &reason, now);
        }
        let needed = self.seq.chunks_needed_for_position(&update);
        if let Err(e) = self.make_resident(&needed) {
            error!(error = %e, "store read failed");
            return;
        }
        match self.seq.update_position(session, update, now) {
            Ok(()) => {
                if let Some(p) = self.peers.get_mut(&session) {
                    let change = p.interest.follow_position(update.pos);
                    self.apply_interest(session, change);
                }
                self.premesh_around(session, update.pos);
            }
            Err(reason) => self.refuse_position(session, update.seq, &reason, now),
        }
    }

    fn apply_interest(&mut self, session: u64, change: crate::interest::InterestChange) {
        let Some(p) = self.peers.get_mut(&session) else {
            return;
        };
        // One frame for a whole re-centring: per-chunk frames (thousands at
        // view radius 8) would overflow the writer queue of a prompt client.
        let gone = p.apply_interest(&mut self.holders, session, change);
        for chunks in gone.chunks(strata_protocol::limits::MAX_UNSUBSCRIBED_PER_UPDATE) {
            let update = WorldUpdate::UnsubscribedMany {
                chunks: chunks.to_vec(),
            };
            if p.updates.try_send(fanout::encode_update(&update)).is_err() {
                p.failed = true;
            }
        }
    }

    fn send_control(&mut self, session: u64, msg: &ServerMessage) {
        if let Some(p) = self.peers.get_mut(&session) {
            if p.control.try_send(fanout::encode_control(msg)).is_err() {
                // Control messages are never dropped silently: a client this
                // far behind is disconnected.
                p.failed = true;
            }
        }
    }

    /// One tick: apply, commit, acknowledge, broadcast, stream. While the
    /// commit runs, safe commands from `rx` are served, and once the next
    /// tick is due the next batch is applied meanwhile (see
    /// [`MAX_CHAINED_COMMITS`]); its commit follows at once. Streaming and
    /// eviction run only after the last, when the world equals the store.
    fn tick(&mut self, rx: Option<&Inbox>) -> anyhow::Result<()> {
        let started = Instant::now();
        let period = self.tick_period();
        let mut phase = Phases::new();
        self.follow_leases();
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
    fn tick_period(&self) -> Duration {
        Duration::from_millis(self.cfg.tick_ms.max(1))
    }

    /// Checks the sight of the edits still waiting for it, then applies the
    /// queued edits on the workers and starts their meshes; refusals are
    /// answered at once.
    fn apply_tick(&mut self) -> Applied {
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
        let (out, meshing) = if idle { apply() } else { pool.install(apply) };
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
        out.batch = batch;
        let stats = match committed {
            Ok(stats) => stats,
            // A region lost mid-flight: the batch is abandoned, the node
            // goes on (cluster nodes apply nothing ahead).
            Err(e) if self.abandon_fenced(&out, &e) => {
                let _ = meshing.recv();
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
        let built = meshing
            .recv()
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
        for e in &out.batch.entries {
            self.versions.extend(e.changes.iter().copied());
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

    /// Live sessions of `player`.
    fn sessions_of(&self, player: &str) -> Vec<u64> {
        self.peers
            .keys()
            .copied()
            .filter(|&id| self.seq.session(id).is_some_and(|s| s.player == player))
            .collect()
    }

    /// Ends a session now: its connection closes with `code`, and the
    /// engine forgets it (its later `Leave` finds nothing).
    fn end_session(&mut self, id: u64, code: ErrorCode, message: &str) {
        if let Some(mut p) = self.peers.remove(&id) {
            p.unlist_all(&mut self.holders, id);
            p.kick(code, message);
        }
        self.seq.session_left(id);
    }

    fn close_all(&mut self) {
        for (id, mut p) in self.peers.drain() {
            p.kick(ErrorCode::ShuttingDown, "server is shutting down");
            self.seq.session_left(id);
        }
        self.holders.clear();
    }
}

/// Calls its function when dropped: at the end of the engine thread,
/// whether it returned or unwound.
struct OnExit<F: FnOnce()>(Option<F>);

impl<F: FnOnce()> Drop for OnExit<F> {
    fn drop(&mut self) {
        if let Some(f) = self.0.take() {
            f();
        }
    }
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
        pool.spawn(move || {
            let _ = tx.send(pending.build());
        });
    }
    rx
}
