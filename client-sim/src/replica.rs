//! The client's copy of the chunks it sees: snapshots and deltas applied
//! with version and hash checks, version-0 chunks regenerated from the seed,
//! and mesh hashes compared with the server's.

use std::collections::HashMap;
use std::sync::Arc;

use strata_protocol::{DeltaUpdate, WorldUpdate};
use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::hash::chunk_hash;
use strata_terrain::mesh::{mesh_chunk, MeshOptions, Neighborhood};
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Voxel, VoxelPos};

/// A chunk as held by the client.
#[derive(Debug, Clone)]
pub struct Held {
    pub chunk: Chunk,
    pub version: u64,
}

/// A mesh whose hash differs from the server's: a consistency bug.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MeshMismatch {
    pub pos: ChunkPos,
    pub version: u64,
    pub server: u64,
    pub client: u64,
}

/// What the client must ask the server for after an update.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// A version gap or hash mismatch: resend the chunk.
    Resync(ChunkPos),
    /// The client cannot regenerate: send full data.
    FullSnapshot(ChunkPos),
}

/// Counters a load test reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplicaStats {
    pub snapshots: u64,
    pub generated: u64,
    pub deltas: u64,
    pub delta_payload_bytes: u64,
    pub gaps: u64,
    pub hash_mismatches: u64,
    pub meshes_checked: u64,
    pub mesh_mismatches: u64,
    pub meshes_unverifiable: u64,
}

/// Chunks held by one client.
#[derive(Debug)]
pub struct Replica {
    generator: Option<Arc<dyn ChunkGenerator>>,
    chunks: HashMap<ChunkPos, Held>,
    /// Server mesh hashes to check at the next tick end: pos -> (version, hash).
    pending_mesh: HashMap<ChunkPos, (u64, u64)>,
    mismatches: Vec<MeshMismatch>,
    /// Every version each chunk passed through, when recording.
    history: Option<HashMap<ChunkPos, Vec<u64>>>,
    pub stats: ReplicaStats,
    last_seq: u64,
}

impl Replica {
    /// `generator` regenerates version-0 chunks; without one, the replica
    /// asks for full snapshots instead.
    pub fn new(generator: Option<Arc<dyn ChunkGenerator>>) -> Self {
        Self {
            generator,
            chunks: HashMap::new(),
            pending_mesh: HashMap::new(),
            mismatches: Vec::new(),
            history: None,
            stats: ReplicaStats::default(),
            last_seq: 0,
        }
    }

    /// Records every version each chunk passes through (ordering tests).
    pub fn record_history(&mut self) {
        self.history.get_or_insert_with(HashMap::new);
    }

    pub fn history(&self) -> Option<&HashMap<ChunkPos, Vec<u64>>> {
        self.history.as_ref()
    }

    pub fn get(&self, pos: ChunkPos) -> Option<&Held> {
        self.chunks.get(&pos)
    }

    pub fn chunks(&self) -> impl Iterator<Item = (ChunkPos, &Held)> {
        self.chunks.iter().map(|(p, h)| (*p, h))
    }

    pub fn len(&self) -> usize {
        self.chunks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.chunks.is_empty()
    }

    /// Sequence number of the last tick end seen.
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    pub fn mesh_mismatches(&self) -> &[MeshMismatch] {
        &self.mismatches
    }

    fn hold(&mut self, pos: ChunkPos, chunk: Chunk, version: u64) {
        if let Some(h) = self.history.as_mut() {
            let seen = h.entry(pos).or_default();
            if seen.last() != Some(&version) {
                seen.push(version);
            }
        }
        self.chunks.insert(pos, Held { chunk, version });
    }

    /// Applies one update; returns what must be requested from the server.
    pub fn apply(&mut self, update: WorldUpdate) -> Option<Request> {
        match update {
            WorldUpdate::Generated { pos } => match &self.generator {
                Some(g) => {
                    let chunk = g.generate(pos);
                    self.stats.generated += 1;
                    self.hold(pos, chunk, 0);
                    None
                }
                None => Some(Request::FullSnapshot(pos)),
            },
            WorldUpdate::Snapshot {
                pos,
                version,
                hash,
                mesh_hash,
                data,
            } => {
                let chunk = match decode_chunk(&data) {
                    Ok(c) if chunk_hash(&c) == hash => c,
                    _ => {
                        self.stats.hash_mismatches += 1;
                        self.chunks.remove(&pos);
                        return Some(Request::Resync(pos));
                    }
                };
                self.stats.snapshots += 1;
                self.hold(pos, chunk, version);
                if version > 0 {
                    self.pending_mesh.insert(pos, (version, mesh_hash));
                }
                None
            }
            WorldUpdate::Delta(d) => self.apply_delta(d),
            WorldUpdate::Unsubscribed { pos } => {
                self.chunks.remove(&pos);
                self.pending_mesh.remove(&pos);
                None
            }
            WorldUpdate::TickEnd { last_seq } => {
                self.last_seq = self.last_seq.max(last_seq);
                self.verify_meshes();
                None
            }
        }
    }

    fn apply_delta(&mut self, d: DeltaUpdate) -> Option<Request> {
        let pos = d.delta.pos;
        let Some(held) = self.chunks.get(&pos) else {
            self.stats.gaps += 1;
            return Some(Request::Resync(pos));
        };
        if held.version != d.delta.from_version {
            self.stats.gaps += 1;
            self.chunks.remove(&pos);
            return Some(Request::Resync(pos));
        }
        match d.delta.apply(&held.chunk) {
            Ok(chunk) => {
                self.stats.deltas += 1;
                self.stats.delta_payload_bytes += d.delta.payload.len() as u64;
                self.hold(pos, chunk, d.delta.to_version);
                self.pending_mesh
                    .insert(pos, (d.delta.to_version, d.mesh_hash));
                None
            }
            Err(_) => {
                self.stats.hash_mismatches += 1;
                self.chunks.remove(&pos);
                Some(Request::Resync(pos))
            }
        }
    }

    /// Meshes every chunk that changed this tick and compares hashes. A
    /// chunk is checked only when the client holds its 26 neighbours, since
    /// the mesh reads them.
    fn verify_meshes(&mut self) {
        let pending: Vec<_> = self.pending_mesh.drain().collect();
        for (pos, (version, server)) in pending {
            match self.chunks.get(&pos) {
                Some(h) if h.version == version => {}
                _ => continue,
            }
            let Some(client) = self.mesh_hash(pos) else {
                self.stats.meshes_unverifiable += 1;
                continue;
            };
            self.stats.meshes_checked += 1;
            if client != server {
                self.stats.mesh_mismatches += 1;
                self.mismatches.push(MeshMismatch {
                    pos,
                    version,
                    server,
                    client,
                });
            }
        }
    }

    /// The LOD-0 mesh hash of a chunk from held chunks only.
    pub fn mesh_hash(&self, pos: ChunkPos) -> Option<u64> {
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if !self.chunks.contains_key(&pos.offset(dx, dy, dz)?) {
                        return None;
                    }
                }
            }
        }
        let nb = Neighborhood::from_fn(pos.origin(), |p: VoxelPos| {
            self.voxel(p).unwrap_or(Voxel::AIR)
        });
        Some(mesh_chunk(&nb, &MeshOptions::default()).hash())
    }

    fn voxel(&self, p: VoxelPos) -> Option<Voxel> {
        let (x, y, z) = p.local();
        self.chunks.get(&p.chunk()).map(|h| h.chunk.get(x, y, z))
    }
}
