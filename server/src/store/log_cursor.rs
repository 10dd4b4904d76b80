//! A place in the edit log that misses no entry on a cluster.
//!
//! One process numbers its edits in the order it logs them, so a single
//! seq is a place in its log. A cluster's nodes number from seq blocks of
//! their own (`pg/seqs.rs`): an entry one node logs after another node's
//! may have the lower seq, and a reader that kept only the highest seq it
//! saw would skip it. So the cursor keeps the last seq it read in each
//! segment ([`ChunkStore::log_segments`]: a node's block), each read in
//! seq order, and asks for every segment begun after the newest it knows
//! (a node may fill blocks between two reads; blocks are reserved, and
//! become visible, in seq order).

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use super::{ChunkStore, LogEntry, StoreError};

/// How long a segment no longer written (its node went on to a newer
/// block, or stopped) is still read: a commit of its node's may have been
/// under way, and is done or given up within this (past the longest
/// `[store.postgres] statement_timeout_ms`, 600 s).
pub const DEAD_SEGMENT_KEPT: Duration = Duration::from_secs(900);

/// Which segments [`ChunkStore::log_segments`] lists besides each node's
/// newest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentsAlso {
    /// Those a cursor starting at the log's end may still see written:
    /// no longer a node's newest for less than [`DEAD_SEGMENT_KEPT`] (a
    /// node's engine finishes a tick in its block after its lease thread
    /// reserved the next).
    Recent,
    /// Those begun after this first seq (a node may fill blocks between
    /// two reads).
    After(u64),
}

/// Part of the edit log written in seq order: seqs `first..=last`, of
/// which `head` is the highest logged (`first - 1` while none is).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LogSegment {
    pub first: u64,
    pub last: u64,
    pub head: u64,
}

#[derive(Debug, Clone)]
struct Seg {
    last: u64,
    /// The highest seq read in it.
    seen: u64,
    /// Since when it is no longer written.
    gone_since: Option<Instant>,
}

/// The last seq read in each segment of the log.
#[derive(Debug, Clone, Default)]
pub struct LogCursor {
    segs: BTreeMap<u64, Seg>,
    /// The first seq of the newest segment known (kept when a segment is
    /// forgotten: one past it is never read again from its start).
    newest: u64,
}

impl LogCursor {
    /// At the log's end now: what is logged from now on is read.
    pub fn at_end(store: &dyn ChunkStore) -> Result<Self, StoreError> {
        let segs: BTreeMap<u64, Seg> = store
            .log_segments(SegmentsAlso::Recent)?
            .into_iter()
            .map(|s| {
                let seg = Seg {
                    last: s.last,
                    seen: s.head,
                    gone_since: None,
                };
                (s.first, seg)
            })
            .collect();
        let newest = segs.keys().next_back().copied().unwrap_or(0);
        Ok(Self { segs, newest })
    }

    /// Calls `f` with each entry logged past the cursor (in seq order
    /// within each segment) and moves past it. A segment begun since (a
    /// node's new block) is read from its start; one no longer written is
    /// read up to its end for [`DEAD_SEGMENT_KEPT`], then forgotten.
    pub fn read(
        &mut self,
        store: &dyn ChunkStore,
        mut f: impl FnMut(LogEntry),
    ) -> Result<(), StoreError> {
        let now = Instant::now();
        let live: BTreeMap<u64, LogSegment> = store
            .log_segments(SegmentsAlso::After(self.newest))?
            .into_iter()
            .map(|s| (s.first, s))
            .collect();
        for s in live.values() {
            // A segment forgotten (or never known, below the newest: done
            // before the cursor began) is not read again from its start.
            if s.first <= self.newest && !self.segs.contains_key(&s.first) {
                continue;
            }
            self.segs.entry(s.first).or_insert(Seg {
                last: s.last,
                seen: s.first.saturating_sub(1),
                gone_since: None,
            });
            self.newest = self.newest.max(s.first);
        }
        let firsts: Vec<u64> = self.segs.keys().copied().collect();
        for (i, (first, seg)) in self.segs.iter_mut().enumerate() {
            let until = match live.get(first) {
                Some(s) => {
                    seg.gone_since = None;
                    s.head
                }
                None => {
                    seg.gone_since.get_or_insert(now);
                    // Up to its end, below the next segment (the whole log's
                    // one before a cluster's first block).
                    let next = firsts.get(i + 1).map_or(u64::MAX, |n| n - 1);
                    seg.last.min(next)
                }
            };
            if until <= seg.seen {
                continue;
            }
            for entry in store.edit_log(seg.seen + 1..=until) {
                let entry = entry?;
                seg.seen = seg.seen.max(entry.seq);
                f(entry);
            }
        }
        self.segs.retain(|_, s| {
            s.gone_since
                .is_none_or(|t| now.duration_since(t) < DEAD_SEGMENT_KEPT)
        });
        Ok(())
    }

    /// Whether entries past the cursor in some segment were pruned
    /// (`[store] log_retention`): they can no longer be read.
    pub fn pruned(&self, store: &dyn ChunkStore) -> Result<bool, StoreError> {
        let mut next: Vec<u64> = self
            .segs
            .values()
            .filter(|s| s.seen < s.last)
            .map(|s| s.seen + 1)
            .collect();
        // Segments begun since, which the next read reads from their start.
        if !self.segs.is_empty() {
            next.extend(
                store
                    .log_segments(SegmentsAlso::After(self.newest))?
                    .iter()
                    .filter(|s| s.first > self.newest)
                    .map(|s| s.first),
            );
        }
        if next.is_empty() {
            return Ok(false);
        }
        store.log_pruned_at_any(&next)
    }
}
