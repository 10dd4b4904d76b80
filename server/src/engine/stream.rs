//! Streaming chunk snapshots to sessions, nearest first, under a per-tick
//! byte budget per session.

use std::collections::HashMap;

use bytes::Bytes;
use strata_protocol::WorldUpdate;
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::hash::chunk_hash;
use strata_terrain::ChunkPos;
use tracing::error;

use super::fanout::encode_update;
use super::Engine;
use crate::net::writer::SendRefused;

/// Encoded snapshots kept for reuse: many sessions near one spot ask for
/// the same chunks.
pub const SNAPSHOT_CACHE_ENTRIES: usize = 4096;

/// Encoded snapshot frames by (chunk, version).
#[derive(Debug, Default)]
pub struct SnapshotCache {
    frames: HashMap<(ChunkPos, u64), Bytes>,
}

impl SnapshotCache {
    fn get(&self, pos: ChunkPos, version: u64) -> Option<Bytes> {
        self.frames.get(&(pos, version)).cloned()
    }

    fn put(&mut self, pos: ChunkPos, version: u64, frame: Bytes) {
        if self.frames.len() >= SNAPSHOT_CACHE_ENTRIES {
            self.frames.clear();
        }
        self.frames.insert((pos, version), frame);
    }
}

impl Engine {
    pub(super) fn stream_snapshots(&mut self) {
        let budget = self.stream.send_budget;
        let ids: Vec<u64> = self.peers.keys().copied().collect();
        for id in ids {
            let mut spent = 0usize;
            while spent < budget {
                let Some(p) = self.peers.get_mut(&id) else {
                    break;
                };
                if p.failed || p.updates.capacity() == 0 {
                    break;
                }
                let Some(pos) = p.pending.pop_front() else {
                    break;
                };
                if !p.interest.covers(pos) {
                    continue;
                }
                let full = p.full_data.contains(&pos);
                let (frame, version) = match self.snapshot_frame(pos, full) {
                    Ok(f) => f,
                    Err(e) => {
                        error!(error = %e, ?pos, "cannot build a snapshot");
                        break;
                    }
                };
                spent += frame.len();
                let p = self.peers.get_mut(&id).expect("checked above");
                match p.updates.try_send(frame) {
                    Ok(()) => {
                        p.known.insert(pos, version);
                    }
                    Err(SendRefused::Full) => {
                        p.pending.push_front(pos);
                        break;
                    }
                    Err(SendRefused::Closed) => {
                        p.failed = true;
                        break;
                    }
                }
            }
        }
    }

    /// The frame that brings a client to the chunk's current version.
    fn snapshot_frame(&mut self, pos: ChunkPos, full: bool) -> anyhow::Result<(Bytes, u64)> {
        let version = self.versions.get(&pos).copied().unwrap_or(0);
        let full = full || !self.stream.regenerable;
        if version == 0 && !full {
            return Ok((encode_update(&WorldUpdate::Generated { pos }), 0));
        }
        if let Some(f) = self
            .snapshots
            .get(pos, version)
            .filter(|_| !full || version > 0)
        {
            return Ok((f, version));
        }
        let around: Vec<ChunkPos> = crate::sequencer::residency::with_neighbours(pos).collect();
        self.make_resident(&around)?;
        let mesh_hash = self.seq.mesh_hash(pos);
        let chunk = self.seq.chunk(pos);
        let update = WorldUpdate::Snapshot {
            pos,
            version,
            hash: chunk_hash(&chunk),
            mesh_hash,
            data: encode_chunk(&chunk),
        };
        let frame = encode_update(&update);
        if version > 0 {
            self.snapshots.put(pos, version, frame.clone());
        }
        Ok((frame, version))
    }
}
