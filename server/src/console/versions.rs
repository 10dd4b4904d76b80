//! Which chunk columns changed: a stamp per column (the sum of its stored
//! chunks' versions, so it grows with every change), kept current by
//! reading the store's edit log past the place last read (a
//! [`LogCursor`]: on a cluster, nodes' entries come in with seqs below
//! others already read). Tiles are cached under the stamps of their
//! columns.
//!
//! It is built on first use (one scan of the modified chunks) and caught up
//! only when a tile is asked for or a watcher's sample is taken: with no
//! console in use it does nothing.

use std::collections::HashMap;
use std::sync::Mutex;

use strata_terrain::ChunkPos;

use crate::store::{ChunkStore, LogCursor, StoreError};

/// Column stamps and the log place they reflect.
#[derive(Debug, Default)]
pub struct VersionIndex {
    state: Mutex<Option<State>>,
}

#[derive(Debug)]
struct State {
    cursor: LogCursor,
    versions: HashMap<ChunkPos, u64>,
    columns: HashMap<(i32, i32), u64>,
}

impl State {
    fn set(&mut self, pos: ChunkPos, version: u64) {
        set(&mut self.versions, &mut self.columns, pos, version);
    }
}

/// Records `pos` at `version`, adding what it rose by to its column.
fn set(
    versions: &mut HashMap<ChunkPos, u64>,
    columns: &mut HashMap<(i32, i32), u64>,
    pos: ChunkPos,
    version: u64,
) {
    let old = versions.entry(pos).or_insert(0);
    if version > *old {
        *columns.entry((pos.x, pos.z)).or_insert(0) += version - *old;
        *old = version;
    }
}

impl VersionIndex {
    /// Applies the log entries past the place last read (building the
    /// index first if needed).
    pub fn catch_up(&self, store: &dyn ChunkStore) -> Result<(), StoreError> {
        let mut guard = self.state.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            // Entries past the place read were pruned (`[store]
            // log_retention`, a console unused that long): built again
            // from the chunks.
            if let Some(s) = guard.as_ref() {
                if s.cursor.pruned(store)? {
                    *guard = None;
                }
            }
            let state = match &mut *guard {
                Some(s) => s,
                None => {
                    // The log's place first: chunks read after it are at
                    // least that new, and versions only grow, so replaying
                    // later entries is safe.
                    let mut s = State {
                        cursor: LogCursor::at_end(store)?,
                        versions: HashMap::new(),
                        columns: HashMap::new(),
                    };
                    for item in store.modified_chunks() {
                        let (pos, version) = item?;
                        s.set(pos, version);
                    }
                    guard.insert(s)
                }
            };
            let before = state.cursor.clone();
            let State {
                cursor,
                versions,
                columns,
            } = state;
            // Each entry as it comes (a console idle for weeks reads weeks
            // of the log here); what was read before a failure counts.
            cursor.read(store, |entry| {
                for (pos, version) in entry.changes {
                    set(versions, columns, pos, version);
                }
            })?;
            // A prune during the read may have taken entries it skipped.
            if !before.pruned(store)? {
                return Ok(());
            }
            *guard = None;
        }
    }

    /// The stamp of the columns `x0..x0+n`, `z0..z0+n` (0 if never read).
    pub fn stamp(&self, x0: i32, z0: i32, n: i32) -> u64 {
        let guard = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let Some(s) = &*guard else {
            return 0;
        };
        let mut sum = 0u64;
        for z in z0..z0 + n {
            for x in x0..x0 + n {
                sum = sum.wrapping_add(s.columns.get(&(x, z)).copied().unwrap_or(0));
            }
        }
        sum
    }
}
