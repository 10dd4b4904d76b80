//! A bounded cache of generated chunks, oldest first out. Generation is a
//! pure function of the position, so entries never go stale. Lookups are
//! counted in `strata_generated_chunks_total{cache, outcome}`, so an
//! operator can see a cache too small for the players' spread.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use rayon::prelude::*;

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
        if let Some(c) = self.lookup(pos) {
            return c;
        }
        let c = Arc::new(generator.generate(pos));
        self.keep_generated(pos, c.clone());
        c
    }

    /// [`Self::get`] of each of `positions` (distinct), in order; those not
    /// cached are generated in parallel on the current rayon pool.
    pub fn get_many(
        &mut self,
        positions: &[ChunkPos],
        generator: &dyn ChunkGenerator,
    ) -> Vec<Arc<Chunk>> {
        let cached: Vec<Option<Arc<Chunk>>> = positions.iter().map(|&p| self.hit(p)).collect();
        let made: Vec<Arc<Chunk>> = positions
            .par_iter()
            .zip(&cached)
            .filter(|(_, c)| c.is_none())
            .map(|(&p, _)| Arc::new(generator.generate(p)))
            .collect();
        self.count(positions.len() - made.len(), made.len());
        let mut made = made.into_iter();
        positions
            .iter()
            .zip(cached)
            .map(|(&p, c)| {
                c.unwrap_or_else(|| {
                    let c = made.next().expect("one generated chunk per miss");
                    self.keep(p, c.clone());
                    c
                })
            })
            .collect()
    }

    /// The cached chunk at `pos`, counted as a hit; `None` counts nothing:
    /// the caller generates it and hands it to [`Self::keep_generated`].
    pub fn lookup(&self, pos: ChunkPos) -> Option<Arc<Chunk>> {
        let c = self.hit(pos)?;
        self.count(1, 0);
        Some(c)
    }

    /// Keeps a chunk generated after a [`Self::lookup`] missed, counted
    /// as generated.
    pub fn keep_generated(&mut self, pos: ChunkPos, chunk: Arc<Chunk>) {
        self.count(0, 1);
        self.keep(pos, chunk);
    }

    fn hit(&self, pos: ChunkPos) -> Option<Arc<Chunk>> {
        self.chunks.get(&pos).cloned()
    }

    /// Counts a lookup's hits and generated chunks, once per call (a
    /// labelled counter's lookup costs more than the cache's own).
    fn count(&self, hits: usize, generated: usize) {
        if hits > 0 {
            metrics::counter!(m::GENERATED_CHUNKS, "cache" => self.label, "outcome" => "hit")
                .increment(hits as u64);
        }
        if generated > 0 {
            metrics::counter!(m::GENERATED_CHUNKS, "cache" => self.label, "outcome" => "generated")
                .increment(generated as u64);
        }
    }

    fn keep(&mut self, pos: ChunkPos, chunk: Arc<Chunk>) {
        if self.chunks.insert(pos, chunk).is_none() {
            self.order.push_back(pos);
        }
        while self.order.len() > self.capacity {
            if let Some(old) = self.order.pop_front() {
                self.chunks.remove(&old);
            }
        }
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

    #[test]
    fn many_at_once_are_the_chunks_one_at_a_time() {
        let g = Generator::fractal(GenParams::default()).expect("valid params");
        let mut cache = GeneratedCache::new(3, Use::PatchBase);
        let kept = cache.get(ChunkPos::new(1, 0, 0), &g);
        let positions: Vec<ChunkPos> = (0..3).map(|x| ChunkPos::new(x, -1 + x % 2, 0)).collect();
        let many = cache.get_many(&positions, &g);
        assert_eq!(many.len(), 3);
        for (p, c) in positions.iter().zip(&many) {
            assert_eq!(**c, g.generate(*p), "{p:?}");
        }
        assert!(
            Arc::ptr_eq(&many[1], &kept),
            "a cached chunk is not generated again"
        );
        // Each kept once, up to the capacity.
        assert_eq!((cache.chunks.len(), cache.order.len()), (3, 3));
        assert!(Arc::ptr_eq(&cache.get(positions[2], &g), &many[2]));
    }
}
