//! A bounded cache of generated chunks, oldest first out. Generation is a
//! pure function of the position, so entries never go stale. Lookups are
//! counted in `strata_generated_chunks_total{cache, outcome}`, so an
//! operator can see a cache too small for the players' spread.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use strata_terrain::{Chunk, ChunkGenerator, ChunkPos};

use crate::metrics as m;

/// What a cache serves: the `cache` label of its lookups.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Use {
    /// The background mesher's unmodified neighbours.
    Premesh,
    /// The generated forms modified chunks are patched against.
    PatchBase,
}

impl Use {
    fn label(self) -> &'static str {
        match self {
            Use::Premesh => "premesh",
            Use::PatchBase => "patch_base",
        }
    }
}

#[derive(Debug)]
pub struct GeneratedCache {
    capacity: usize,
    label: &'static str,
    chunks: HashMap<ChunkPos, Arc<Chunk>>,
    order: VecDeque<ChunkPos>,
}

impl GeneratedCache {
    /// A cache holding at most `capacity` chunks (at least one).
    pub fn new(capacity: usize, serves: Use) -> Self {
        Self {
            capacity: capacity.max(1),
            label: serves.label(),
            chunks: HashMap::new(),
            order: VecDeque::new(),
        }
    }

    /// The generated chunk at `pos`, from the cache or the generator.
    pub fn get(&mut self, pos: ChunkPos, generator: &dyn ChunkGenerator) -> Arc<Chunk> {
        if let Some(c) = self.chunks.get(&pos) {
            metrics::counter!(m::GENERATED_CHUNKS, "cache" => self.label, "outcome" => "hit")
                .increment(1);
            return c.clone();
        }
        metrics::counter!(m::GENERATED_CHUNKS, "cache" => self.label, "outcome" => "generated")
            .increment(1);
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
        let mut cache = GeneratedCache::new(3, Use::Premesh);
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
