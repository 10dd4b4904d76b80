//! Voxel and chunk coordinates. Y is up, the frame is right-handed.

use serde::{Deserialize, Serialize};

/// Edge length of a chunk in voxels.
pub const CHUNK_SIZE: i32 = 32;
/// log2 of [`CHUNK_SIZE`].
pub const CHUNK_SHIFT: u32 = 5;
/// Voxels in one chunk.
pub const CHUNK_VOLUME: usize = (CHUNK_SIZE * CHUNK_SIZE * CHUNK_SIZE) as usize;

/// A voxel in world space.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct VoxelPos {
    pub x: i32,
    pub y: i32,
    pub z: i32,
}

/// A chunk: the voxel position floor-divided by [`CHUNK_SIZE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ChunkPos {
    pub x: i32,
    pub y: i32,
    pub z: i32,
}

impl VoxelPos {
    pub const fn new(x: i32, y: i32, z: i32) -> Self {
        Self { x, y, z }
    }

    /// The chunk holding this voxel (floor division, so -1 is in chunk -1).
    pub const fn chunk(self) -> ChunkPos {
        ChunkPos {
            x: self.x >> CHUNK_SHIFT,
            y: self.y >> CHUNK_SHIFT,
            z: self.z >> CHUNK_SHIFT,
        }
    }

    /// Coordinates inside its chunk, each in `0..32`.
    pub const fn local(self) -> (usize, usize, usize) {
        let m = CHUNK_SIZE - 1;
        ((self.x & m) as usize, (self.y & m) as usize, (self.z & m) as usize)
    }

    /// Checked component-wise offset; `None` on i32 overflow.
    pub fn checked_offset(self, dx: i32, dy: i32, dz: i32) -> Option<Self> {
        Some(Self::new(
            self.x.checked_add(dx)?,
            self.y.checked_add(dy)?,
            self.z.checked_add(dz)?,
        ))
    }
}

impl ChunkPos {
    pub const fn new(x: i32, y: i32, z: i32) -> Self {
        Self { x, y, z }
    }

    /// World position of this chunk's minimum voxel.
    pub const fn origin(self) -> VoxelPos {
        VoxelPos {
            x: self.x.wrapping_shl(CHUNK_SHIFT),
            y: self.y.wrapping_shl(CHUNK_SHIFT),
            z: self.z.wrapping_shl(CHUNK_SHIFT),
        }
    }

    /// Chebyshev distance in chunks.
    pub fn chebyshev(self, o: ChunkPos) -> u32 {
        let d = |a: i32, b: i32| (a as i64 - b as i64).unsigned_abs();
        d(self.x, o.x).max(d(self.y, o.y)).max(d(self.z, o.z)) as u32
    }

    /// The neighbour at the given offset, if it does not overflow.
    pub fn offset(self, dx: i32, dy: i32, dz: i32) -> Option<Self> {
        Some(Self::new(
            self.x.checked_add(dx)?,
            self.y.checked_add(dy)?,
            self.z.checked_add(dz)?,
        ))
    }
}

/// Index of a local coordinate in a chunk's arrays: x fastest, then y, then z.
#[inline]
pub const fn local_index(x: usize, y: usize, z: usize) -> usize {
    x | (y << CHUNK_SHIFT) | (z << (2 * CHUNK_SHIFT))
}

/// Inverse of [`local_index`].
#[inline]
pub const fn index_local(i: usize) -> (usize, usize, usize) {
    let m = CHUNK_SIZE as usize - 1;
    (i & m, (i >> CHUNK_SHIFT) & m, i >> (2 * CHUNK_SHIFT))
}

/// An inclusive axis-aligned box of voxels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct VoxelBox {
    pub min: VoxelPos,
    pub max: VoxelPos,
}

impl VoxelBox {
    /// A box from two corners, in any order.
    pub fn from_corners(a: VoxelPos, b: VoxelPos) -> Self {
        Self {
            min: VoxelPos::new(a.x.min(b.x), a.y.min(b.y), a.z.min(b.z)),
            max: VoxelPos::new(a.x.max(b.x), a.y.max(b.y), a.z.max(b.z)),
        }
    }

    pub fn contains(&self, p: VoxelPos) -> bool {
        (self.min.x..=self.max.x).contains(&p.x)
            && (self.min.y..=self.max.y).contains(&p.y)
            && (self.min.z..=self.max.z).contains(&p.z)
    }

    /// Voxel count, saturating at `u64::MAX`.
    pub fn volume(&self) -> u64 {
        let e = |a: i32, b: i32| (b as i64 - a as i64 + 1).max(0) as u64;
        e(self.min.x, self.max.x)
            .saturating_mul(e(self.min.y, self.max.y))
            .saturating_mul(e(self.min.z, self.max.z))
    }

    pub fn intersect(&self, o: &VoxelBox) -> Option<VoxelBox> {
        let min = VoxelPos::new(
            self.min.x.max(o.min.x),
            self.min.y.max(o.min.y),
            self.min.z.max(o.min.z),
        );
        let max = VoxelPos::new(
            self.max.x.min(o.max.x),
            self.max.y.min(o.max.y),
            self.max.z.min(o.max.z),
        );
        (min.x <= max.x && min.y <= max.y && min.z <= max.z).then_some(VoxelBox { min, max })
    }

    pub fn union(&self, o: &VoxelBox) -> VoxelBox {
        VoxelBox {
            min: VoxelPos::new(
                self.min.x.min(o.min.x),
                self.min.y.min(o.min.y),
                self.min.z.min(o.min.z),
            ),
            max: VoxelPos::new(
                self.max.x.max(o.max.x),
                self.max.y.max(o.max.y),
                self.max.z.max(o.max.z),
            ),
        }
    }

    /// Chunks this box touches, in (z, y, x) order.
    pub fn chunks(&self) -> impl Iterator<Item = ChunkPos> {
        let (a, b) = (self.min.chunk(), self.max.chunk());
        (a.z..=b.z).flat_map(move |z| {
            (a.y..=b.y).flat_map(move |y| (a.x..=b.x).map(move |x| ChunkPos::new(x, y, z)))
        })
    }

    /// The voxels of one chunk that lie in this box.
    pub fn within_chunk(&self, c: ChunkPos) -> Option<VoxelBox> {
        let o = c.origin();
        let chunk = VoxelBox {
            min: o,
            max: VoxelPos::new(o.x + CHUNK_SIZE - 1, o.y + CHUNK_SIZE - 1, o.z + CHUNK_SIZE - 1),
        };
        self.intersect(&chunk)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_division_for_negatives() {
        assert_eq!(VoxelPos::new(-1, 0, 31).chunk(), ChunkPos::new(-1, 0, 0));
        assert_eq!(VoxelPos::new(-32, -33, 32).chunk(), ChunkPos::new(-1, -2, 1));
        assert_eq!(VoxelPos::new(-1, -32, 5).local(), (31, 0, 5));
        assert_eq!(ChunkPos::new(-2, 0, 1).origin(), VoxelPos::new(-64, 0, 32));
    }

    #[test]
    fn index_round_trip() {
        for i in [0, 1, 31, 32, 1023, 1024, CHUNK_VOLUME - 1] {
            let (x, y, z) = index_local(i);
            assert_eq!(local_index(x, y, z), i);
        }
        assert_eq!(local_index(1, 2, 3), 1 + 2 * 32 + 3 * 1024);
    }

    #[test]
    fn box_chunks_cover_negative_corners() {
        let b = VoxelBox::from_corners(VoxelPos::new(-1, -1, -1), VoxelPos::new(0, 0, 0));
        assert_eq!(b.chunks().count(), 8);
        assert_eq!(b.volume(), 8);
        let inner = b.within_chunk(ChunkPos::new(-1, -1, -1)).unwrap();
        assert_eq!(inner.volume(), 1);
    }
}
