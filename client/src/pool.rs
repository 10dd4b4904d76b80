//! Chunks and mesh hashes shared by the replicas of one process. Many bots
//! near one spot hold the same chunk versions; sharing them keeps a
//! thousand replicas in memory and meshes each state once.
//!
//! Sharing is sound because a replica only ever holds a chunk whose hash it
//! checked: `(pos, version)` names one content, and a mesh is a function of
//! the 27 chunk versions around it. Bots that disagree on a version's hash
//! are reported by the load tester, not hidden: the pool compares hashes.

use std::sync::{Arc, Mutex, Weak};

use rustc_hash::FxHashMap as HashMap;
use strata_terrain::{Chunk, ChunkPos};

/// Mesh hashes in each of the memo's two generations: when the young one
/// is full it becomes the old one, and the old one is forgotten.
pub const MESH_MEMO_ENTRIES: usize = 1 << 16;
/// Chunk entries after which dead ones are swept.
pub const CHUNK_SWEEP_ENTRIES: usize = 1 << 14;

/// The chunk versions a mesh reads: the chunk and its 26 neighbours.
pub type MeshKey = (ChunkPos, [u64; 27]);

#[derive(Debug, Default)]
struct Chunks {
    map: HashMap<(ChunkPos, u64), (u64, Weak<Chunk>)>,
    sweep_at: usize,
}

/// Shared, weakly held chunks by `(pos, version)`, and a mesh-hash memo.
#[derive(Debug, Default)]
pub struct ChunkPool {
    chunks: Mutex<Chunks>,
    meshes: Mutex<MeshMemo>,
}

/// Two generations of mesh hashes, so a full memo never forgets everything
/// at once (every replica would re-mesh at the same moment).
#[derive(Debug, Default)]
struct MeshMemo {
    young: HashMap<MeshKey, u64>,
    old: HashMap<MeshKey, u64>,
}

impl ChunkPool {
    /// A live chunk at `(pos, version)` with its hash, if some replica holds it.
    pub fn get(&self, pos: ChunkPos, version: u64) -> Option<(Arc<Chunk>, u64)> {
        let c = self
            .chunks
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let (hash, weak) = c.map.get(&(pos, version))?;
        Some((weak.upgrade()?, *hash))
    }

    /// Shares `chunk` (hash `hash`): returns the pooled copy if one with the
    /// same hash is alive, else pools this one.
    pub fn intern(
        &self,
        pos: ChunkPos,
        version: u64,
        hash: u64,
        chunk: impl Into<Arc<Chunk>>,
    ) -> Arc<Chunk> {
        let mut c = self
            .chunks
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((h, weak)) = c.map.get(&(pos, version)) {
            if *h == hash {
                if let Some(live) = weak.upgrade() {
                    return live;
                }
            }
        }
        let arc = chunk.into();
        c.map.insert((pos, version), (hash, Arc::downgrade(&arc)));
        if c.map.len() >= c.sweep_at.max(CHUNK_SWEEP_ENTRIES) {
            c.map.retain(|_, (_, w)| w.strong_count() > 0);
            c.sweep_at = c.map.len() * 2;
        }
        arc
    }

    pub fn mesh_hash(&self, key: &MeshKey) -> Option<u64> {
        let m = self
            .meshes
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        m.young.get(key).or_else(|| m.old.get(key)).copied()
    }

    pub fn put_mesh_hash(&self, key: MeshKey, hash: u64) {
        let mut m = self
            .meshes
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if m.young.len() >= MESH_MEMO_ENTRIES {
            m.old = std::mem::take(&mut m.young);
        }
        m.young.insert(key, hash);
    }

    /// Live pooled chunks (for reports).
    pub fn live_chunks(&self) -> usize {
        let c = self
            .chunks
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        c.map.values().filter(|(_, w)| w.strong_count() > 0).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::Voxel;

    #[test]
    fn shares_live_chunks_and_forgets_dead_ones() {
        let pool = ChunkPool::default();
        let pos = ChunkPos::new(1, 2, 3);
        let a = pool.intern(pos, 4, 9, Chunk::uniform(Voxel::AIR));
        let b = pool.intern(pos, 4, 9, Chunk::uniform(Voxel::solid(1)));
        assert!(Arc::ptr_eq(&a, &b), "same version and hash: shared");
        let other = pool.intern(pos, 4, 10, Chunk::uniform(Voxel::solid(1)));
        assert!(!Arc::ptr_eq(&a, &other), "a different hash is never shared");
        drop((a, b, other));
        assert!(pool.get(pos, 4).is_none());
        assert_eq!(pool.live_chunks(), 0);
        let key = (pos, [0; 27]);
        pool.put_mesh_hash(key, 77);
        assert_eq!(pool.mesh_hash(&key), Some(77));
    }

    #[test]
    fn mesh_memo_forgets_one_generation_at_a_time() {
        let pool = ChunkPool::default();
        let key = |i: usize| (ChunkPos::new(i as i32, 0, 0), [i as u64; 27]);
        for i in 0..MESH_MEMO_ENTRIES {
            pool.put_mesh_hash(key(i), i as u64);
        }
        // The young generation is full: the next insert ages it, it stays readable.
        pool.put_mesh_hash(key(MESH_MEMO_ENTRIES), 1);
        assert_eq!(pool.mesh_hash(&key(0)), Some(0));
        assert_eq!(pool.mesh_hash(&key(MESH_MEMO_ENTRIES)), Some(1));
        for i in MESH_MEMO_ENTRIES + 1..=2 * MESH_MEMO_ENTRIES {
            pool.put_mesh_hash(key(i), i as u64);
        }
        assert_eq!(
            pool.mesh_hash(&key(0)),
            None,
            "two generations ago: forgotten"
        );
        assert_eq!(pool.mesh_hash(&key(MESH_MEMO_ENTRIES)), Some(1));
    }
}
