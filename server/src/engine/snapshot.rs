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

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use strata_terrain::ChunkPos;

use super::Engine;
use crate::store::{CommitBatch, RawChunk};

/// Default bound on one snapshot's pre-images (chunks changed while it runs).
pub const DEFAULT_SNAPSHOT_PREIMAGES: usize = 65_536;
/// Largest bound an admin may ask for.
pub const MAX_SNAPSHOT_PREIMAGES: usize = 1 << 20;
/// Snapshots that may run at once.
pub const MAX_CONCURRENT_SNAPSHOTS: usize = 2;

#[derive(Debug, Default)]
struct State {
    map: HashMap<ChunkPos, Option<RawChunk>>,
    aborted: Option<String>,
}

/// One running snapshot's pre-images, shared by the engine and its reader.
/// The engine forgets it once the reader drops its handle.
#[derive(Debug)]
pub struct PreImages {
    seq: u64,
    limit: usize,
    state: Mutex<State>,
}

impl PreImages {
    pub fn new(seq: u64, limit: usize) -> Self {
        Self {
            seq,
            limit,
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
        if s.map.len() >= self.limit {
            s.map.clear();
            s.aborted = Some(format!(
                "more than {} chunks changed while the snapshot ran (raise the pre-image limit)",
                self.limit
            ));
            return;
        }
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
    pub(super) fn begin_snapshot(&mut self, limit: usize) -> Result<Arc<PreImages>, String> {
        self.snapshots_running
            .retain(|s| Arc::strong_count(s) > 1 && s.aborted().is_none());
        if self.snapshots_running.len() >= MAX_CONCURRENT_SNAPSHOTS {
            return Err(format!(
                "{MAX_CONCURRENT_SNAPSHOTS} snapshots are already running"
            ));
        }
        let limit = match limit {
            0 => self.cfg.snapshot_preimages,
            n => n.min(MAX_SNAPSHOT_PREIMAGES),
        };
        let pre = Arc::new(PreImages::new(self.seq.last_seq(), limit));
        self.snapshots_running.push(pre.clone());
        Ok(pre)
    }

    /// Before a commit: saves the state at each running snapshot's seq of
    /// every chunk the batch changes for the first time since then.
    pub(super) fn capture_preimages(&mut self, batch: &CommitBatch) {
        self.snapshots_running
            .retain(|s| Arc::strong_count(s) > 1 && s.aborted().is_none());
        if self.snapshots_running.is_empty() {
            return;
        }
        for (pos, _, _) in &batch.chunks {
            if self.snapshots_running.iter().all(|s| s.has(*pos)) {
                continue;
            }
            // Not yet recorded, so unchanged since the snapshot's seq: the
            // store's current record is its state then.
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
