//! Chunks whose visible copy changed since the game last asked: a queue in
//! first-change order that holds each chunk once, so a game that polls
//! rarely re-meshes each chunk once, and the queue never outgrows the
//! chunks the client has seen.

use std::collections::VecDeque;

use rustc_hash::FxHashSet as HashSet;
use strata_terrain::ChunkPos;

/// Changed chunks, oldest change first, each at most once.
#[derive(Debug, Default)]
pub struct ChangedChunks {
    order: VecDeque<ChunkPos>,
    queued: HashSet<ChunkPos>,
}

impl ChangedChunks {
    /// Notes that `pos` changed (a no-op when it is already queued).
    pub fn mark(&mut self, pos: ChunkPos) {
        if self.queued.insert(pos) {
            self.order.push_back(pos);
        }
    }

    /// The chunk that changed first, removed from the queue.
    pub fn pop(&mut self) -> Option<ChunkPos> {
        let pos = self.order.pop_front()?;
        self.queued.remove(&pos);
        Some(pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_chunk_is_queued_once_in_first_change_order() {
        let mut c = ChangedChunks::default();
        let (a, b) = (ChunkPos::new(1, 0, 0), ChunkPos::new(0, 2, 0));
        c.mark(a);
        c.mark(b);
        c.mark(a);
        assert_eq!(c.pop(), Some(a));
        c.mark(a);
        assert_eq!(c.pop(), Some(b));
        assert_eq!(c.pop(), Some(a));
        assert_eq!(c.pop(), None);
    }
}
