//! Meshes a whole raw u8 density volume of any size (the admin CLI's
//! `mesh` command, benchmarks against VTK) by reusing the chunk mesher.
//!
//! The volume is cut into 32³-cell chunks. Each chunk samples its apron from
//! the volume (clamped at the volume's faces, which only affects gradient
//! normals there), is meshed independently and in parallel, and the chunk
//! meshes are welded in chunk order by [`VertexKey`] into one indexed mesh.
//! Because a vertex depends only on its own edge (the mesher's exactness
//! rule), welding is exact and the result is the same for any thread count.
//!
//! Speed: a min/max pre-scan skips chunks with no sign change before any
//! copying; each worker refills one reused [`Neighborhood`] (materials set
//! once); chunks go one z-slab at a time, and a slab is welded (copied once
//! into the growing output) while the next one is meshed, so only two slabs
//! of chunk meshes are ever alive. Output keys are optional
//! ([`VolumeMeshOptions::keys`]): they are a quarter of the output memory, and
//! first-touch page faults on fresh output are a large share of the time.
//!
//! On a one-thread pool the same chunks are meshed by `direct.rs` instead:
//! straight from the volume into the output, with no neighbourhoods, chunk
//! meshes or weld map, and the same bytes (tests compare both paths).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use rayon::prelude::*;
use thiserror::Error;

use super::neighborhood::DIM_X;
use super::{try_mesh_chunk, Mesh, MeshError, MeshOptions, Neighborhood, VertexKey};
use crate::material::{ids, MaterialId};
use crate::{VoxelPos, CHUNK_SIZE};

mod direct;

/// Cells per chunk edge: the chunk mesher's size.
const CELLS: u32 = CHUNK_SIZE as u32;
/// Samples in one row of a chunk's cells (both ends).
const ROW: usize = CELLS as usize + 1;
/// Largest accepted volume edge in samples. Keeps every voxel coordinate
/// (plus the apron) far inside `i32`, and f32 positions within 1/16 voxel.
pub const MAX_VOLUME_DIM: u64 = 1 << 20;
/// Coarsest level of detail: the chunk mesher's.
pub const MAX_VOLUME_LOD: u8 = super::MAX_LOD;
/// Output indices are `u32`.
pub const MAX_VOLUME_VERTICES: u64 = u32::MAX as u64;

/// Why a volume cannot be meshed. Nothing is meshed when one is returned.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum VolumeError {
    #[error("volume dimension {axis} is 0; every dimension must be at least 1")]
    ZeroDim { axis: char },
    #[error("volume dimension {axis} = {dim} exceeds the limit of {max}")]
    DimTooLarge { axis: char, dim: u64, max: u64 },
    #[error("volume dimensions {0:?} overflow: their product does not fit in memory addresses")]
    SizeOverflow([u64; 3]),
    #[error("volume data is {actual} bytes but dimensions {dims:?} need {expected} bytes (one u8 per sample)")]
    LengthMismatch {
        dims: [u64; 3],
        expected: u64,
        actual: u64,
    },
    #[error("level of detail {lod} is out of range 0..={max}")]
    BadLod { lod: u8, max: u8 },
    #[error("isovalue {0} is not a finite number")]
    BadIso(f32),
    #[error("mesh has {count} vertices, more than {max} (u32 indices)")]
    TooManyVertices { count: u64, max: u64 },
    #[error("chunk mesher rejected the options: {0}")]
    Mesh(#[from] MeshError),
}

/// A borrowed raw density volume: one u8 per sample, x fastest, then y, then z.
#[derive(Debug, Clone, Copy)]
pub struct VolumeGrid<'a> {
    dims: [u32; 3],
    density: &'a [u8],
}

const AXES: [char; 3] = ['x', 'y', 'z'];

impl<'a> VolumeGrid<'a> {
    /// Validates dimensions alone and returns the sample count; lets callers
    /// check a file's size before reading it.
    pub fn sample_count(dims: [u64; 3]) -> Result<usize, VolumeError> {
        for (axis, &dim) in AXES.into_iter().zip(&dims) {
            if dim == 0 {
                return Err(VolumeError::ZeroDim { axis });
            }
        }
        let product = dims
            .iter()
            .try_fold(1u64, |acc, &d| acc.checked_mul(d))
            .and_then(|p| usize::try_from(p).ok())
            .ok_or(VolumeError::SizeOverflow(dims))?;
        for (axis, &dim) in AXES.into_iter().zip(&dims) {
            if dim > MAX_VOLUME_DIM {
                return Err(VolumeError::DimTooLarge {
                    axis,
                    dim,
                    max: MAX_VOLUME_DIM,
                });
            }
        }
        Ok(product)
    }

    pub fn new(dims: [u64; 3], density: &'a [u8]) -> Result<Self, VolumeError> {
        let expected = Self::sample_count(dims)?;
        if density.len() != expected {
            return Err(VolumeError::LengthMismatch {
                dims,
                expected: expected as u64,
                actual: density.len() as u64,
            });
        }
        // Each dim <= MAX_VOLUME_DIM fits u32 (checked above).
        Ok(Self {
            dims: dims.map(|d| d as u32),
            density,
        })
    }

    pub fn dims(&self) -> [u32; 3] {
        self.dims
    }

    /// Chunks the volume is cut into at `lod` (progress bars size by it).
    pub fn chunk_count(&self, lod: u8) -> u64 {
        self.dims
            .iter()
            .map(|&d| ((d - 1) >> lod << lod).div_ceil(CELLS) as u64)
            .product()
    }

    /// Cells meshed at `lod`: per axis, whole strides between the samples.
    pub fn cell_count(&self, lod: u8) -> u64 {
        self.dims.iter().map(|&d| ((d - 1) >> lod) as u64).product()
    }

    #[inline]
    fn index(&self, x: u32, y: u32, z: u32) -> usize {
        let [dx, dy, _] = self.dims;
        (z as usize * dy as usize + y as usize) * dx as usize + x as usize
    }
}

/// How to mesh a volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VolumeMeshOptions {
    /// A sample is inside (solid) when its density is greater than `iso`.
    pub iso: f32,
    /// Level of detail `0..=MAX_VOLUME_LOD`: cells span `1 << lod` samples.
    pub lod: u8,
    /// Material given to every sample (raw volumes carry density only).
    pub material: MaterialId,
    /// Fill [`Mesh::keys`] of the result. Off by default: the mesh is already
    /// welded, and the keys would be a quarter of its memory.
    pub keys: bool,
}

impl Default for VolumeMeshOptions {
    fn default() -> Self {
        Self {
            iso: super::DEFAULT_ISO,
            lod: 0,
            material: ids::STONE,
            keys: false,
        }
    }
}

/// Counts describing a meshed volume.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VolumeStats {
    /// Cells meshed (at the requested level of detail).
    pub cells: u64,
    pub vertices: u64,
    pub triangles: u64,
    /// Chunks the volume was cut into, and how many of them the min/max
    /// pre-scan proved empty (never sampled or meshed).
    pub chunks: u64,
    pub empty_chunks: u64,
}

/// One welded mesh of a whole volume. Positions are in voxel units: sample
/// `(i, j, k)` sits at `(i, j, k)`; keys (only with [`VolumeMeshOptions::keys`],
/// else empty) are in the same coordinates.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeMesh {
    pub mesh: Mesh,
    pub stats: VolumeStats,
}

/// Meshes `grid` with the current rayon pool (on one thread: the direct sweep).
pub fn mesh_volume(
    grid: &VolumeGrid<'_>,
    opts: &VolumeMeshOptions,
) -> Result<VolumeMesh, VolumeError> {
    mesh_volume_with_progress(grid, opts, &|| {})
}

/// As [`mesh_volume`], calling `progress` once per chunk finished (from
/// worker threads, in any order) so a caller can draw a progress bar.
pub fn mesh_volume_with_progress(
    grid: &VolumeGrid<'_>,
    opts: &VolumeMeshOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<VolumeMesh, VolumeError> {
    if opts.lod > MAX_VOLUME_LOD {
        return Err(VolumeError::BadLod {
            lod: opts.lod,
            max: MAX_VOLUME_LOD,
        });
    }
    if !opts.iso.is_finite() {
        return Err(VolumeError::BadIso(opts.iso));
    }
    let chunks = chunk_list(grid, opts.lod);
    if rayon::current_num_threads() == 1 {
        let (mesh, empty_chunks) = direct::mesh_direct(grid, opts, &chunks, progress)?;
        return Ok(VolumeMesh {
            stats: stats_of(grid, opts, &mesh, chunks.len(), empty_chunks),
            mesh,
        });
    }
    // Chunks are meshed one z-slab (a layer of chunks) at a time, and each slab is welded
    // while the next one is meshed: only two slabs of chunk meshes are alive at once, so
    // their memory is reused instead of growing by the whole volume's worth.
    let mesh_slab = |slab: &[ChunkJob]| -> Result<Vec<Option<Mesh>>, VolumeError> {
        slab.par_iter()
            .map_init(
                || Neighborhood::with_material(opts.material),
                |nb, c| {
                    let m = mesh_one_chunk(grid, opts, c, nb);
                    progress();
                    m
                },
            )
            .collect::<Result<_, _>>()
            .map_err(VolumeError::from)
    };
    let mut welder = Welder::new(opts.keys);
    let mut empty_chunks = 0u64;
    let mut weld_slab = |slab: &[ChunkJob], meshes: Vec<Option<Mesh>>| {
        for (job, mesh) in slab.iter().zip(meshes) {
            match mesh {
                Some(m) => welder.add(job.voxel_origin(), &m)?,
                None => empty_chunks += 1,
            }
        }
        // Later slabs can only share vertices on this slab's top face.
        if let Some(job) = slab.first() {
            welder.forget_seams_below(job.origin[2] + job.extent[2]);
        }
        Ok::<(), VolumeError>(())
    };
    let mut pending: Option<(&[ChunkJob], Vec<Option<Mesh>>)> = None;
    for slab in chunks.chunk_by(|a, b| a.origin[2] == b.origin[2]) {
        // Welding first: on one thread the previous slab's meshes are still in cache.
        let (welded, meshed) = rayon::join(
            || pending.take().map(|(s, m)| weld_slab(s, m)),
            || mesh_slab(slab),
        );
        welded.transpose()?;
        pending = Some((slab, meshed?));
    }
    if let Some((s, m)) = pending {
        weld_slab(s, m)?;
    }
    let mesh = welder.finish();
    let stats = stats_of(grid, opts, &mesh, chunks.len(), empty_chunks);
    Ok(VolumeMesh { mesh, stats })
}

fn stats_of(
    grid: &VolumeGrid<'_>,
    opts: &VolumeMeshOptions,
    mesh: &Mesh,
    chunks: usize,
    empty_chunks: u64,
) -> VolumeStats {
    VolumeStats {
        cells: grid.cell_count(opts.lod),
        vertices: mesh.positions.len() as u64,
        triangles: mesh.triangle_count() as u64,
        chunks: chunks as u64,
        empty_chunks,
    }
}

/// One chunk of cells: its origin sample and how many voxels of cells it
/// spans per axis (less than 32 at the volume's far faces).
#[derive(Debug, Clone, Copy)]
struct ChunkJob {
    origin: [u32; 3],
    extent: [u32; 3],
}

impl ChunkJob {
    /// World position of the chunk's local (0, 0, 0).
    fn voxel_origin(&self) -> VoxelPos {
        let [x, y, z] = self.origin.map(|c| c as i32);
        VoxelPos::new(x, y, z)
    }
}

/// Chunks in z, then y, then x order (the weld order). An axis with fewer
/// than one whole stride of cells left gets no chunk.
fn chunk_list(grid: &VolumeGrid<'_>, lod: u8) -> Vec<ChunkJob> {
    let stride_mask = !((1u32 << lod) - 1);
    let per_axis = |d: u32| -> Vec<(u32, u32)> {
        let cells = (d - 1) & stride_mask;
        (0..cells.div_ceil(CELLS))
            .map(|c| (c * CELLS, (cells - c * CELLS).min(CELLS)))
            .collect()
    };
    let [xs, ys, zs] = grid.dims.map(per_axis);
    let mut jobs = Vec::with_capacity(xs.len() * ys.len() * zs.len());
    for &(oz, ez) in &zs {
        for &(oy, ey) in &ys {
            for &(ox, ex) in &xs {
                jobs.push(ChunkJob {
                    origin: [ox, oy, oz],
                    extent: [ex, ey, ez],
                });
            }
        }
    }
    jobs
}

/// True when the chunk's corner samples are all inside or all outside, so
/// it has no surface. Scans every sample of the chunk's closed box, which is
/// a superset of the corners at any level of detail.
fn chunk_is_empty(grid: &VolumeGrid<'_>, iso: f32, job: &ChunkJob) -> bool {
    let [ox, oy, oz] = job.origin;
    let [ex, ey, ez] = job.extent;
    let len = ex as usize + 1;
    // Element-wise min/max over whole rows (vectorises), reduced once per
    // z-slice: reducing every short row to a scalar cost more than reading it.
    // 32 lanes stay in registers (33 spilled to the stack); the rest is scalar.
    let (mut lo, mut hi) = ([u8::MAX; 32], [u8::MIN; 32]);
    let (mut lo_end, mut hi_end) = (u8::MAX, u8::MIN);
    let (mut any_in, mut any_out) = (false, false);
    for z in oz..=oz + ez {
        for y in oy..=oy + ey {
            let row = grid.index(ox, y, z);
            let samples = &grid.density[row..row + len];
            let tail = match samples.split_first_chunk::<32>() {
                Some((head, tail)) => {
                    for ((l, h), &d) in lo.iter_mut().zip(hi.iter_mut()).zip(head) {
                        *l = (*l).min(d);
                        *h = (*h).max(d);
                    }
                    tail
                }
                None => samples,
            };
            for &d in tail {
                lo_end = lo_end.min(d);
                hi_end = hi_end.max(d);
            }
        }
        let slice_lo = lo.iter().fold(lo_end, |a, &b| a.min(b));
        let slice_hi = hi.iter().fold(hi_end, |a, &b| a.max(b));
        any_in |= slice_hi as f32 > iso;
        any_out |= slice_lo as f32 <= iso;
        // Early out once both sides of the surface have been seen.
        if any_in && any_out {
            return false;
        }
    }
    true
}

/// Meshes one chunk, refilling the worker's reusable neighbourhood `nb` (whose materials
/// are already `opts.material`). `None` when the chunk has no triangles.
fn mesh_one_chunk(
    grid: &VolumeGrid<'_>,
    opts: &VolumeMeshOptions,
    job: &ChunkJob,
    nb: &mut Neighborhood,
) -> Result<Option<Mesh>, MeshError> {
    if chunk_is_empty(grid, opts.iso, job) {
        return Ok(None);
    }
    let [dx, dy, dz] = grid.dims.map(|d| d as i32 - 1);
    // Apron samples outside the volume repeat the nearest face sample: cells
    // never reach them (cell_extent stops at the last sample), only the
    // central-difference normals at the volume's faces do. Rows are copied
    // whole, with only their ends clamped.
    let (row, slice) = (
        grid.dims[0] as usize,
        grid.dims[0] as usize * grid.dims[1] as usize,
    );
    let density: &[u8] = grid.density;
    nb.refill_densities(job.voxel_origin(), |start, drow| {
        let y = start.y.clamp(0, dy) as usize;
        let z = start.z.clamp(0, dz) as usize;
        let line = &density[z * slice + y * row..z * slice + y * row + row];
        let n = drow.len() as i32;
        // drow[k] samples x = start.x + k; [a, b) lies inside the volume.
        let a = (-start.x).clamp(0, n);
        let b = (dx + 1 - start.x).clamp(a, n);
        let (a, b) = (a as usize, b as usize);
        drow[..a].fill(line[0]);
        let x0 = (start.x + a as i32) as usize;
        if let (0, Ok(inner)) = (a, <&mut [u8; DIM_X]>::try_from(&mut drow[..b])) {
            // The usual case, a row wholly inside the volume: a fixed-length copy.
            inner.copy_from_slice(&line[x0..x0 + DIM_X]);
            return;
        }
        drow[..a].fill(line[0]);
        if b > a {
            drow[a..b].copy_from_slice(&line[x0..x0 + (b - a)]);
        }
        drow[b..].fill(line[dx as usize]);
    });
    let mesh_opts = MeshOptions {
        iso: opts.iso,
        lod: opts.lod,
        transition_faces: 0,
        cell_extent: job.extent,
    };
    let mesh = try_mesh_chunk(nb, &mesh_opts)?;
    Ok((!mesh.indices.is_empty()).then_some(mesh))
}

/// FxHash-style multiplicative hasher: the weld map holds only seam keys and
/// is probed millions of times, where SipHash would dominate. Its order is
/// never observed, so output stays deterministic.
#[derive(Default)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u8(&mut self, v: u8) {
        self.write_u64(v as u64);
    }
    fn write_u32(&mut self, v: u32) {
        self.write_u64(v as u64);
    }
    fn write_i32(&mut self, v: i32) {
        self.write_u64(v as u32 as u64);
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

type SeamMap = HashMap<VertexKey, u32, BuildHasherDefault<KeyHasher>>;

/// Whether a vertex's edge lies in a chunk boundary plane, so that another
/// chunk can produce the same vertex. Only those go through the weld map.
#[inline]
fn on_chunk_seam(key: &VertexKey) -> bool {
    let m = CHUNK_SIZE - 1;
    let b = [key.base.x, key.base.y, key.base.z];
    (0..3).any(|a| a != key.axis as usize && b[a] & m == 0)
}

/// Concatenates chunk meshes in the given order, merging seam vertices that
/// share both key and world position, and moves each chunk's positions by its
/// origin (the world position of its local (0, 0, 0)). Keys must be in the
/// same world coordinates with chunk seams at multiples of 32, as
/// [`super::mesh_chunk`] gives them, so meshes of neighbouring world chunks
/// weld exactly.
///
/// Meshes with transition faces may mix: a transition pushes a chunk's
/// vertices near its faces inward by amounts of its own, so two chunks (two
/// diagonal coarse ones, say) can put one key at different positions. Such
/// vertices stay apart; the weld never moves a vertex and never joins
/// triangles that did not meet.
///
/// Vertex ids follow chunk order (a seam vertex takes the id of its first
/// appearance), so the result does not depend on how the meshes were made.
pub fn weld(pieces: impl IntoIterator<Item = (VoxelPos, Mesh)>) -> Result<Mesh, VolumeError> {
    let mut welder = Welder::new(true);
    welder.exact = true;
    for (origin, mesh) in pieces {
        welder.add(origin, &mesh)?;
    }
    Ok(welder.finish())
}

/// Incremental [`weld`]: chunk meshes are appended in order, each copied once
/// straight into the output (no pre-sized, zeroed output to fill later).
struct Welder {
    out: Mesh,
    /// Whether `out.keys` is filled.
    keys: bool,
    seam: SeamMap,
    /// Whether a seam vertex joins an earlier one of its key only at the same
    /// position ([`weld`]: meshes may carry transition faces). The volume
    /// mesher's chunks are all one LOD with no transitions, where a key
    /// names one position.
    exact: bool,
    /// Seam vertices whose key an earlier chunk put elsewhere, by key and
    /// position bits (only when `exact`).
    moved: HashMap<(VertexKey, [u32; 3]), u32>,
    /// Global id of each vertex of the chunk being added (reused).
    remap: Vec<u32>,
}

impl Welder {
    fn new(keys: bool) -> Self {
        Self {
            out: Mesh::default(),
            keys,
            seam: SeamMap::default(),
            exact: false,
            moved: HashMap::new(),
            remap: Vec::new(),
        }
    }

    fn add(&mut self, origin: VoxelPos, mesh: &Mesh) -> Result<(), VolumeError> {
        let out = &mut self.out;
        let n = mesh.keys.len();
        out.positions.reserve(n);
        out.normals.reserve(n);
        out.materials.reserve(n);
        if self.keys {
            out.keys.reserve(n);
        }
        self.remap.clear();
        let o = [origin.x as f32, origin.y as f32, origin.z as f32];
        for (i, key) in mesh.keys.iter().enumerate() {
            let next = out.positions.len() as u64;
            let id = next as u32;
            let v = mesh.positions[i];
            let world = [v[0] + o[0], v[1] + o[1], v[2] + o[2]];
            let global = if !on_chunk_seam(key) {
                id
            } else {
                let first = *self.seam.entry(*key).or_insert(id);
                if self.exact && first != id && out.positions[first as usize] != world {
                    *self
                        .moved
                        .entry((*key, world.map(f32::to_bits)))
                        .or_insert(id)
                } else {
                    first
                }
            };
            if global == id {
                if next >= MAX_VOLUME_VERTICES {
                    return Err(VolumeError::TooManyVertices {
                        count: next + 1,
                        max: MAX_VOLUME_VERTICES,
                    });
                }
                out.positions.push(world);
                out.normals.push(mesh.normals[i]);
                out.materials.push(mesh.materials[i]);
                if self.keys {
                    out.keys.push(*key);
                }
            }
            self.remap.push(global);
        }
        // A plain slice: through `&Vec` its length was reloaded for every index.
        let remap: &[u32] = &self.remap;
        out.indices
            .extend(mesh.indices.iter().map(|&i| remap[i as usize]));
        Ok(())
    }

    /// Drops seam entries of vertices below the plane `z`, which no chunk
    /// still to come can share: keeps the map small and in cache.
    fn forget_seams_below(&mut self, z: u32) {
        let z = z as i32;
        self.seam.retain(|k, _| k.base.z >= z);
    }

    fn finish(self) -> Mesh {
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// A volume sampled from `f(x, y, z)`.
    fn volume(dims: [u32; 3], f: impl Fn(u32, u32, u32) -> u8) -> Vec<u8> {
        let mut v = Vec::with_capacity(dims.iter().map(|&d| d as usize).product());
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    v.push(f(x, y, z));
                }
            }
        }
        v
    }

    fn ramp(signed_distance: f64) -> u8 {
        (127.5 + signed_distance * 40.0).floor().clamp(0.0, 255.0) as u8
    }

    fn sphere(dims: [u32; 3], c: [f64; 3], r: f64) -> Vec<u8> {
        volume(dims, |x, y, z| {
            let d = [x as f64 - c[0], y as f64 - c[1], z as f64 - c[2]];
            ramp(r - (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt())
        })
    }

    /// Rolling terrain: a height field made of two triangle waves, so the
    /// surface crosses every chunk and reaches every side face.
    fn terrain(dims: [u32; 3]) -> Vec<u8> {
        let tri = |v: f64, p: f64| ((v / p).floor() - v / p + 0.5).abs() * 2.0;
        volume(dims, |x, y, z| {
            let h = 8.0 + 9.0 * tri(x as f64 + 3.0, 23.0) + 7.0 * tri(z as f64 * 1.3, 17.0);
            ramp(h - y as f64)
        })
    }

    fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(f)
    }

    /// Meshes on one thread (the direct sweep) and on two (chunks and welder), and checks
    /// that both give the same bytes.
    fn mesh(dims: [u32; 3], data: &[u8], opts: &VolumeMeshOptions) -> VolumeMesh {
        let grid = VolumeGrid::new(dims.map(u64::from), data).unwrap();
        let one = on_threads(1, || mesh_volume(&grid, opts)).unwrap();
        let two = on_threads(2, || mesh_volume(&grid, opts)).unwrap();
        assert_eq!(one, two, "one-thread sweep differs from the chunk path");
        one
    }

    #[test]
    fn sweep_matches_the_chunk_path_at_every_lod_and_size() {
        // Sizes below, at and around chunk multiples, so chunks are partial, single or
        // cut on every axis; keys on, so vertex identity is compared too.
        for dims in [
            [70, 70, 70],
            [33, 65, 34],
            [97, 12, 40],
            [2, 2, 2],
            [130, 9, 66],
        ] {
            let c = dims.map(|d| d as f64 * 0.45);
            let data = [
                sphere(dims, c, dims[0].min(dims[2]) as f64 * 0.4),
                terrain(dims),
            ];
            for (data, lod, iso) in (data.iter())
                .flat_map(|d| (0..=3).map(move |lod| (d, lod)))
                .flat_map(|(d, lod)| [127.5, 100.25, 3.0].map(|iso| (d, lod, iso)))
            {
                let opts = VolumeMeshOptions {
                    iso,
                    lod,
                    keys: true,
                    ..Default::default()
                };
                mesh(dims, data, &opts);
            }
        }
    }

    /// Undirected edge -> (uses, signed orientation sum).
    fn edge_uses(m: &Mesh) -> BTreeMap<(u32, u32), (u32, i32)> {
        let mut edges = BTreeMap::new();
        for t in m.indices.chunks_exact(3) {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = edges.entry((a.min(b), a.max(b))).or_insert((0, 0));
                e.0 += 1;
                e.1 += if a < b { 1 } else { -1 };
            }
        }
        edges
    }

    #[test]
    fn sphere_across_seams_is_closed_with_euler_two() {
        let dims = [70, 70, 70];
        // Radius 26 around ~35 crosses the seams at 32 and 64 on every axis.
        let keys = VolumeMeshOptions {
            keys: true,
            ..Default::default()
        };
        let vm = mesh(dims, &sphere(dims, [35.3, 34.6, 35.2], 26.0), &keys);
        let m = &vm.mesh;
        let edges = edge_uses(m);
        for (e, (uses, orient)) in &edges {
            assert_eq!(
                (*uses, *orient),
                (2, 0),
                "edge {e:?} not shared by two opposite triangles"
            );
        }
        let (v, e, f) = (
            m.positions.len() as i64,
            edges.len() as i64,
            vm.stats.triangles as i64,
        );
        assert_eq!(v - e + f, 2, "Euler characteristic of a sphere");
        // Welding left no duplicate vertex behind.
        let mut keys = m.keys.clone();
        keys.sort();
        keys.dedup();
        assert_eq!(keys.len(), m.positions.len());
        assert_eq!(vm.stats.chunks, 27);
        assert!(vm.stats.empty_chunks > 0, "corner chunks hold no surface");
    }

    #[test]
    fn keys_are_optional_and_change_nothing_else() {
        let dims = [45, 37, 50];
        let data = terrain(dims);
        let plain = mesh(dims, &data, &Default::default());
        let keyed = VolumeMeshOptions {
            keys: true,
            ..Default::default()
        };
        let mut with_keys = mesh(dims, &data, &keyed);
        assert!(plain.mesh.keys.is_empty());
        assert_eq!(with_keys.mesh.keys.len(), with_keys.mesh.positions.len());
        with_keys.mesh.keys.clear();
        assert_eq!(plain, with_keys);
    }

    /// Canonical triangles (rotated to start at the smallest corner, so the
    /// winding is kept) with positions moved by `-shift`, plus normals.
    fn canonical(m: &Mesh, shift: f32) -> Vec<[[u32; 6]; 3]> {
        let mut tris: Vec<[[u32; 6]; 3]> = m
            .indices
            .chunks_exact(3)
            .map(|t| {
                let c = |i: u32| {
                    let (p, n) = (m.positions[i as usize], m.normals[i as usize]);
                    [p[0] - shift, p[1] - shift, p[2] - shift, n[0], n[1], n[2]].map(f32::to_bits)
                };
                let mut tri = [c(t[0]), c(t[1]), c(t[2])];
                let first = (0..3).min_by_key(|&k| tri[k]).unwrap();
                tri.rotate_left(first);
                tri
            })
            .collect();
        tris.sort();
        tris
    }

    #[test]
    fn chunk_seams_do_not_change_the_surface() {
        // The same sphere, once near the origin and once moved by 13 voxels,
        // so chunk seams cut it in different places: identical triangles.
        let (a_dims, b_dims) = ([50, 50, 50], [63, 63, 63]);
        let a = mesh(
            a_dims,
            &sphere(a_dims, [24.3, 25.6, 23.8], 18.0),
            &Default::default(),
        );
        let b = mesh(
            b_dims,
            &sphere(b_dims, [37.3, 38.6, 36.8], 18.0),
            &Default::default(),
        );
        assert!(a.stats.triangles > 1000);
        assert_eq!(canonical(&a.mesh, 0.0), canonical(&b.mesh, 13.0));
    }

    #[test]
    fn identical_output_for_one_and_four_threads() {
        let dims = [45, 37, 50];
        let data = terrain(dims);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| mesh(dims, &data, &Default::default()))
        };
        let (one, four) = (run(1), run(4));
        assert!(one.stats.triangles > 0);
        assert_eq!(one.mesh.hash(), four.mesh.hash());
        assert_eq!(one, four);
        let bits = |m: &Mesh| {
            m.positions
                .iter()
                .flatten()
                .map(|c| c.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&one.mesh), bits(&four.mesh));
    }

    #[test]
    fn odd_sized_volume_is_welded_and_stays_inside() {
        let dims = [45, 37, 50];
        let vm = mesh(dims, &terrain(dims), &Default::default());
        assert_eq!(vm.stats.cells, 44 * 36 * 49);
        assert_eq!(vm.stats.chunks, 2 * 2 * 2);
        assert_eq!(
            VolumeGrid::new([45, 37, 50], &[0; 45 * 37 * 50])
                .unwrap()
                .chunk_count(0),
            8
        );
        let max = dims.map(|d| (d - 1) as f32);
        for p in &vm.mesh.positions {
            for a in 0..3 {
                assert!((0.0..=max[a]).contains(&p[a]), "{p:?} outside the volume");
            }
        }
        // The terrain surface is open only where it meets the volume's side
        // faces: every edge used once lies on x = 0 | 44 or z = 0 | 49.
        let on_side = |p: [f32; 3]| p[0] == 0.0 || p[0] == max[0] || p[2] == 0.0 || p[2] == max[2];
        let mut open = 0;
        for ((a, b), (uses, _)) in edge_uses(&vm.mesh) {
            assert!(uses <= 2);
            if uses == 1 {
                open += 1;
                let (pa, pb) = (vm.mesh.positions[a as usize], vm.mesh.positions[b as usize]);
                assert!(
                    on_side(pa) && on_side(pb),
                    "open edge {pa:?}-{pb:?} inside the volume"
                );
            }
        }
        assert!(open > 0, "the surface does reach the side faces");
    }

    #[test]
    fn plane_ends_at_the_last_sample() {
        // Solid for x >= 20 up to the far face: only the wall at x = 19.5 is
        // meshed, with no cap at x = 39 nor past it, and it covers exactly
        // (Y-1)(Z-1) unit squares.
        let dims = [40, 21, 35];
        let data = volume(dims, |x, _, _| if x >= 20 { 200 } else { 30 });
        let vm = mesh(dims, &data, &Default::default());
        assert_eq!(vm.stats.triangles, 2 * 20 * 34);
        let mut area2 = 0.0f64;
        for t in vm.mesh.indices.chunks_exact(3) {
            let p = [t[0], t[1], t[2]].map(|i| vm.mesh.positions[i as usize].map(f64::from));
            for q in &p {
                assert!(q[0] > 19.0 && q[0] < 20.0, "vertex {q:?} off the wall");
                assert!(
                    q[1] <= 20.0 && q[2] <= 34.0,
                    "vertex {q:?} past the last sample"
                );
            }
            let (u, v) = (
                [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]],
                [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]],
            );
            let c = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            // Wall normal points to -x (towards the air).
            assert!(c[0] < 0.0, "triangle faces the solid side");
            area2 += (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        }
        assert!((area2 / 2.0 - 20.0 * 34.0).abs() < 1e-6);
    }

    #[test]
    fn custom_iso_moves_vertices() {
        // Density rises 10 per voxel along y; iso 100.25 sits at y = 10.025.
        let dims = [9, 20, 9];
        let data = volume(dims, |_, y, _| (y * 10) as u8);
        let opts = VolumeMeshOptions {
            iso: 100.25,
            material: 7,
            ..Default::default()
        };
        let vm = mesh(dims, &data, &opts);
        assert_eq!(vm.stats.triangles, 2 * 8 * 8);
        for p in &vm.mesh.positions {
            assert!((p[1] - 10.025).abs() < 1.0 / 65536.0 + 1e-6, "{p:?}");
        }
        assert!(vm.mesh.materials.iter().all(|&m| m == 7));
    }

    #[test]
    fn coarser_lod_meshes_whole_strides_and_stays_closed() {
        let dims = [70, 70, 70];
        let data = sphere(dims, [35.3, 34.6, 35.2], 26.0);
        let lod0 = mesh(dims, &data, &Default::default());
        let vm = mesh(
            dims,
            &data,
            &VolumeMeshOptions {
                lod: 1,
                keys: true,
                ..Default::default()
            },
        );
        assert_eq!(vm.stats.cells, 34 * 34 * 34);
        assert!(vm.stats.triangles > 0 && vm.stats.triangles < lod0.stats.triangles / 2);
        assert!(vm.mesh.keys.iter().all(|k| k.len == 2));
        for (_, (uses, orient)) in edge_uses(&vm.mesh) {
            assert_eq!((uses, orient), (2, 0));
        }
        let lod3 = mesh(
            dims,
            &data,
            &VolumeMeshOptions {
                lod: 3,
                ..Default::default()
            },
        );
        assert_eq!(lod3.stats.cells, 8 * 8 * 8);
        assert!(lod3.mesh.positions.iter().flatten().all(|&c| c <= 64.0));
    }

    #[test]
    fn lone_sample_on_a_chunk_corner_is_meshed_by_all_eight_chunks() {
        // Sample (32, 32, 32) is the far corner of chunk 0 and the near corner
        // of seven others: the empty-chunk pre-scan must include both ends.
        let dims = [70, 70, 70];
        let data = volume(
            dims,
            |x, y, z| if (x, y, z) == (32, 32, 32) { 255 } else { 0 },
        );
        let vm = mesh(dims, &data, &Default::default());
        assert_eq!(vm.stats.empty_chunks, 27 - 8);
        assert_eq!(
            (vm.mesh.positions.len(), vm.stats.triangles),
            (6, 8),
            "an octahedron"
        );
        for (_, (uses, orient)) in edge_uses(&vm.mesh) {
            assert_eq!((uses, orient), (2, 0));
        }
    }

    #[test]
    fn uniform_and_tiny_volumes_give_empty_meshes() {
        let air = mesh([40, 40, 40], &[0u8; 64000], &Default::default());
        assert_eq!(
            (
                air.stats.triangles,
                air.stats.empty_chunks,
                air.stats.chunks
            ),
            (0, 8, 8)
        );
        assert!(air.mesh.positions.is_empty());
        let one = mesh([1, 1, 1], &[255], &Default::default());
        assert_eq!(
            (one.stats.cells, one.stats.chunks, one.stats.triangles),
            (0, 0, 0)
        );
        let flat = mesh([5, 1, 5], &[255; 25], &Default::default());
        assert_eq!(flat.stats.cells, 0);
    }

    #[test]
    fn bad_input_is_rejected() {
        assert_eq!(
            VolumeGrid::new([4, 0, 4], &[]).unwrap_err(),
            VolumeError::ZeroDim { axis: 'y' }
        );
        let big = 1u64 << 32;
        assert!(matches!(
            VolumeGrid::new([big, big, big], &[]),
            Err(VolumeError::SizeOverflow(_))
        ));
        assert!(matches!(
            VolumeGrid::new([MAX_VOLUME_DIM + 1, 1, 1], &[]),
            Err(VolumeError::DimTooLarge { axis: 'x', .. })
        ));
        assert_eq!(
            VolumeGrid::new([2, 2, 2], &[0; 7]).unwrap_err(),
            VolumeError::LengthMismatch {
                dims: [2, 2, 2],
                expected: 8,
                actual: 7
            }
        );
        let data = [0u8; 8];
        let grid = VolumeGrid::new([2, 2, 2], &data).unwrap();
        let lod4 = VolumeMeshOptions {
            lod: 4,
            ..Default::default()
        };
        assert_eq!(
            mesh_volume(&grid, &lod4).unwrap_err(),
            VolumeError::BadLod { lod: 4, max: 3 }
        );
        let nan = VolumeMeshOptions {
            iso: f32::NAN,
            ..Default::default()
        };
        assert!(matches!(
            mesh_volume(&grid, &nan),
            Err(VolumeError::BadIso(_))
        ));
    }

    #[test]
    fn seam_detection_matches_chunk_planes() {
        let key = |x, y, z, axis| VertexKey {
            base: VoxelPos::new(x, y, z),
            axis,
            len: 1,
        };
        assert!(
            on_chunk_seam(&key(5, 32, 7, 0)),
            "x edge in the y = 32 plane"
        );
        assert!(
            on_chunk_seam(&key(64, 3, 7, 1)),
            "y edge in the x = 64 plane"
        );
        assert!(
            !on_chunk_seam(&key(32, 3, 7, 0)),
            "x edge starting at x = 32 is inside"
        );
        assert!(!on_chunk_seam(&key(5, 6, 7, 2)));
    }
}
