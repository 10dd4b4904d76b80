//! Axis-aligned slices of the world, sampled once and contoured chunk-wise.
//!
//! A slice is the plane `axis = level`. Its two in-plane axes `(u, v)` are
//! the remaining world axes in x, y, z order:
//!
//! | axis | u | v |
//! |------|---|---|
//! | X    | y | z |
//! | Y    | x | z |
//! | Z    | x | y |
//!
//! So a horizontal (Y) slice is a top-down map with `u = x`, `v = z`.
//! Polylines are in `(u, v)` units and keep the module's orientation rule
//! (inside = solid on the left, with u to the right and v up); for a Y slice
//! that means seen from below, since `x × z = -y`. Because the slice's tiles
//! are exactly the chunks it crosses, each chunk is read once.

use super::chunked::{contour_tiled, Rect, TilePos, TiledField, TILE_AREA, TILE_SIZE};
use super::{ContourError, Polyline};
use crate::chunk::{Chunk, Voxel};
use crate::pos::{local_index, ChunkPos, VoxelPos};
use crate::world::{ChunkRead, VoxelRead};

/// A world axis, naming the slice plane's normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// World position of slice point `(u, v)` at `level` on this axis.
    pub const fn voxel(self, level: i32, u: i32, v: i32) -> VoxelPos {
        match self {
            Axis::X => VoxelPos::new(level, u, v),
            Axis::Y => VoxelPos::new(u, level, v),
            Axis::Z => VoxelPos::new(u, v, level),
        }
    }
}

/// Which slice to take: the plane `axis = level`, over `region` in `(u, v)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SliceSpec {
    pub axis: Axis,
    pub level: i32,
    pub region: Rect,
}

/// The sampled slice: density and material at every `(u, v)` of the region,
/// so a renderer can fill solid and air by material without re-reading.
#[derive(Debug, Clone, PartialEq)]
pub struct SliceGrid {
    spec: SliceSpec,
    density: TiledField<u8>,
    material: TiledField<u8>,
}

impl SliceGrid {
    pub fn spec(&self) -> SliceSpec {
        self.spec
    }

    pub fn region(&self) -> Rect {
        self.spec.region
    }

    /// The voxel at slice point `(u, v)`, if inside the region.
    pub fn voxel(&self, u: i32, v: i32) -> Option<Voxel> {
        Some(Voxel::new(
            self.density.get(u, v)?,
            self.material.get(u, v)?,
        ))
    }

    /// Densities as a tiled field (tiles = the chunks crossed).
    pub fn density(&self) -> &TiledField<u8> {
        &self.density
    }

    /// Materials as a tiled field, same layout as [`Self::density`].
    pub fn material(&self) -> &TiledField<u8> {
        &self.material
    }

    /// Contour lines of the slice at `iso` (use [`super::DENSITY_ISO`] for the
    /// solid/air boundary), chunked with gap cells.
    pub fn contours(&self, iso: f32) -> Result<Vec<Polyline>, ContourError> {
        contour_tiled(&self.density, iso)
    }
}

/// The chunk holding tile `tp` of a slice at `level` on `axis`.
fn tile_chunk(axis: Axis, level: i32, tp: TilePos) -> ChunkPos {
    let [u0, v0] = tp.origin();
    axis.voxel(level, u0, v0).chunk()
}

/// Builds a slice tile by tile; `read` fills the region's samples of one
/// tile into density and material planes (indexed u fastest).
fn build(
    spec: SliceSpec,
    mut read: impl FnMut(TilePos, &mut [u8], &mut [u8]),
) -> Result<SliceGrid, ContourError> {
    let r = spec.region;
    let (first, last) = (
        TilePos::of(r.min[0], r.min[1]),
        TilePos::of(r.max[0], r.max[1]),
    );
    let mut densities = Vec::new();
    let mut materials = Vec::new();
    for ty in first.y..=last.y {
        for tx in first.x..=last.x {
            let mut d = vec![0u8; TILE_AREA];
            let mut m = vec![0u8; TILE_AREA];
            read(TilePos { x: tx, y: ty }, &mut d, &mut m);
            densities.push(d);
            materials.push(m);
        }
    }
    Ok(SliceGrid {
        spec,
        density: TiledField::from_tiles(r, densities)?,
        material: TiledField::from_tiles(r, materials)?,
    })
}

/// The in-region `(u, v)` range of a tile, each inclusive.
fn tile_span(r: &Rect, tp: TilePos) -> ([i32; 2], [i32; 2]) {
    let [u0, v0] = tp.origin();
    let lo = [u0.max(r.min[0]), v0.max(r.min[1])];
    let hi = [
        (u0 + (TILE_SIZE - 1)).min(r.max[0]),
        (v0 + (TILE_SIZE - 1)).min(r.max[1]),
    ];
    (lo, hi)
}

#[inline]
fn plane_index(u: i32, v: i32) -> usize {
    let m = TILE_SIZE - 1;
    ((u & m) + (v & m) * TILE_SIZE) as usize
}

/// Samples a slice through any voxel reader, reading each sample once.
///
/// For a [`World`] prefer [`slice_grid_chunks`]: `World::voxel` generates
/// an unloaded chunk anew for every voxel it is asked for.
pub fn slice_grid(src: &impl VoxelRead, spec: SliceSpec) -> Result<SliceGrid, ContourError> {
    let r = spec.region;
    build(spec, |tp, d, m| {
        let (lo, hi) = tile_span(&r, tp);
        for v in lo[1]..=hi[1] {
            for u in lo[0]..=hi[0] {
                let vox = src.voxel(spec.axis.voxel(spec.level, u, v));
                let i = plane_index(u, v);
                d[i] = vox.density;
                m[i] = vox.material;
            }
        }
    })
}

/// Samples a slice by whole chunks: each chunk the slice crosses is fetched
/// once, and a uniform chunk fills its tile without per-voxel reads.
pub fn slice_grid_chunks(src: &impl ChunkRead, spec: SliceSpec) -> Result<SliceGrid, ContourError> {
    let r = spec.region;
    build(spec, |tp, d, m| {
        let chunk = src.chunk_at(tile_chunk(spec.axis, spec.level, tp));
        let dense = match &*chunk {
            Chunk::Uniform(vox) => {
                d.fill(vox.density);
                m.fill(vox.material);
                return;
            }
            Chunk::Dense(dense) => dense,
        };
        // Index steps in the chunk's planes (x fastest, then y, then z) for
        // one step along u and along v, and the fixed level's offset.
        let level = spec.level & (TILE_SIZE - 1);
        let (base, su, sv) = match spec.axis {
            Axis::X => (
                local_index(level as usize, 0, 0),
                local_index(0, 1, 0),
                local_index(0, 0, 1),
            ),
            Axis::Y => (
                local_index(0, level as usize, 0),
                local_index(1, 0, 0),
                local_index(0, 0, 1),
            ),
            Axis::Z => (
                local_index(0, 0, level as usize),
                local_index(1, 0, 0),
                local_index(0, 1, 0),
            ),
        };
        let (lo, hi) = tile_span(&r, tp);
        let m32 = TILE_SIZE - 1;
        for v in lo[1]..=hi[1] {
            let row = base + (v & m32) as usize * sv;
            for u in lo[0]..=hi[0] {
                let src_i = row + (u & m32) as usize * su;
                let i = plane_index(u, v);
                d[i] = dense.density[src_i];
                m[i] = dense.material[src_i];
            }
        }
    })
}

/// Contours the slice `axis = level` over `region = (min_u, min_v, max_u,
/// max_v)` (inclusive, in the axes of the module table) at `iso`, reading
/// each sample once through `src`.
pub fn slice_contours(
    src: &impl VoxelRead,
    axis: Axis,
    level: i32,
    region: (i32, i32, i32, i32),
    iso: f32,
) -> Result<Vec<Polyline>, ContourError> {
    if !iso.is_finite() {
        return Err(ContourError::NonFiniteIso(iso));
    }
    let (min_u, min_v, max_u, max_v) = region;
    let spec = SliceSpec {
        axis,
        level,
        region: Rect::new(min_u, min_v, max_u, max_v)?,
    };
    slice_grid(src, spec)?.contours(iso)
}
