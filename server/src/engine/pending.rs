//! The chunks a session still needs sent: an ordered queue with a set
//! beside it, so a resync or a new view asks "already queued?" in constant
//! time instead of scanning a queue as long as the view (a client can send
//! such requests as fast as its request tokens allow).

use std::collections::VecDeque;

use rustc_hash::FxHashMap;
use strata_terrain::ChunkPos;

/// Dead entries (removed chunks still in the queue) tolerated beyond the
/// live ones before the queue is compacted.
const DEAD_SLACK: usize = 64;

/// A queue of distinct chunks. Removing one costs O(1): its entry stays in
/// the queue, dead, until it reaches the front or a compaction drops it, so
/// a client naming chunks to forget pays for the chunks it names, not for
/// the length of its queue.
#[derive(Debug, Default)]
pub struct Pending {
    /// Chunks with the ticket of their live entry in `order`.
    order: VecDeque<(ChunkPos, u64)>,
    queued: FxHashMap<ChunkPos, u64>,
    next_ticket: u64,
}

impl Pending {
    #[cfg(test)]
    pub fn contains(&self, pos: ChunkPos) -> bool {
        self.queued.contains_key(&pos)
    }

    fn live(&self, (pos, ticket): (ChunkPos, u64)) -> bool {
        self.queued.get(&pos) == Some(&ticket)
    }

    /// A new ticket for `pos` if it is not queued.
    fn admit(&mut self, pos: ChunkPos) -> Option<u64> {
        if self.queued.contains_key(&pos) {
            return None;
        }
        let ticket = self.next_ticket;
        self.next_ticket += 1;
        self.queued.insert(pos, ticket);
        Some(ticket)
    }

    /// Queues `pos` last unless it is queued already; whether it was added.
    pub fn push_back(&mut self, pos: ChunkPos) -> bool {
        let Some(ticket) = self.admit(pos) else {
            return false;
        };
        self.order.push_back((pos, ticket));
        self.compact_if_dead();
        true
    }

    /// Queues `pos` first unless it is queued already (where it stays).
    pub fn push_front(&mut self, pos: ChunkPos) -> bool {
        let Some(ticket) = self.admit(pos) else {
            return false;
        };
        self.order.push_front((pos, ticket));
        self.compact_if_dead();
        true
    }

    pub fn pop_front(&mut self) -> Option<ChunkPos> {
        while let Some(entry) = self.order.pop_front() {
            if self.live(entry) {
                self.queued.remove(&entry.0);
                return Some(entry.0);
            }
        }
        None
    }

    /// Takes `pos` out of the queue if it is there; whether it was.
    pub fn remove(&mut self, pos: ChunkPos) -> bool {
        let was = self.queued.remove(&pos).is_some();
        if was {
            self.compact_if_dead();
        }
        was
    }

    /// Re-orders the queue by `key`, smallest first (stable).
    pub fn sort_by_key<K: Ord>(&mut self, mut key: impl FnMut(&ChunkPos) -> K) {
        self.compact();
        self.order.make_contiguous().sort_by_key(|(p, _)| key(p));
    }

    pub fn is_empty(&self) -> bool {
        self.queued.is_empty()
    }

    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.queued.len()
    }

    pub fn iter(&self) -> impl Iterator<Item = ChunkPos> + '_ {
        self.order
            .iter()
            .copied()
            .filter(|&e| self.live(e))
            .map(|(p, _)| p)
    }

    /// Drops the dead entries once they outnumber the live ones (plus
    /// [`DEAD_SLACK`]): the queue stays under twice its live length.
    fn compact_if_dead(&mut self) {
        if self.order.len() > 2 * self.queued.len() + DEAD_SLACK {
            self.compact();
        }
    }

    fn compact(&mut self) {
        let queued = &self.queued;
        self.order.retain(|(p, t)| queued.get(p) == Some(t));
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
        assert!(q.remove(c(1)));
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

    #[test]
    fn removing_leaves_the_rest_in_order_and_a_chunk_queued_again_goes_where_it_was_put() {
        let c = |x| ChunkPos::new(x, 0, 0);
        let mut q = Pending::default();
        for x in 0..5 {
            q.push_back(c(x));
        }
        assert!(q.remove(c(1)) && q.remove(c(3)));
        assert!(!q.remove(c(3)), "not queued any more");
        assert_eq!(q.iter().collect::<Vec<_>>(), [c(0), c(2), c(4)]);
        assert!(q.push_back(c(1)), "queued again: last, not where it was");
        assert!(q.push_front(c(3)));
        assert_eq!(q.iter().collect::<Vec<_>>(), [c(3), c(0), c(2), c(4), c(1)]);
        assert_eq!(q.len(), 5);
        let mut popped = Vec::new();
        while let Some(p) = q.pop_front() {
            popped.push(p);
        }
        assert_eq!(popped, [c(3), c(0), c(2), c(4), c(1)]);
    }

    #[test]
    fn removals_never_let_the_queue_grow_past_twice_its_live_chunks() {
        let c = |x| ChunkPos::new(x, 0, 0);
        let mut q = Pending::default();
        for x in 0..1000 {
            q.push_back(c(x));
        }
        // Forget and queue again, over and over: dead entries are compacted.
        for round in 0..50 {
            for x in 0..1000 {
                if (x + round) % 3 == 0 {
                    q.remove(c(x));
                    q.push_back(c(x));
                }
            }
            assert!(
                q.order.len() <= 2 * q.len() + DEAD_SLACK,
                "{}",
                q.order.len()
            );
        }
        assert_eq!(q.len(), 1000);
        q.sort_by_key(|p| p.x);
        assert_eq!(
            q.iter().collect::<Vec<_>>(),
            (0..1000).map(c).collect::<Vec<_>>()
        );
        assert_eq!(q.order.len(), 1000, "a sort compacts");
    }
}
