//! A flat box of voxels: the whole-array reference for chunked edits.

use crate::chunk::Voxel;
use crate::pos::{VoxelBox, VoxelPos};
use crate::world::{VoxelRead, World};

/// Voxels of one box in a single array (x fastest, then y, then z).
/// Reads outside the box return `outside`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Region {
    bounds: VoxelBox,
    dims: [usize; 3],
    voxels: Vec<Voxel>,
    outside: Voxel,
}

impl Region {
    /// Copies `bounds` out of any voxel source.
    pub fn from_source(src: &impl VoxelRead, bounds: VoxelBox, outside: Voxel) -> Self {
        let dims = [
            (bounds.max.x - bounds.min.x + 1) as usize,
            (bounds.max.y - bounds.min.y + 1) as usize,
            (bounds.max.z - bounds.min.z + 1) as usize,
        ];
        let mut voxels = Vec::with_capacity(dims.iter().product());
        for z in bounds.min.z..=bounds.max.z {
            for y in bounds.min.y..=bounds.max.y {
                for x in bounds.min.x..=bounds.max.x {
                    voxels.push(src.voxel(VoxelPos::new(x, y, z)));
                }
            }
        }
        Self {
            bounds,
            dims,
            voxels,
            outside,
        }
    }

    /// Copies `bounds` out of a world whose chunks there are all loaded,
    /// a chunk at a time (one lookup per chunk, not per voxel).
    pub(crate) fn from_loaded(world: &World, bounds: VoxelBox) -> Self {
        let dims = [
            (bounds.max.x - bounds.min.x + 1) as usize,
            (bounds.max.y - bounds.min.y + 1) as usize,
            (bounds.max.z - bounds.min.z + 1) as usize,
        ];
        let mut voxels = vec![Voxel::AIR; dims.iter().product()];
        for c in bounds.chunks() {
            let Some(sub) = bounds.within_chunk(c) else {
                continue;
            };
            let chunk = &world.peek(c).expect("loaded by the caller").chunk;
            for z in sub.min.z..=sub.max.z {
                for y in sub.min.y..=sub.max.y {
                    let row = (y - bounds.min.y) as usize * dims[0]
                        + (z - bounds.min.z) as usize * dims[0] * dims[1];
                    for x in sub.min.x..=sub.max.x {
                        let (lx, ly, lz) = VoxelPos::new(x, y, z).local();
                        voxels[row + (x - bounds.min.x) as usize] = chunk.get(lx, ly, lz);
                    }
                }
            }
        }
        Self {
            bounds,
            dims,
            voxels,
            outside: Voxel::AIR,
        }
    }

    pub fn bounds(&self) -> VoxelBox {
        self.bounds
    }

    fn index(&self, p: VoxelPos) -> Option<usize> {
        self.bounds.contains(p).then(|| {
            let (x, y, z) = (
                (p.x - self.bounds.min.x) as usize,
                (p.y - self.bounds.min.y) as usize,
                (p.z - self.bounds.min.z) as usize,
            );
            x + self.dims[0] * (y + self.dims[1] * z)
        })
    }

    /// Sets a voxel inside the region; returns false outside it.
    pub fn set(&mut self, p: VoxelPos, v: Voxel) -> bool {
        match self.index(p) {
            Some(i) => {
                self.voxels[i] = v;
                true
            }
            None => false,
        }
    }
}

impl VoxelRead for Region {
    fn voxel(&self, p: VoxelPos) -> Voxel {
        self.index(p).map_or(self.outside, |i| self.voxels[i])
    }
}
