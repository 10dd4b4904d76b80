//! Recycled neighbourhood buffers. Every mesh the server builds first copies
//! its chunk and apron into a [`Neighborhood`]: two 51 KB planes. Taking one
//! back from here skips the allocation, its zeroing and, once the allocator
//! has handed the pages back to the kernel, their page faults.
//!
//! One pool per process, shared by the engine, the tick's lanes, the meshing
//! workers and the premesh thread; it holds at most
//! [`POOLED_NEIGHBORHOODS`] buffers. Nothing a client sends can grow it.

use std::ops::RangeInclusive;
use std::sync::{Mutex, MutexGuard};

use strata_terrain::mesh::Neighborhood;
use strata_terrain::{Chunk, ChunkPos, World};

/// Buffers kept for reuse (about 100 KB each, so 25 MB at most); more are
/// freed. A tick of 3000 players meshes about 150 chunks while the one
/// before it may still hold its buffers: 64 made every other mesh allocate.
pub const POOLED_NEIGHBORHOODS: usize = 256;

static POOL: Mutex<Vec<Neighborhood>> = Mutex::new(Vec::new());

fn pool() -> MutexGuard<'static, Vec<Neighborhood>> {
    // A panic while holding the lock leaves a valid Vec: keep using it.
    POOL.lock().unwrap_or_else(|e| e.into_inner())
}

fn take() -> Option<Neighborhood> {
    pool().pop()
}

/// [`Neighborhood::from_world`] into a recycled buffer when one is free.
pub fn from_world(world: &World, pos: ChunkPos) -> Neighborhood {
    match take() {
        Some(mut nb) => {
            nb.refill_from_world(world, pos);
            nb
        }
        None => Neighborhood::from_world(world, pos),
    }
}

/// [`Neighborhood::refill_layers_from_world`] of `layers` into a recycled
/// buffer when one is free (else a new buffer, copied whole).
pub fn from_world_layers(
    world: &World,
    pos: ChunkPos,
    layers: RangeInclusive<i32>,
) -> Neighborhood {
    match take() {
        Some(mut nb) => {
            nb.refill_layers_from_world(world, pos, layers);
            nb
        }
        None => Neighborhood::from_world(world, pos),
    }
}

/// [`Neighborhood::from_chunks`] into a recycled buffer when one is free.
pub fn from_chunks<'c>(
    pos: ChunkPos,
    get: impl FnMut(ChunkPos) -> Option<&'c Chunk>,
) -> Neighborhood {
    match take() {
        Some(mut nb) => {
            nb.refill_from_chunks(pos, get);
            nb
        }
        None => Neighborhood::from_chunks(pos, get),
    }
}

/// Hands buffers back once their meshes are built; past the bound they are freed.
pub fn recycle(done: impl IntoIterator<Item = Neighborhood>) {
    let mut pool = pool();
    for nb in done {
        if pool.len() >= POOLED_NEIGHBORHOODS {
            break;
        }
        pool.push(nb);
    }
}

/// Buffers waiting for reuse.
pub fn pooled() -> usize {
    pool().len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use strata_terrain::world::FlatGenerator;
    use strata_terrain::{material::ids, Voxel};

    #[test]
    fn recycled_buffers_sample_like_fresh_ones_and_the_pool_stays_bounded() {
        let world = World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        }));
        let (a, b) = (ChunkPos::new(0, -1, 0), ChunkPos::new(5, 0, 2));
        recycle((0..POOLED_NEIGHBORHOODS + 10).map(|_| Neighborhood::from_world(&world, a)));
        // Other tests share the pool (and may take from it meanwhile): what
        // matters is the bound, and that every buffer handed out is refilled.
        assert!(pooled() <= POOLED_NEIGHBORHOODS);
        for pos in [b, a, b] {
            assert_eq!(
                from_world(&world, pos),
                Neighborhood::from_world(&world, pos)
            );
            let fresh = Neighborhood::from_chunks(pos, |_| None);
            assert_eq!(from_chunks(pos, |_| None), fresh);
        }
        assert!(pooled() <= POOLED_NEIGHBORHOODS);
    }
}
