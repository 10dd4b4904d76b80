//! The chunks a session still needs sent: an ordered queue with a set
//! beside it, so a resync or a new view asks "already queued?" in constant
//! time instead of scanning a queue as long as the view (a client can send
//! such requests as fast as its request tokens allow).

use std::collections::VecDeque;

use rustc_hash::FxHashSet;
use strata_terrain::ChunkPos;

/// A queue of distinct chunks.
#[derive(Debug, Default)]
pub struct Pending {
    order: VecDeque<ChunkPos>,
    queued: FxHashSet<ChunkPos>,
}

impl Pending {
    #[cfg(test)]
    pub fn contains(&self, pos: ChunkPos) -> bool {
        self.queued.contains(&pos)
    }

    /// Queues `pos` last unless it is queued already; whether it was added.
    pub fn push_back(&mut self, pos: ChunkPos) -> bool {
        let new = self.queued.insert(pos);
        if new {
            self.order.push_back(pos);
        }
        new
    }

    /// Queues `pos` first unless it is queued already (where it stays).
    pub fn push_front(&mut self, pos: ChunkPos) -> bool {
        let new = self.queued.insert(pos);
        if new {
            self.order.push_front(pos);
        }
        new
    }

    pub fn pop_front(&mut self) -> Option<ChunkPos> {
        let pos = self.order.pop_front()?;
        self.queued.remove(&pos);
        Some(pos)
    }

    /// Keeps the chunks for which `keep` is true, in order.
    pub fn retain(&mut self, mut keep: impl FnMut(ChunkPos) -> bool) {
        let queued = &mut self.queued;
        self.order.retain(|p| {
            let k = keep(*p);
            if !k {
                queued.remove(p);
            }
            k
        });
    }

    /// Re-orders the queue by `key`, smallest first (stable).
    pub fn sort_by_key<K: Ord>(&mut self, key: impl FnMut(&ChunkPos) -> K) {
        self.order.make_contiguous().sort_by_key(key);
    }

    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.order.len()
    }

    pub fn iter(&self) -> impl Iterator<Item = ChunkPos> + '_ {
        self.order.iter().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn holds_each_chunk_once_in_order() {
        let c = |x| ChunkPos::new(x, 0, 0);
        let mut q = Pending::default();
        assert!(q.push_back(c(1)));
        assert!(q.push_back(c(2)));
        assert!(!q.push_back(c(1)), "queued already");
        assert!(q.push_front(c(3)));
        assert!(!q.push_front(c(2)), "stays where it is");
        assert_eq!(q.iter().collect::<Vec<_>>(), [c(3), c(1), c(2)]);
        q.retain(|p| p != c(1));
        assert!(!q.contains(c(1)) && q.contains(c(2)));
        q.sort_by_key(|p| -p.x);
        assert_eq!(q.pop_front(), Some(c(3)));
        assert!(!q.contains(c(3)));
        assert_eq!(q.len(), 1);
        assert!(q.push_back(c(3)), "queued again once sent");
        assert_eq!(q.pop_front(), Some(c(2)));
        assert_eq!(q.pop_front(), Some(c(3)));
        assert!(q.is_empty() && q.pop_front().is_none());
    }
}
