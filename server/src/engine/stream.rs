//! Streaming chunk snapshots to sessions, nearest first, under a per-tick
//! byte budget per session and a time budget per tick for all of them;
//! `InterestComplete` follows a view's last chunk. A modified chunk goes to a client that can
//! regenerate as a patch: a delta from its generated form, usually tens of
//! times smaller than the chunk.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use bytes::{Bytes, BytesMut};
use strata_protocol::{WorldUpdate, CAP_SNAPSHOTS};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::hash::chunk_hash;
use strata_terrain::ChunkPos;
use tracing::error;

use super::fanout::encode_update;
use super::Engine;
use crate::metrics as m;
use crate::net::writer::SendRefused;

/// Default generated chunks kept as patch bases (at most 64 KiB each;
/// `[engine] patch_base_chunks`).
pub const DEFAULT_PATCH_BASE_CHUNKS: usize = 2048;

/// Default encoded snapshots kept for reuse (`[engine]
/// snapshot_cache_entries`): many sessions near one spot ask for the same
/// chunks.
pub const DEFAULT_SNAPSHOT_CACHE_ENTRIES: usize = 8192;

/// An encoded snapshot or patch and the update it encodes.
#[derive(Debug)]
struct Cached {
    update: WorldUpdate,
    frame: Bytes,
}

/// Snapshot frames by (chunk, version, full data rather than a patch).
///
/// A frame carries its chunk's mesh hash, which also depends on the
/// neighbours, so a hit is reused only if that hash is still current; else
/// only the (small) frame is re-encoded, not the chunk or the patch.
/// Full, it starts over empty.
#[derive(Debug)]
pub struct SnapshotCache {
    capacity: usize,
    frames: HashMap<(ChunkPos, u64, bool), Cached>,
}

/// The mesh hash a snapshot or patch carries.
fn mesh_hash_of(u: &mut WorldUpdate) -> Option<&mut u64> {
    match u {
        WorldUpdate::Snapshot { mesh_hash, .. } | WorldUpdate::Patched { mesh_hash, .. } => {
            Some(mesh_hash)
        }
        _ => None,
    }
}

impl SnapshotCache {
    /// A cache of at most `capacity` frames (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: HashMap::new(),
        }
    }

    /// The cached frame, re-encoded first if `mesh_hash` changed.
    fn get(&mut self, key: (ChunkPos, u64, bool), mesh_hash: u64) -> Option<Bytes> {
        let Some(c) = self.frames.get_mut(&key) else {
            metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "miss").increment(1);
            return None;
        };
        metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "hit").increment(1);
        let held = mesh_hash_of(&mut c.update)?;
        if *held != mesh_hash {
            *held = mesh_hash;
            c.frame = encode_update(&c.update);
        }
        Some(c.frame.clone())
    }

    fn put(&mut self, key: (ChunkPos, u64, bool), update: WorldUpdate, frame: Bytes) {
        if self.frames.len() >= self.capacity {
            metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "cleared")
                .increment(self.frames.len() as u64);
            self.frames.clear();
        }
        self.frames.insert(key, Cached { update, frame });
    }
}

impl Engine {
    /// Streams pending snapshots, one batch (one queue slot) per session,
    /// until the tick's streaming time is spent. Sessions are served in turn
    /// from where the last tick stopped, so a join storm delays snapshots,
    /// never the tick's edits.
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
        for (i, id) in ids.into_iter().enumerate() {
            // At least one session per tick, however small the budget.
            if i > 0 && Instant::now() >= deadline {
                break;
            }
            self.stream_cursor = id;
            self.stream_batch(id, deadline);
        }
    }

    /// Sends one session up to its byte budget of snapshots (and until
    /// `deadline`) as one batch, once its previous batch went to the writer.
    fn stream_batch(&mut self, id: u64, deadline: Instant) {
        let budget = self.stream.send_budget;
        let mut batch = BytesMut::new();
        let mut sent: Vec<(ChunkPos, u64, &'static str)> = Vec::new();
        while batch.len() < budget && (batch.is_empty() || Instant::now() < deadline) {
            let Some(p) = self.peers.get_mut(&id) else {
                return;
            };
            // One batch in flight at most: a delta queued after it then
            // waits behind one batch of snapshots, not many.
            if p.failed || (batch.is_empty() && !p.updates.is_idle()) {
                break;
            }
            let Some(pos) = p.pending.pop_front() else {
                break;
            };
            if !p.interest.covers(pos) {
                continue;
            }
            // A thin client (no generator) gets every chunk whole.
            let full = p.full_data.contains(&pos) || p.has(CAP_SNAPSHOTS);
            match self.snapshot_frame(pos, full) {
                Ok((frame, version, kind)) => {
                    batch.extend_from_slice(&frame);
                    sent.push((pos, version, kind));
                }
                Err(e) => {
                    error!(error = %e, ?pos, "cannot build a snapshot");
                    // Tried again after the session's other chunks.
                    if let Some(p) = self.peers.get_mut(&id) {
                        p.pending.push_back(pos);
                    }
                    break;
                }
            }
        }
        let Some(p) = self.peers.get_mut(&id) else {
            return;
        };
        // The view's end marker goes after its last chunk, in the same batch.
        let completes = p.complete_due
            && p.pending.is_empty()
            && !p.failed
            && (!batch.is_empty() || p.updates.is_idle());
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
        match p.updates.try_send(batch.freeze()) {
            Ok(()) => {
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

    /// The frame that brings a client to the chunk's current version: a
    /// patch against the generated chunk when the client can regenerate,
    /// else (or when it asked for full data) the whole chunk.
    fn snapshot_frame(
        &mut self,
        pos: ChunkPos,
        full: bool,
    ) -> anyhow::Result<(Bytes, u64, &'static str)> {
        let version = self.versions.get(&pos).copied().unwrap_or(0);
        let full = full || !self.stream.regenerable;
        if version == 0 && !full {
            let frame = encode_update(&WorldUpdate::Generated { pos });
            return Ok((frame, 0, "generated"));
        }
        let kind = if full { "full" } else { "patched" };
        let around: Vec<ChunkPos> = crate::sequencer::residency::with_neighbours(pos).collect();
        self.make_resident(&around)?;
        let mesh_hash = self.seq.mesh_hash(pos);
        let key = (pos, version, full);
        if let Some(f) = self.snapshots.get(key, mesh_hash) {
            return Ok((f, version, kind));
        }
        let chunk = self.seq.chunk(pos);
        let update = if full {
            WorldUpdate::Snapshot {
                pos,
                version,
                hash: chunk_hash(&chunk),
                mesh_hash,
                data: encode_chunk(&chunk),
            }
        } else {
            let base = self.patch_bases.get(pos, &**self.seq.world().generator());
            // A patch: the delta from the generated chunk (version 0).
            let delta = ChunkDelta::encode(pos, 0, version, &base, &chunk)?;
            metrics::counter!(m::PATCH_BYTES).increment(delta.payload.len() as u64);
            WorldUpdate::Patched { delta, mesh_hash }
        };
        let frame = encode_update(&update);
        // Full frames of version 0 are as costly to build (generate, compress,
        // mesh) as any; end-of-run checks ask many sessions for the same ones.
        self.snapshots.put(key, update, frame.clone());
        Ok((frame, version, kind))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::{Chunk, Voxel};

    fn patched(pos: ChunkPos, mesh_hash: u64) -> WorldUpdate {
        let at = |d: u8| Chunk::Uniform(Voxel::new(d, 1));
        let delta = ChunkDelta::encode(pos, 0, 1, &at(0), &at(9)).unwrap();
        WorldUpdate::Patched { delta, mesh_hash }
    }

    #[test]
    fn holds_at_most_its_capacity_and_refreshes_the_mesh_hash() {
        let mut cache = SnapshotCache::new(2);
        let key = |x: i32| (ChunkPos::new(x, 0, 0), 1, false);
        for x in 0..2 {
            let u = patched(key(x).0, 7);
            let frame = encode_update(&u);
            cache.put(key(x), u, frame);
        }
        assert_eq!(
            cache.get(key(0), 7),
            Some(encode_update(&patched(key(0).0, 7)))
        );
        // A changed neighbour changed the mesh hash: only the frame is redone.
        assert_eq!(
            cache.get(key(0), 8),
            Some(encode_update(&patched(key(0).0, 8)))
        );
        assert_eq!(cache.get(key(5), 7), None);
        let u = patched(key(2).0, 7);
        let frame = encode_update(&u);
        cache.put(key(2), u, frame);
        assert!(cache.frames.len() <= 2, "{} frames", cache.frames.len());
        assert!(cache.get(key(2), 7).is_some(), "the newest is kept");
    }
}
