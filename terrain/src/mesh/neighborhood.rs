//! A chunk's voxels plus the read-only apron the mesher needs around them.

use std::borrow::Cow;
use std::ops::RangeInclusive;

use crate::chunk::{Chunk, Voxel};
use crate::pos::{local_index, ChunkPos, VoxelPos, CHUNK_SIZE};
use crate::world::ChunkRead;

/// The 27 chunk offsets of a neighbourhood, z slowest then y then x.
const NEIGHBOURS: [(i32, i32, i32); 27] = {
    let mut out = [(0, 0, 0); 27];
    let mut i = 0;
    while i < 27 {
        out[i] = (
            (i % 3) as i32 - 1,
            ((i / 3) % 3) as i32 - 1,
            (i / 9) as i32 - 1,
        );
        i += 1;
    }
    out
};

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
/// Last local coordinate an LOD-0 mesh reads on every axis, y included: the surface scan
/// (the rows above) runs only on coarse edges.
pub const LOD0_LOCAL_MAX: i32 = CHUNK_SIZE + APRON_HIGH;

/// Samples per row (x).
pub const DIM_X: usize = (LOCAL_MAX - LOCAL_MIN + 1) as usize;
// `from_chunks` copies each row as 1 + 32 + 2 samples.
const _: () = assert!(DIM_X == 1 + CHUNK_SIZE as usize + 2);
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
    /// Samples the chunk at `chunk` plus its apron (faces, edges, corners). Each of the 27
    /// chunks around it is read once (loaded ones borrowed, missing ones generated), and
    /// copied a row at a time.
    pub fn from_world(src: &impl ChunkRead, chunk: ChunkPos) -> Self {
        let mut nb = Self::with_material(0);
        nb.refill_from_world(src, chunk);
        nb
    }

    /// [`Self::from_world`] into this neighbourhood's buffers (see
    /// [`Self::refill_from_chunks`]).
    pub fn refill_from_world(&mut self, src: &impl ChunkRead, chunk: ChunkPos) {
        self.refill_layers_from_world(src, chunk, LOCAL_MIN..=LOCAL_MAX);
    }

    /// [`Self::refill_from_world`] of the sample layers whose local z is in `layers` only
    /// (clamped to the held range); the other layers keep what they held, whatever that was.
    /// For [`super::remesh_chunk_layered_known`], which reads only the layers it is told.
    pub fn refill_layers_from_world(
        &mut self,
        src: &impl ChunkRead,
        chunk: ChunkPos,
        layers: RangeInclusive<i32>,
    ) {
        let (lo, hi) = (
            (*layers.start()).max(LOCAL_MIN),
            (*layers.end()).min(LOCAL_MAX),
        );
        // Only the chunk layers (dz) the sample layers fall in are read.
        let reads = |dz: i32| {
            let shift = dz * CHUNK_SIZE;
            lo < shift + CHUNK_SIZE && hi >= shift
        };
        let around: Vec<Option<Cow<'_, Chunk>>> = NEIGHBOURS
            .iter()
            .map(|&(dx, dy, dz)| {
                let p = chunk.offset(dx, dy, dz).filter(|_| reads(dz))?;
                Some(src.chunk_at(p))
            })
            .collect();
        let rows = if lo > hi {
            0..0
        } else {
            (lo - LOCAL_MIN) as usize * DIM_Y..(hi - LOCAL_MIN + 1) as usize * DIM_Y
        };
        self.refill_rows_from_chunks(chunk, rows, |p| {
            let d = (p.x - chunk.x, p.y - chunk.y, p.z - chunk.z);
            let i = NEIGHBOURS.iter().position(|n| *n == d)?;
            around[i].as_deref()
        });
    }

    /// Samples by callback; `origin` is the world position of local (0,0,0). World positions
    /// wrap at the i32 limits instead of overflowing. One call per sample: prefer
    /// [`Self::from_rows`] or [`Self::from_chunks`] for bulk sources.
    pub fn from_fn(origin: VoxelPos, mut f: impl FnMut(VoxelPos) -> Voxel) -> Self {
        Self::from_rows(origin, |start, density, material| {
            for (k, (d, m)) in density.iter_mut().zip(material.iter_mut()).enumerate() {
                let v = f(VoxelPos::new(
                    start.x.wrapping_add(k as i32),
                    start.y,
                    start.z,
                ));
                *d = v.density;
                *m = v.material;
            }
        })
    }

    /// Samples a row at a time: `fill(start, density, material)` fills the
    /// [`DIM_X`]-sample row of x values beginning at world position `start`.
    pub fn from_rows(
        origin: VoxelPos,
        mut fill: impl FnMut(VoxelPos, &mut [u8], &mut [u8]),
    ) -> Self {
        let mut density = vec![0u8; SAMPLES].into_boxed_slice();
        let mut material = vec![0u8; SAMPLES].into_boxed_slice();
        let rows = density
            .chunks_exact_mut(DIM_X)
            .zip(material.chunks_exact_mut(DIM_X));
        for (r, (drow, mrow)) in rows.enumerate() {
            fill(row_start(origin, r), drow, mrow);
        }
        Self {
            origin,
            density,
            material,
        }
    }

    /// An all-air neighbourhood at the world origin whose every sample has material
    /// `material`: a reusable buffer for [`Self::refill_densities`].
    pub(crate) fn with_material(material: u8) -> Self {
        Self {
            origin: VoxelPos::new(0, 0, 0),
            density: vec![0u8; SAMPLES].into_boxed_slice(),
            material: vec![material; SAMPLES].into_boxed_slice(),
        }
    }

    /// Moves this neighbourhood to `origin` and refills every density row as
    /// [`Self::from_rows`] does (`fill(start, density)`), keeping the materials: bulk
    /// meshers reuse one buffer instead of allocating and zeroing two per chunk.
    pub(crate) fn refill_densities(
        &mut self,
        origin: VoxelPos,
        mut fill: impl FnMut(VoxelPos, &mut [u8]),
    ) {
        self.origin = origin;
        for (r, drow) in self.density.chunks_exact_mut(DIM_X).enumerate() {
            fill(row_start(origin, r), drow);
        }
    }

    /// Samples the chunk at `chunk` and its apron straight from chunk storage: each of the
    /// (up to) 27 chunks around it is fetched once and copied in row runs. Chunks that `get`
    /// does not return read as air.
    pub fn from_chunks<'c>(
        chunk: ChunkPos,
        get: impl FnMut(ChunkPos) -> Option<&'c Chunk>,
    ) -> Self {
        let mut nb = Self::with_material(0);
        nb.refill_from_chunks(chunk, get);
        nb
    }

    /// [`Self::from_chunks`] into this neighbourhood's buffers: every sample is overwritten, so
    /// a recycled buffer needs no clearing, and no memory is allocated.
    pub fn refill_from_chunks<'c>(
        &mut self,
        chunk: ChunkPos,
        get: impl FnMut(ChunkPos) -> Option<&'c Chunk>,
    ) {
        self.refill_rows_from_chunks(chunk, 0..DIM_Y * DIM_Z, get);
    }

    /// [`Self::refill_from_chunks`] of the rows in `rows` only (rows run y fastest, then z).
    fn refill_rows_from_chunks<'c>(
        &mut self,
        chunk: ChunkPos,
        rows: std::ops::Range<usize>,
        mut get: impl FnMut(ChunkPos) -> Option<&'c Chunk>,
    ) {
        let around: [Option<&'c Chunk>; 27] = std::array::from_fn(|i| {
            let (dx, dy, dz) = NEIGHBOURS[i];
            chunk.offset(dx, dy, dz).and_then(&mut get)
        });
        let m = CHUNK_SIZE - 1;
        let first = rows.start;
        let (density, material) = (
            &mut self.density[rows.start * DIM_X..rows.end * DIM_X],
            &mut self.material[rows.start * DIM_X..rows.end * DIM_X],
        );
        let rows = density
            .chunks_exact_mut(DIM_X)
            .zip(material.chunks_exact_mut(DIM_X));
        for (r, (drow, mrow)) in rows.enumerate() {
            let r = first + r;
            // Local y and z of this row, and the chunk layer each falls in.
            let (y, z) = (
                (r % DIM_Y) as i32 + LOCAL_MIN,
                (r / DIM_Y) as i32 + LOCAL_MIN,
            );
            let (dy, dz) = (y.div_euclid(CHUNK_SIZE), z.div_euclid(CHUNK_SIZE));
            let slot = |dx: i32| (dx + 1 + 3 * (dy + 1) + 9 * (dz + 1)) as usize;
            let base = local_index(0, (y & m) as usize, (z & m) as usize);
            // Each row crosses three chunks along x: local -1, 0..=31 and 32..=33, which
            // together write all DIM_X samples. Fixed-size pieces compile to a few moves
            // instead of memcpy calls.
            copy_piece::<1>(around[slot(-1)], base + m as usize, drow, mrow, 0);
            copy_piece::<32>(around[slot(0)], base, drow, mrow, 1);
            copy_piece::<2>(around[slot(1)], base, drow, mrow, 33);
        }
        self.origin = chunk.origin();
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

/// Copies `N` voxels of one chunk row starting at chunk index `from` into `drow` / `mrow` at
/// `at` (air when the chunk is missing).
#[inline(always)]
fn copy_piece<const N: usize>(
    c: Option<&Chunk>,
    from: usize,
    drow: &mut [u8],
    mrow: &mut [u8],
    at: usize,
) {
    let (d, m): (&mut [u8; N], &mut [u8; N]) = (
        (&mut drow[at..at + N]).try_into().expect("N samples"),
        (&mut mrow[at..at + N]).try_into().expect("N samples"),
    );
    match c {
        None => {
            *d = [0; N];
            *m = [0; N];
        }
        Some(Chunk::Uniform(v)) => {
            *d = [v.density; N];
            *m = [v.material; N];
        }
        Some(Chunk::Dense(dc)) => {
            *d = dc.density[from..from + N].try_into().expect("N samples");
            *m = dc.material[from..from + N].try_into().expect("N samples");
        }
    }
}

/// World position of the first sample of row `r` (rows run y fastest, then z) of the
/// neighbourhood whose local (0, 0, 0) is `origin`.
fn row_start(origin: VoxelPos, r: usize) -> VoxelPos {
    let (y, z) = (
        (r % DIM_Y) as i32 + LOCAL_MIN,
        (r / DIM_Y) as i32 + LOCAL_MIN,
    );
    VoxelPos::new(
        origin.x.wrapping_add(LOCAL_MIN),
        origin.y.wrapping_add(y),
        origin.z.wrapping_add(z),
    )
}

/// Internal index of a local position; callers keep it inside the held range.
#[inline]
pub(crate) const fn index(x: i32, y: i32, z: i32) -> usize {
    (x - LOCAL_MIN) as usize + (y - LOCAL_MIN) as usize * STEP_Y + (z - LOCAL_MIN) as usize * STEP_Z
}
