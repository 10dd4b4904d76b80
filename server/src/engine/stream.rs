//! Streaming chunk snapshots to sessions, nearest first, under a per-tick
//! byte budget per session and a time budget per tick for all of them;
//! `InterestComplete` follows a view's last chunk. A modified chunk goes to a client that can
//! regenerate as a patch: a delta from its generated form, usually tens of
//! times smaller than the chunk.

use std::time::{Duration, Instant};

use bytes::{Bytes, BytesMut};
use strata_protocol::WorldUpdate;
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::{ChunkDelta, DeltaError};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, ChunkPos};
use tracing::error;

use super::fanout::encode_update;
use super::frame_cache::FrameKey;
use super::Engine;
use crate::log_every::{LogEvery, LOG_EVERY};
use crate::metrics as m;
use crate::net::writer::SendRefused;

/// Default generated chunks kept as patch bases (at most 64 KiB each;
/// `[engine] patch_base_chunks`).
pub const DEFAULT_PATCH_BASE_CHUNKS: usize = 2048;

/// Chunks whose frame cannot be built (a stored chunk that does not read)
/// are tried again every tick: one line a second stands for them.
pub(super) static SNAPSHOT_ERRORS: LogEvery = LogEvery::new(LOG_EVERY);

/// The update that brings a client to `chunk` at `version`: the whole
/// chunk, or, given its generated form `base`, a patch against that.
pub fn frame_update(
    pos: ChunkPos,
    version: u64,
    mesh_hash: u64,
    chunk: &Chunk,
    base: Option<&Chunk>,
) -> Result<WorldUpdate, DeltaError> {
    Ok(match base {
        None => WorldUpdate::Snapshot {
            pos,
            version,
            hash: chunk_hash(chunk),
            mesh_hash,
            data: encode_chunk(chunk),
        },
        Some(base) => {
            // A patch: the delta from the generated chunk (version 0).
            let delta = ChunkDelta::encode(pos, 0, version, base, chunk)?;
            metrics::counter!(m::PATCH_BYTES).increment(delta.payload.len() as u64);
            WorldUpdate::Patched { delta, mesh_hash }
        }
    })
}

/// One session's batch while a tick's streaming assembles it.
struct OpenBatch {
    id: u64,
    bytes: BytesMut,
    sent: Vec<(ChunkPos, u64, &'static str)>,
    /// The frame it stopped at, not built yet.
    waiting: Option<FrameKey>,
}

impl Engine {
    /// Streams pending snapshots, one batch (one queue slot) per session,
    /// until the tick's streaming time is spent. Sessions are served in turn
    /// from where the last tick stopped, so a join storm delays snapshots,
    /// never the tick's edits.
    ///
    /// Three steps: each session's batch takes what needs no building
    /// (cached frames, `Generated` lines) up to the first frame that does;
    /// those frames are built on the workers, for many sessions at once
    /// (`prebuild.rs`); then the batches go on with them and are sent.
    /// `[engine] stream_us` bounds the first and the last step, and sizes
    /// the building between them.
    pub(super) fn stream_snapshots(&mut self) {
        let deadline = Instant::now() + Duration::from_micros(self.cfg.stream_us);
        let mut ids: Vec<u64> = self
            .peers
            .iter()
            .filter(|(_, p)| !p.pending.is_empty() || p.complete_due)
            .map(|(id, _)| *id)
            .collect();
        ids.sort_unstable();
        // Resume after the session served last.
        let start = ids.partition_point(|id| *id <= self.stream_cursor);
        ids.rotate_left(start);
        let mut due = self.prebuild_plan();
        let mut open = Vec::new();
        for (i, id) in ids.into_iter().enumerate() {
            // At least one session per tick, however small the budget.
            if i > 0 && Instant::now() >= deadline {
                break;
            }
            let Some(mut batch) = self.open_batch(id) else {
                self.stream_cursor = id;
                continue;
            };
            self.fill_batch(&mut batch, deadline, false);
            if batch.waiting.is_some() {
                if due.is_full() {
                    // No room left to build its frames: it goes first next
                    // tick (with what it has now), ahead of those served.
                    open.push(batch);
                    break;
                }
                self.plan_frames(id, &mut due);
            }
            self.stream_cursor = id;
            open.push(batch);
        }
        if !due.is_empty() {
            // With the store failing, no frame is built here either: each
            // session's would wait on it in turn.
            let store_answers = self.prebuild_frames(&due);
            let deadline = Instant::now() + Duration::from_micros(self.cfg.stream_us);
            for batch in open.iter_mut() {
                // A frame planned and still not built (its chunk could not
                // be read) is built here, so the session moves on.
                if let Some(key) = batch.waiting.take() {
                    self.fill_batch(batch, deadline, store_answers && due.contains(key));
                }
            }
        }
        for batch in open {
            self.send_batch(batch);
        }
    }

    /// An empty batch for session `id`, unless it is gone, failed, or its
    /// previous batch is still being written: one batch in flight at
    /// most, so a delta queued after it waits behind one batch of
    /// snapshots, not many.
    fn open_batch(&self, id: u64) -> Option<OpenBatch> {
        let p = self.peers.get(&id)?;
        (!p.failed && p.may_stream()).then(|| OpenBatch {
            id,
            bytes: BytesMut::new(),
            sent: Vec::new(),
            waiting: None,
        })
    }

    /// Adds the session's next frames to `batch` up to its byte budget (and
    /// until `deadline`, once it holds one), stopping at a frame not built
    /// yet: built here only if `build_first` and the batch is empty.
    fn fill_batch(&mut self, batch: &mut OpenBatch, deadline: Instant, build_first: bool) {
        let budget = self.stream.send_budget;
        let id = batch.id;
        while batch.bytes.len() < budget && (batch.bytes.is_empty() || Instant::now() < deadline) {
            let Some(p) = self.peers.get_mut(&id) else {
                return;
            };
            let Some(pos) = p.pending.pop_front() else {
                break;
            };
            if !p.interest.covers(pos) {
                continue;
            }
            let full = p.wants_full(pos);
            let build = build_first && batch.bytes.is_empty();
            match self.snapshot_frame(pos, full, build) {
                Ok(Ok((frame, version, kind))) => {
                    batch.bytes.extend_from_slice(&frame);
                    batch.sent.push((pos, version, kind));
                }
                Ok(Err(key)) => {
                    if let Some(p) = self.peers.get_mut(&id) {
                        p.pending.push_front(pos);
                    }
                    batch.waiting = Some(key);
                    break;
                }
                Err(e) => {
                    // Each tick tries it again: a line a second at most.
                    if let Some(folded) = SNAPSHOT_ERRORS.event() {
                        error!(error = %e, ?pos, folded, "cannot build a snapshot");
                    }
                    // Tried again after the session's other chunks.
                    if let Some(p) = self.peers.get_mut(&id) {
                        p.pending.push_back(pos);
                    }
                    break;
                }
            }
        }
    }

    /// Sends a batch (with the view's end marker after its last chunk),
    /// and records what the session now holds.
    fn send_batch(&mut self, batch: OpenBatch) {
        let OpenBatch {
            id,
            bytes: mut batch,
            sent,
            ..
        } = batch;
        let Some(p) = self.peers.get_mut(&id) else {
            return;
        };
        let completes = p.complete_due && p.pending.is_empty() && !p.failed;
        if let (true, Some(center)) = (completes, p.interest.center()) {
            let radius = p.interest.radius();
            batch.extend_from_slice(&encode_update(&WorldUpdate::InterestComplete {
                center,
                radius,
            }));
        }
        if batch.is_empty() {
            return;
        }
        match p.send_update(batch.freeze(), false) {
            Ok(_) => {
                p.changes_queued = false;
                p.complete_due &= !completes;
                for (pos, version, kind) in sent {
                    p.receive(&mut self.holders, id, pos, version);
                    metrics::counter!(m::SNAPSHOTS_SENT, "kind" => kind).increment(1);
                }
            }
            Err(SendRefused::Full) => {
                for (pos, _, _) in sent.into_iter().rev() {
                    p.pending.push_front(pos);
                }
            }
            Err(SendRefused::Closed) => p.failed = true,
        }
    }

    /// The key of the frame that brings a client to the chunk's current
    /// version: a patch against the generated chunk when the client can
    /// regenerate, else (or when `full`) the whole chunk.
    pub(super) fn frame_key(&self, pos: ChunkPos, full: bool) -> FrameKey {
        let version = self.versions.get(&pos).copied().unwrap_or(0);
        (pos, version, full || !self.stream.regenerable)
    }

    /// That frame, from the cache or (when `build`) built here; else the
    /// key of the frame not built yet.
    fn snapshot_frame(
        &mut self,
        pos: ChunkPos,
        full: bool,
        build: bool,
    ) -> anyhow::Result<Result<(Bytes, u64, &'static str), FrameKey>> {
        let key @ (_, version, full) = self.frame_key(pos, full);
        if version == 0 && !full {
            let frame = encode_update(&WorldUpdate::Generated { pos });
            return Ok(Ok((frame, 0, "generated")));
        }
        let kind = if full { "full" } else { "patched" };
        // A cached frame is sent without touching the world.
        if let Some(mesh_hash) = self.cached_frame_mesh(key) {
            if let Some(f) = self.snapshots.get(key, mesh_hash) {
                return Ok(Ok((f, version, kind)));
            }
        }
        if !build {
            return Ok(Err(key));
        }
        if self.unreadable.blocks(pos, Instant::now()) {
            anyhow::bail!("the chunk or a neighbour does not read (tried again later)");
        }
        let around: Vec<ChunkPos> = crate::sequencer::residency::with_neighbours(pos).collect();
        self.make_resident(&around)?;
        let mesh_hash = self.seq.mesh_hash(pos);
        if let Some(f) = self.snapshots.get(key, mesh_hash) {
            return Ok(Ok((f, version, kind)));
        }
        metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "miss").increment(1);
        let chunk = self.seq.chunk(pos);
        let base = match full {
            true => None,
            false => Some(self.patch_bases.get(pos, &**self.seq.world().generator())),
        };
        let update = frame_update(pos, version, mesh_hash, &chunk, base.as_deref())?;
        metrics::counter!(m::SNAPSHOT_FRAMES_BUILT, "on" => "engine").increment(1);
        let frame = encode_update(&update);
        // Full frames of version 0 are as costly to build (generate, compress,
        // mesh) as any; end-of-run checks ask many sessions for the same ones.
        self.snapshots.put(key, update, frame.clone());
        Ok(Ok((frame, version, kind)))
    }
}
