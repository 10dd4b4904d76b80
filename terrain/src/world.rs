//! An in-memory chunked world: generated chunks on demand, plus versions.
//!
//! This is the I/O-free core the server's sequencer drives: feed an edit in,
//! get changed chunks and their new versions out.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;

use crate::chunk::{Chunk, Voxel};
use crate::pos::{ChunkPos, VoxelPos};

/// Produces the unmodified (version 0) state of any chunk.
///
/// Implementations must be pure: the same position gives the same chunk on
/// every call, run, thread count and platform.
pub trait ChunkGenerator: Send + Sync + std::fmt::Debug {
    fn generate(&self, pos: ChunkPos) -> Chunk;
}

/// A generator that fills every chunk below `y = 0` with one voxel and
/// leaves the rest air. Used by tests and as a trivial flat world.
#[derive(Debug, Clone, Copy)]
pub struct FlatGenerator {
    pub ground: Voxel,
}

impl ChunkGenerator for FlatGenerator {
    fn generate(&self, pos: ChunkPos) -> Chunk {
        if pos.y < 0 {
            Chunk::uniform(self.ground)
        } else {
            Chunk::uniform(Voxel::AIR)
        }
    }
}

/// The highest chunk version a store, snapshot or peer may hand over (what
/// PostgreSQL's `bigint` holds). Edits would take 2^63 years to reach it;
/// a record above it is corrupt, and refusing it keeps every `+ 1` exact.
pub const MAX_CHUNK_VERSION: u64 = i64::MAX as u64;

/// A chunk plus its version: 0 means "as generated", and every edit that
/// changes the chunk raises it by one.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VersionedChunk {
    /// Shared: a reader that needs the state beyond a borrow (a background
    /// job, a snapshot's pre-image) holds it without a copy; a change
    /// replaces it, never writes it in place.
    pub chunk: Arc<Chunk>,
    pub version: u64,
}

/// Read access to voxels by world position.
pub trait VoxelRead {
    fn voxel(&self, p: VoxelPos) -> Voxel;
}

/// Whole-chunk reads, for bulk readers (mesh aprons, map slices) that would
/// otherwise pay a lookup, or a generation, per voxel.
pub trait ChunkRead: VoxelRead {
    /// The chunk at `pos`: borrowed if held, else generated (not cached).
    fn chunk_at(&self, pos: ChunkPos) -> Cow<'_, Chunk>;
}

/// Chunks by position, generating missing ones on first use.
#[derive(Debug, Clone)]
pub struct World {
    generator: Arc<dyn ChunkGenerator>,
    /// foldhash: seeded per process like std's SipHash (a client cannot
    /// plan collisions offline), several times faster on a `ChunkPos`.
    chunks: HashMap<ChunkPos, VersionedChunk, foldhash::fast::RandomState>,
}

impl World {
    pub fn new(generator: Arc<dyn ChunkGenerator>) -> Self {
        Self {
            generator,
            chunks: HashMap::default(),
        }
    }

    pub fn generator(&self) -> &Arc<dyn ChunkGenerator> {
        &self.generator
    }

    /// The chunk at `pos`, generating and caching it at version 0 if absent.
    pub fn chunk(&mut self, pos: ChunkPos) -> &VersionedChunk {
        self.entry(pos)
    }

    fn entry(&mut self, pos: ChunkPos) -> &mut VersionedChunk {
        let generator = &self.generator;
        self.chunks.entry(pos).or_insert_with(|| VersionedChunk {
            chunk: Arc::new(generator.generate(pos)),
            version: 0,
        })
    }

    /// The chunk at `pos` if it is loaded.
    pub fn peek(&self, pos: ChunkPos) -> Option<&VersionedChunk> {
        self.chunks.get(&pos)
    }

    /// Makes sure every listed chunk is loaded.
    pub fn load(&mut self, positions: impl IntoIterator<Item = ChunkPos>) {
        for p in positions {
            self.entry(p);
        }
    }

    /// Replaces a chunk and its version (restore, store load, replication).
    /// Readers of stored or received chunks refuse versions above
    /// [`MAX_CHUNK_VERSION`], and edits refuse a chunk at it, so a
    /// commit's `+ 1` never leaves it.
    pub fn insert(&mut self, pos: ChunkPos, chunk: impl Into<Arc<Chunk>>, version: u64) {
        let chunk = chunk.into();
        self.chunks.insert(pos, VersionedChunk { chunk, version });
    }

    /// Sets a chunk to a new state and bumps its version; returns the new version.
    pub fn commit(&mut self, pos: ChunkPos, chunk: Chunk) -> u64 {
        self.commit_replace(pos, chunk).0
    }

    /// [`Self::commit`] that also hands back the state it replaced.
    pub fn commit_replace(&mut self, pos: ChunkPos, mut chunk: Chunk) -> (u64, Arc<Chunk>) {
        chunk.compact();
        let e = self.entry(pos);
        let before = std::mem::replace(&mut e.chunk, Arc::new(chunk));
        e.version += 1;
        (e.version, before)
    }

    /// The voxel at `p`, generating its chunk if needed.
    pub fn voxel_mut_load(&mut self, p: VoxelPos) -> Voxel {
        let (x, y, z) = p.local();
        self.entry(p.chunk()).chunk.get(x, y, z)
    }

    /// Loaded chunks whose version is above 0 (they differ from generation).
    pub fn modified(&self) -> impl Iterator<Item = (ChunkPos, &VersionedChunk)> {
        self.chunks
            .iter()
            .filter(|(_, c)| c.version > 0)
            .map(|(p, c)| (*p, c))
    }

    /// Moves the listed chunks that are loaded into a new world with the
    /// same generator, so disjoint parts of a world can be edited on
    /// different threads; [`Self::absorb`] puts them back.
    pub fn extract(&mut self, positions: impl IntoIterator<Item = ChunkPos>) -> World {
        let mut part = World::new(self.generator.clone());
        for p in positions {
            if let Some(c) = self.chunks.remove(&p) {
                part.chunks.insert(p, c);
            }
        }
        part
    }

    /// Moves every chunk of `part` (extracted, then edited or generated)
    /// into this world, replacing what is here.
    pub fn absorb(&mut self, part: World) {
        self.chunks.extend(part.chunks);
    }

    /// Number of loaded chunks.
    pub fn loaded(&self) -> usize {
        self.chunks.len()
    }

    /// Drops unmodified chunks for which `keep` is false; they regenerate on
    /// demand. Returns them, for the caller to free where it suits.
    pub fn evict_generated(&mut self, keep: impl Fn(ChunkPos) -> bool) -> Vec<VersionedChunk> {
        self.take_where(|p, c| c.version == 0 && !keep(p))
    }

    /// Drops every chunk for which `keep` is false, modified ones too: only
    /// for callers that hold the modified chunks elsewhere (a store) and
    /// load them again before reading. Returns the dropped chunks: freeing
    /// thousands of them takes milliseconds, which the caller may spend on
    /// another thread.
    pub fn evict(&mut self, keep: impl Fn(ChunkPos) -> bool) -> Vec<VersionedChunk> {
        self.take_where(|p, _| !keep(p))
    }

    fn take_where(
        &mut self,
        drop: impl Fn(ChunkPos, &VersionedChunk) -> bool,
    ) -> Vec<VersionedChunk> {
        let gone: Vec<ChunkPos> = self
            .chunks
            .iter()
            .filter(|(p, c)| drop(**p, c))
            .map(|(p, _)| *p)
            .collect();
        gone.iter().filter_map(|p| self.chunks.remove(p)).collect()
    }
}

impl ChunkRead for World {
    fn chunk_at(&self, pos: ChunkPos) -> Cow<'_, Chunk> {
        match self.chunks.get(&pos) {
            Some(c) => Cow::Borrowed(&c.chunk),
            None => Cow::Owned(self.generator.generate(pos)),
        }
    }
}

impl VoxelRead for World {
    /// Reads a loaded voxel, or generates its chunk without caching it
    /// (slow: load the chunks first when reading many voxels).
    fn voxel(&self, p: VoxelPos) -> Voxel {
        let (x, y, z) = p.local();
        match self.chunks.get(&p.chunk()) {
            Some(c) => c.chunk.get(x, y, z),
            None => self.generator.generate(p.chunk()).get(x, y, z),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::ids;

    #[test]
    fn extract_moves_loaded_chunks_and_absorb_puts_back_edits() {
        let mut w = World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        }));
        let (a, b, c) = (
            ChunkPos::new(0, -1, 0),
            ChunkPos::new(1, -1, 0),
            ChunkPos::new(5, -1, 0),
        );
        w.load([a, b]);
        w.commit(a, Chunk::uniform(Voxel::AIR));
        // `c` is not loaded: the part generates it on demand.
        let mut part = w.extract([a, c]);
        assert_eq!((w.loaded(), part.loaded()), (1, 1));
        assert!(w.peek(a).is_none() && part.peek(a).unwrap().version == 1);
        part.commit(c, Chunk::uniform(Voxel::AIR));
        w.absorb(part);
        assert_eq!(w.loaded(), 3);
        assert_eq!(w.peek(a).unwrap().version, 1);
        assert_eq!(w.peek(c).unwrap().version, 1);
        assert_eq!(w.peek(b).unwrap().version, 0);
    }

    #[test]
    fn a_shared_state_never_changes_under_its_holder() {
        let mut w = World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        }));
        let p = ChunkPos::new(0, -1, 0);
        let held = w.chunk(p).chunk.clone();
        let mut next = Chunk::clone(&held);
        next.set(1, 2, 3, Voxel::AIR);
        let (v, before) = w.commit_replace(p, next.clone());
        assert_eq!(v, 1);
        // The state replaced is the one shared, not a copy, and unchanged.
        assert!(Arc::ptr_eq(&before, &held));
        assert_eq!(*held, Chunk::uniform(Voxel::solid(ids::STONE)));
        assert_eq!(*w.peek(p).unwrap().chunk, next);
        // A world's clone shares its chunks; changing one leaves the other.
        let copy = w.clone();
        assert!(Arc::ptr_eq(
            &copy.peek(p).unwrap().chunk,
            &w.peek(p).unwrap().chunk
        ));
        w.commit(p, Chunk::uniform(Voxel::AIR));
        assert_eq!(*copy.peek(p).unwrap().chunk, next);
    }

    #[test]
    fn generates_on_demand_and_versions() {
        let mut w = World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        }));
        let p = ChunkPos::new(0, -1, 0);
        assert_eq!(w.chunk(p).version, 0);
        assert_eq!(w.voxel(VoxelPos::new(0, -1, 0)), Voxel::solid(ids::STONE));
        assert_eq!(w.voxel(VoxelPos::new(0, 0, 0)), Voxel::AIR);
        let mut c = Chunk::clone(&w.chunk(p).chunk);
        c.set(0, 0, 0, Voxel::AIR);
        assert_eq!(w.commit(p, c), 1);
        assert_eq!(w.modified().count(), 1);
        w.load([ChunkPos::new(5, 5, 5)]);
        w.evict_generated(|_| false);
        assert_eq!(w.loaded(), 1);
    }
}
