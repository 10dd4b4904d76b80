//! Copy-on-write pre-images for consistent online snapshots.
//!
//! A snapshot begins on the engine thread between ticks, so the store then
//! holds exactly the world at seq `S`. From then on, before each commit the
//! engine records, for every chunk the commit changes and the snapshot has
//! not seen change yet, its state at `S` (`None`: not stored at `S`). A
//! reader walks the store's chunk records and, after reading each one,
//! prefers its pre-image if there is one. Pre-images are inserted before the
//! commit that overwrites the record, so a record read after that commit
//! always finds its pre-image: every chunk comes out exactly as at `S`,
//! while edits keep committing. The map is bounded; past its limit the
//! snapshot is aborted (with a reason) rather than delaying edits.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};

use strata_terrain::ChunkPos;

use super::Engine;
use crate::store::{CommitBatch, RawChunk};

/// Default bound on one snapshot's pre-images (chunks changed while it runs).
pub const DEFAULT_SNAPSHOT_PREIMAGES: usize = 65_536;
/// Largest bound an admin may ask for.
pub const MAX_SNAPSHOT_PREIMAGES: usize = 1 << 20;
/// Default bound on one snapshot's pre-image bytes (`[engine]
/// snapshot_preimage_bytes`): a count alone lets large chunks (up to 64 KiB
/// encoded) hold gigabytes while a slow reader runs.
pub const DEFAULT_SNAPSHOT_PREIMAGE_BYTES: usize = 512 << 20;
/// Fewest and most bytes `snapshot_preimage_bytes` may allow.
pub const SNAPSHOT_PREIMAGE_BYTES_RANGE: (usize, usize) = (1 << 20, 64 << 30);
/// Snapshots that may run at once.
pub const MAX_CONCURRENT_SNAPSHOTS: usize = 2;

/// Why a snapshot still running when the engine stops is aborted.
pub const STOPPING: &str = "the server is stopping";

/// Why the engine refuses to begin an online snapshot.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SnapshotRefused {
    /// Pre-images cover only this node's commits, while the walk reads a
    /// store other nodes also write: the copy would not be consistent.
    #[error(
        "online snapshots are not consistent on a cluster node; stop every node and take an \
         offline snapshot (`strata-admin snapshot create --data-dir DIR` with the store's config)"
    )]
    Clustered,
    #[error("{MAX_CONCURRENT_SNAPSHOTS} snapshots are already running")]
    TooMany,
}

#[derive(Debug, Default)]
struct State {
    map: HashMap<ChunkPos, Option<RawChunk>>,
    /// Encoded bytes the map holds.
    bytes: usize,
    aborted: Option<String>,
}

/// One running snapshot's pre-images, shared by the engine and its reader.
/// The engine forgets it once the reader drops its handle.
#[derive(Debug)]
pub struct PreImages {
    seq: u64,
    limit: usize,
    /// `[engine] snapshot_preimage_bytes`.
    byte_limit: usize,
    state: Mutex<State>,
}

impl PreImages {
    /// At most `limit` chunks and `byte_limit` encoded bytes.
    pub fn new(seq: u64, limit: usize, byte_limit: usize) -> Self {
        Self {
            seq,
            limit,
            byte_limit,
            state: Mutex::new(State::default()),
        }
    }

    /// The seq the snapshot captures.
    pub fn seq(&self) -> u64 {
        self.seq
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // A poisoned lock only means a panicking reader; the map is intact.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Why the snapshot was aborted, if it was.
    pub fn aborted(&self) -> Option<String> {
        self.lock().aborted.clone()
    }

    pub fn abort(&self, reason: String) {
        let mut s = self.lock();
        s.map.clear();
        s.bytes = 0;
        s.aborted.get_or_insert(reason);
    }

    fn has(&self, pos: ChunkPos) -> bool {
        let s = self.lock();
        s.aborted.is_some() || s.map.contains_key(&pos)
    }

    /// Records `pos`'s state at the snapshot's seq, unless already recorded.
    fn record(&self, pos: ChunkPos, before: &Option<RawChunk>) {
        let mut s = self.lock();
        if s.aborted.is_some() || s.map.contains_key(&pos) {
            return;
        }
        let size = before.as_ref().map_or(0, |c| c.encoded.len());
        let over = if s.map.len() >= self.limit {
            Some(format!(
                "more than {} chunks changed while the snapshot ran (raise the pre-image limit)",
                self.limit
            ))
        } else if s.bytes.saturating_add(size) > self.byte_limit {
            Some(format!(
                "the chunks changed while the snapshot ran took more than {} KiB",
                self.byte_limit >> 10
            ))
        } else {
            None
        };
        if let Some(reason) = over {
            s.map.clear();
            s.bytes = 0;
            s.aborted = Some(reason);
            return;
        }
        s.bytes += size;
        s.map.insert(pos, before.clone());
    }

    /// What the snapshot holds for a record the reader just read: the
    /// pre-image if the chunk changed since the seq, else the record itself.
    pub fn resolve(&self, read: RawChunk) -> Option<RawChunk> {
        match self.lock().map.get(&read.pos) {
            Some(pre) => pre.clone(),
            None => Some(read),
        }
    }

    /// Chunks recorded so far.
    pub fn len(&self) -> usize {
        self.lock().map.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Engine {
    /// Registers a snapshot at the current seq (call between ticks).
    /// Refused on a cluster node ([`SnapshotRefused::Clustered`]).
    pub(super) fn begin_snapshot(&mut self, limit: usize) -> Result<Arc<PreImages>, String> {
        if self.store.clustered() {
            return Err(SnapshotRefused::Clustered.to_string());
        }
        self.snapshots_running
            .retain(|s| Arc::strong_count(s) > 1 && s.aborted().is_none());
        if self.snapshots_running.len() >= MAX_CONCURRENT_SNAPSHOTS {
            return Err(SnapshotRefused::TooMany.to_string());
        }
        let limit = match limit {
            0 => self.cfg.snapshot_preimages,
            n => n.min(MAX_SNAPSHOT_PREIMAGES),
        };
        let bytes = self.cfg.snapshot_preimage_bytes;
        let pre = Arc::new(PreImages::new(self.seq.last_seq(), limit, bytes));
        self.snapshots_running.push(pre.clone());
        Ok(pre)
    }

    /// Aborts every running snapshot (their readers stop at their next
    /// chunk with `reason`).
    pub(super) fn abort_snapshots(&mut self, reason: &str) {
        for s in self.snapshots_running.drain(..) {
            s.abort(reason.to_string());
        }
    }

    /// Before a commit: saves the state at each running snapshot's seq of
    /// every chunk the batch changes (whole or by delta) for the first time
    /// since then.
    pub(super) fn capture_preimages(&mut self, batch: &CommitBatch) {
        self.snapshots_running
            .retain(|s| Arc::strong_count(s) > 1 && s.aborted().is_none());
        if self.snapshots_running.is_empty() {
            return;
        }
        let changed: BTreeSet<ChunkPos> = batch
            .entries
            .iter()
            .flat_map(|e| e.changes.iter().map(|&(p, _)| p))
            .collect();
        for pos in &changed {
            if self.snapshots_running.iter().all(|s| s.has(*pos)) {
                continue;
            }
            // Not yet recorded, so unchanged since the snapshot's seq: the
            // store's newest state (record plus deltas) is its state then.
            let before = if self.versions.contains_key(pos) {
                match self.store.raw_chunk(*pos) {
                    Ok(b) => b,
                    Err(e) => {
                        for s in &self.snapshots_running {
                            s.abort(format!("store read failed: {e}"));
                        }
                        return;
                    }
                }
            } else {
                None
            };
            for s in &self.snapshots_running {
                s.record(*pos, &before);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{ChunkStore, LogEntry, SledStore, WorldMeta};
    use strata_terrain::chunk_codec::encode_chunk;
    use strata_terrain::material::ids;
    use strata_terrain::{Chunk, Edit, Fixed, FixedVec3, MaterialId, Voxel};

    /// Commits edit `seq`, which moves each chunk to a version and material.
    fn commit(store: &SledStore, seq: u64, chunks: &[(ChunkPos, u64, MaterialId)]) {
        let batch = CommitBatch {
            entries: vec![LogEntry {
                seq,
                player: "p".into(),
                time_ms: seq,
                edit: Edit::Mine {
                    center: FixedVec3::from_voxels(0, 0, 0),
                    radius: Fixed::from_voxels(1),
                    strength: 1,
                },
                changes: chunks.iter().map(|&(p, v, _)| (p, v)).collect(),
            }],
            chunks: chunks
                .iter()
                .map(|&(p, v, m)| (p, v, Chunk::Uniform(Voxel::solid(m)).into()))
                .collect(),
            deltas: Vec::new(),
            generated: Vec::new(),
            last_seq: seq,
            epochs: None,
        };
        store.commit_batch(&batch).unwrap();
    }

    fn raw(pos: ChunkPos, version: u64, m: MaterialId) -> RawChunk {
        RawChunk {
            pos,
            version,
            encoded: encode_chunk(&Chunk::Uniform(Voxel::solid(m))),
        }
    }

    /// What the engine does before a commit, for one snapshot.
    fn capture(store: &SledStore, pre: &PreImages, chunks: &[(ChunkPos, u64, MaterialId)]) {
        for &(pos, _, _) in chunks {
            if !pre.has(pos) {
                pre.record(pos, &store.raw_chunk(pos).unwrap());
            }
        }
    }

    #[test]
    fn a_store_walk_through_pre_images_sees_the_world_at_the_seq() {
        let tmp = tempfile::tempdir().unwrap();
        let store = SledStore::open(tmp.path()).unwrap();
        store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
        let [a, b, c, new] =
            [(0, 0, 0), (1, 0, 0), (2, 0, 0), (1, 5, 0)].map(|(x, y, z)| ChunkPos::new(x, y, z));
        commit(
            &store,
            1,
            &[(a, 1, ids::STONE), (b, 1, ids::DIRT), (c, 1, ids::STONE)],
        );

        let pre = PreImages::new(1, 8, DEFAULT_SNAPSHOT_PREIMAGE_BYTES);
        assert_eq!(pre.seq(), 1);
        // Seq 2 changes `a` and creates `new`; seq 3 changes both again.
        let seq2 = [(a, 2, ids::DIRT), (new, 1, ids::DIRT)];
        capture(&store, &pre, &seq2);
        commit(&store, 2, &seq2);
        let seq3 = [(a, 3, ids::STONE), (new, 2, ids::STONE)];
        capture(&store, &pre, &seq3);
        // A late record of a chunk already saved keeps the first pre-image.
        pre.record(a, &Some(raw(a, 2, ids::DIRT)));
        commit(&store, 3, &seq3);
        assert_eq!(pre.len(), 2);
        assert!(pre.aborted().is_none());

        // New chunks resolve to nothing, changed ones to their seq-1 state,
        // untouched ones to the record read.
        assert_eq!(pre.resolve(raw(new, 2, ids::STONE)), None);
        assert_eq!(
            pre.resolve(raw(a, 3, ids::STONE)),
            Some(raw(a, 1, ids::STONE))
        );
        assert_eq!(
            pre.resolve(raw(b, 1, ids::DIRT)),
            Some(raw(b, 1, ids::DIRT))
        );
        let walked: Vec<RawChunk> = store
            .raw_chunks()
            .filter_map(|r| pre.resolve(r.unwrap()))
            .collect();
        assert_eq!(
            walked,
            vec![
                raw(a, 1, ids::STONE),
                raw(b, 1, ids::DIRT),
                raw(c, 1, ids::STONE)
            ]
        );
    }

    #[test]
    fn past_its_limit_a_snapshot_aborts_with_a_reason_and_saves_nothing() {
        let tmp = tempfile::tempdir().unwrap();
        let store = SledStore::open(tmp.path()).unwrap();
        store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
        let pos: Vec<ChunkPos> = (0..4).map(|x| ChunkPos::new(x, 0, 0)).collect();
        commit(
            &store,
            1,
            &[(pos[0], 1, ids::STONE), (pos[1], 1, ids::STONE)],
        );

        let pre = PreImages::new(1, 3, DEFAULT_SNAPSHOT_PREIMAGE_BYTES);
        let seq2: Vec<_> = pos
            .iter()
            .map(|&p| (p, if p.x < 2 { 2 } else { 1 }, ids::DIRT))
            .collect();
        capture(&store, &pre, &seq2[..3]);
        assert_eq!(pre.len(), 3);
        assert!(pre.aborted().is_none());
        // The fourth distinct chunk is one past the limit.
        capture(&store, &pre, &seq2[3..]);
        let reason = pre.aborted().expect("aborted");
        assert!(reason.contains("more than 3 chunks changed"), "{reason}");
        assert!(pre.is_empty(), "the saved pre-images are dropped");
        // Nothing more is saved, and the engine no longer reads for it.
        assert!(pre.has(ChunkPos::new(9, 9, 9)));
        pre.record(ChunkPos::new(9, 9, 9), &None);
        assert!(pre.is_empty());
        // The first reason stays.
        pre.abort("store read failed".into());
        assert_eq!(pre.aborted(), Some(reason));
    }

    #[test]
    fn past_its_byte_bound_a_snapshot_aborts_however_few_chunks_changed() {
        let pre = PreImages::new(1, MAX_SNAPSHOT_PREIMAGES, 1 << 20);
        let big = |x| {
            Some(RawChunk {
                pos: ChunkPos::new(x, 0, 0),
                version: 1,
                encoded: vec![0; 64 << 10],
            })
        };
        let fit = 16;
        for x in 0..fit {
            pre.record(ChunkPos::new(x, 0, 0), &big(x));
        }
        assert!(pre.aborted().is_none());
        assert_eq!(pre.len(), fit as usize);
        pre.record(ChunkPos::new(fit, 0, 0), &big(fit));
        let reason = pre.aborted().expect("aborted");
        assert!(reason.contains("more than 1024 KiB"), "{reason}");
        assert!(pre.is_empty());
    }
}
