//! Which sessions hold each chunk, so a tick's fan-out visits only the
//! sessions holding something it changed rather than every session.
//!
//! The index lists every (chunk, session) pair in some session's `known`,
//! and possibly a few more: a pair is added when a chunk is streamed to a
//! session and removed when the chunk leaves the session's view, when the
//! client forgets it or when the session ends. A chunk dropped for a resend
//! stays listed until the fan-out next finds the session does not hold it
//! (a stale pair costs one lookup and is then removed). Every pair lies in
//! a live session's view (a chunk leaving the view is unlisted, and an
//! ending session is unlisted for its whole view), so the index is bounded
//! by the sessions' views.

use rustc_hash::FxHashMap;
use strata_terrain::ChunkPos;

#[derive(Debug, Default)]
pub struct Holders {
    by_chunk: FxHashMap<ChunkPos, Vec<u64>>,
}

impl Holders {
    /// Lists `session` as holding `pos` (once, however often it is told).
    pub fn add(&mut self, pos: ChunkPos, session: u64) {
        let ids = self.by_chunk.entry(pos).or_default();
        if !ids.contains(&session) {
            ids.push(session);
        }
    }

    /// Unlists `session` for `pos`.
    pub fn remove(&mut self, pos: ChunkPos, session: u64) {
        if let Some(ids) = self.by_chunk.get_mut(&pos) {
            ids.retain(|&s| s != session);
            if ids.is_empty() {
                self.by_chunk.remove(&pos);
            }
        }
    }

    /// The sessions listed for `pos`.
    pub fn of(&self, pos: ChunkPos) -> &[u64] {
        self.by_chunk.get(&pos).map_or(&[], Vec::as_slice)
    }

    /// Whether `session` is listed for `pos`.
    pub fn lists(&self, pos: ChunkPos, session: u64) -> bool {
        self.of(pos).contains(&session)
    }

    /// (chunk, session) pairs listed.
    #[cfg(test)]
    pub fn pairs(&self) -> usize {
        self.by_chunk.values().map(Vec::len).sum()
    }

    pub fn clear(&mut self) {
        self.by_chunk.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_each_pair_once_and_forgets_empty_chunks() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let mut h = Holders::default();
        h.add(a, 1);
        h.add(a, 1);
        h.add(a, 2);
        h.add(b, 2);
        assert_eq!(h.of(a), &[1, 2]);
        assert_eq!(h.pairs(), 3);
        h.remove(a, 1);
        h.remove(a, 7);
        assert_eq!(h.of(a), &[2]);
        h.remove(b, 2);
        assert!(h.of(b).is_empty());
        assert!(!h.by_chunk.contains_key(&b), "no empty lists kept");
        assert!(h.lists(a, 2) && !h.lists(a, 1));
    }
}
