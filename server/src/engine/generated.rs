//! A bounded cache of generated chunks, oldest first out. Generation is a
//! pure function of the position, so entries never go stale.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use strata_terrain::{Chunk, ChunkGenerator, ChunkPos};

#[derive(Debug)]
pub struct GeneratedCache {
    capacity: usize,
    chunks: HashMap<ChunkPos, Arc<Chunk>>,
    order: VecDeque<ChunkPos>,
}

impl GeneratedCache {
    /// A cache holding at most `capacity` chunks (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            chunks: HashMap::new(),
            order: VecDeque::new(),
        }
    }

    /// The generated chunk at `pos`, from the cache or the generator.
    pub fn get(&mut self, pos: ChunkPos, generator: &dyn ChunkGenerator) -> Arc<Chunk> {
        if let Some(c) = self.chunks.get(&pos) {
            return c.clone();
        }
        let c = Arc::new(generator.generate(pos));
        self.chunks.insert(pos, c.clone());
        self.order.push_back(pos);
        while self.order.len() > self.capacity {
            if let Some(old) = self.order.pop_front() {
                self.chunks.remove(&old);
            }
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::gen::{GenParams, Generator};

    #[test]
    fn keeps_the_newest_chunks_up_to_capacity() {
        let g = Generator::fractal(GenParams::default()).expect("valid params");
        let mut cache = GeneratedCache::new(3);
        let a = cache.get(ChunkPos::new(0, 0, 0), &g);
        assert!(Arc::ptr_eq(&a, &cache.get(ChunkPos::new(0, 0, 0), &g)));
        for x in 1..=3 {
            cache.get(ChunkPos::new(x, 0, 0), &g);
        }
        assert_eq!(cache.chunks.len(), 3);
        let again = cache.get(ChunkPos::new(0, 0, 0), &g);
        assert!(!Arc::ptr_eq(&a, &again), "the oldest was dropped");
        assert_eq!(*a, *again, "and generates the same again");
    }
}
