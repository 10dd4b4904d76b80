//! A chunk's voxels plus the read-only apron the mesher needs around them.

use crate::chunk::{Chunk, Voxel};
use crate::pos::{ChunkPos, VoxelPos, CHUNK_SIZE};
use crate::world::VoxelRead;

/// Samples below local 0 on each axis: central-difference normals at sample 0 read local -1.
pub const APRON_LOW: i32 = 1;
/// Samples above local 32 on each axis: the last cells read sample 32, its normal reads 33.
pub const APRON_HIGH: i32 = 1;
/// How far the LOD material scan climbs above a solid sample (seed 001's `MaxScanDistance`).
pub const MAX_SURFACE_SCAN: i32 = 8;

/// First local coordinate held on every axis.
pub const LOCAL_MIN: i32 = -APRON_LOW;
/// Last local coordinate held on x and z.
pub const LOCAL_MAX: i32 = CHUNK_SIZE + APRON_HIGH;
/// Last local coordinate held on y: higher, so the surface scan from sample 32 stays inside.
pub const LOCAL_MAX_Y: i32 = CHUNK_SIZE + MAX_SURFACE_SCAN;

/// Samples per row (x).
pub(crate) const DIM_X: usize = (LOCAL_MAX - LOCAL_MIN + 1) as usize;
/// Rows per slice (y).
pub(crate) const DIM_Y: usize = (LOCAL_MAX_Y - LOCAL_MIN + 1) as usize;
/// Slices (z).
pub(crate) const DIM_Z: usize = (LOCAL_MAX - LOCAL_MIN + 1) as usize;
/// Index step between neighbouring rows.
pub(crate) const STEP_Y: usize = DIM_X;
/// Index step between neighbouring slices.
pub(crate) const STEP_Z: usize = DIM_X * DIM_Y;
/// Samples held.
pub(crate) const SAMPLES: usize = DIM_X * DIM_Y * DIM_Z;

/// The padded samples of one chunk: local -1..=33 on x and z and -1..=40 on y (the extra rows
/// above feed the LOD material scan), density and material planes, x fastest then y then z.
///
/// The mesher reads only this, so a mesh depends on nothing but these samples, and a vertex on
/// a chunk face or edge sees the same data from every chunk that shares it.
#[derive(Clone, PartialEq, Eq)]
pub struct Neighborhood {
    origin: VoxelPos,
    density: Box<[u8]>,
    material: Box<[u8]>,
}

impl std::fmt::Debug for Neighborhood {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Neighborhood")
            .field("origin", &self.origin)
            .finish_non_exhaustive()
    }
}

impl Neighborhood {
    /// Samples the chunk at `chunk` plus its apron (faces, edges, corners) from any voxel source.
    pub fn from_world(src: &impl VoxelRead, chunk: ChunkPos) -> Self {
        Self::from_fn(chunk.origin(), |p| src.voxel(p))
    }

    /// Samples by callback; `origin` is the world position of local (0,0,0). World positions
    /// wrap at the i32 limits instead of overflowing.
    pub fn from_fn(origin: VoxelPos, mut f: impl FnMut(VoxelPos) -> Voxel) -> Self {
        let mut density = vec![0u8; SAMPLES].into_boxed_slice();
        let mut material = vec![0u8; SAMPLES].into_boxed_slice();
        let mut i = 0;
        for z in LOCAL_MIN..=LOCAL_MAX {
            for y in LOCAL_MIN..=LOCAL_MAX_Y {
                for x in LOCAL_MIN..=LOCAL_MAX {
                    let v = f(VoxelPos::new(
                        origin.x.wrapping_add(x),
                        origin.y.wrapping_add(y),
                        origin.z.wrapping_add(z),
                    ));
                    density[i] = v.density;
                    material[i] = v.material;
                    i += 1;
                }
            }
        }
        Self {
            origin,
            density,
            material,
        }
    }

    /// Samples the chunk at `chunk` and its apron straight from chunk storage: each of the
    /// (up to) 27 chunks around it is fetched once, instead of once per voxel as through
    /// [`VoxelRead`]. Chunks that `get` does not return read as air.
    pub fn from_chunks<'c>(
        chunk: ChunkPos,
        mut get: impl FnMut(ChunkPos) -> Option<&'c Chunk>,
    ) -> Self {
        let origin = chunk.origin();
        let mut density = vec![0u8; SAMPLES].into_boxed_slice();
        let mut material = vec![0u8; SAMPLES].into_boxed_slice();
        // Local range [lo, hi] of each neighbour offset -1, 0, +1 per axis (y reaches further).
        let span = |d: i32, max: i32| match d {
            -1 => (LOCAL_MIN, -1),
            0 => (0, CHUNK_SIZE - 1),
            _ => (CHUNK_SIZE, max),
        };
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(c) = chunk.offset(dx, dy, dz).and_then(&mut get) else {
                        continue; // air: the planes start zeroed
                    };
                    let (x0, x1) = span(dx, LOCAL_MAX);
                    let (y0, y1) = span(dy, LOCAL_MAX_Y);
                    let (z0, z1) = span(dz, LOCAL_MAX);
                    for z in z0..=z1 {
                        for y in y0..=y1 {
                            for x in x0..=x1 {
                                let m = CHUNK_SIZE - 1;
                                let v = c.get((x & m) as usize, (y & m) as usize, (z & m) as usize);
                                let i = index(x, y, z);
                                density[i] = v.density;
                                material[i] = v.material;
                            }
                        }
                    }
                }
            }
        }
        Self {
            origin,
            density,
            material,
        }
    }

    /// World position of local (0,0,0).
    pub fn origin(&self) -> VoxelPos {
        self.origin
    }

    /// The voxel at a local position, or `None` outside the held range.
    pub fn voxel(&self, x: i32, y: i32, z: i32) -> Option<Voxel> {
        let inside = (LOCAL_MIN..=LOCAL_MAX).contains(&x)
            && (LOCAL_MIN..=LOCAL_MAX_Y).contains(&y)
            && (LOCAL_MIN..=LOCAL_MAX).contains(&z);
        inside.then(|| {
            let i = index(x, y, z);
            Voxel::new(self.density[i], self.material[i])
        })
    }

    /// Density plane in the internal order (see [`index`]).
    #[inline]
    pub(crate) fn densities(&self) -> &[u8] {
        &self.density
    }

    /// Material plane in the internal order.
    #[inline]
    pub(crate) fn materials(&self) -> &[u8] {
        &self.material
    }
}

/// Internal index of a local position; callers keep it inside the held range.
#[inline]
pub(crate) const fn index(x: i32, y: i32, z: i32) -> usize {
    (x - LOCAL_MIN) as usize + (y - LOCAL_MIN) as usize * STEP_Y + (z - LOCAL_MIN) as usize * STEP_Z
}
