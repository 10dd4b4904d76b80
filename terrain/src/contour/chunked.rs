//! Chunked contouring with seed 004's gap cells.
//!
//! The plane is split into 32x32 tiles aligned with world chunks (tile
//! `(tx, ty)` holds samples `tx*32 .. tx*32+31` by `ty*32 .. ty*32+31`). A
//! tile owns the 32x32 cells whose lower corner is one of its samples: its
//! 31x31 interior cells, plus the *gap cells* along its +x border, its +y
//! border and the +x+y corner, whose far corners come from the +x, +y and
//! +x+y neighbour tiles. Every cell of the region therefore belongs to
//! exactly one tile, and the segments' global edge keys stitch the tiles'
//! pieces into polylines across tile borders.

use rayon::prelude::*;

use super::grid::GridView;
use super::stitch::stitch;
use super::{ContourError, Polyline, Sample, Segment, MAX_SIDE};
use crate::pos::{CHUNK_SHIFT, CHUNK_SIZE};

/// Tile side in samples: one chunk.
pub const TILE_SIZE: i32 = CHUNK_SIZE;
/// Samples per tile.
pub const TILE_AREA: usize = (TILE_SIZE * TILE_SIZE) as usize;

/// An inclusive rectangle of sample positions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Rect {
    pub min: [i32; 2],
    pub max: [i32; 2],
}

impl Rect {
    /// Checks `min <= max` and that neither side exceeds [`MAX_SIDE`].
    pub fn new(min_x: i32, min_y: i32, max_x: i32, max_y: i32) -> Result<Self, ContourError> {
        if min_x > max_x || min_y > max_y {
            return Err(ContourError::InvertedRegion {
                min_x,
                min_y,
                max_x,
                max_y,
            });
        }
        let side = |a: i32, b: i32| (i64::from(b) - i64::from(a) + 1) as u64;
        let (width, height) = (side(min_x, max_x), side(min_y, max_y));
        if width > u64::from(MAX_SIDE) || height > u64::from(MAX_SIDE) {
            return Err(ContourError::RegionTooLarge { width, height });
        }
        Ok(Self {
            min: [min_x, min_y],
            max: [max_x, max_y],
        })
    }

    /// Samples along x (at most [`MAX_SIDE`]).
    pub fn width(&self) -> u32 {
        (i64::from(self.max[0]) - i64::from(self.min[0]) + 1) as u32
    }

    /// Samples along y (at most [`MAX_SIDE`]).
    pub fn height(&self) -> u32 {
        (i64::from(self.max[1]) - i64::from(self.min[1]) + 1) as u32
    }

    pub fn contains(&self, x: i32, y: i32) -> bool {
        (self.min[0]..=self.max[0]).contains(&x) && (self.min[1]..=self.max[1]).contains(&y)
    }

    /// The first and last tile touched, per axis.
    fn tile_span(&self) -> (TilePos, TilePos) {
        (
            TilePos::of(self.min[0], self.min[1]),
            TilePos::of(self.max[0], self.max[1]),
        )
    }
}

/// A tile's position: sample position floor-divided by [`TILE_SIZE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TilePos {
    pub x: i32,
    pub y: i32,
}

impl TilePos {
    /// The tile holding sample `(x, y)`.
    pub const fn of(x: i32, y: i32) -> Self {
        Self {
            x: x >> CHUNK_SHIFT,
            y: y >> CHUNK_SHIFT,
        }
    }

    /// Position of the tile's lowest sample.
    pub const fn origin(self) -> [i32; 2] {
        [
            self.x.wrapping_shl(CHUNK_SHIFT),
            self.y.wrapping_shl(CHUNK_SHIFT),
        ]
    }
}

/// Index of a sample inside its tile: x fastest.
#[inline]
fn tile_index(x: i32, y: i32) -> usize {
    let m = TILE_SIZE - 1;
    ((x & m) | ((y & m) << CHUNK_SHIFT)) as usize
}

/// A field over a region, stored as the 32x32 tiles that touch it.
///
/// Tile slots outside the region hold `T::default()` (so equal fields
/// compare equal) and are never read.
#[derive(Clone, PartialEq)]
pub struct TiledField<T> {
    region: Rect,
    first: TilePos,
    tiles_x: usize,
    tiles_y: usize,
    /// Tiles in row order (x fastest), each [`TILE_AREA`] samples.
    tiles: Vec<Box<[T]>>,
}

impl<T> std::fmt::Debug for TiledField<T> {
    /// Shape only: the samples would drown any message.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TiledField")
            .field("region", &self.region)
            .field("tiles", &(self.tiles_x, self.tiles_y))
            .finish_non_exhaustive()
    }
}

impl<T: Sample> TiledField<T> {
    fn empty(region: Rect) -> Self {
        let (a, b) = region.tile_span();
        let tiles_x = (b.x - a.x + 1) as usize;
        let tiles_y = (b.y - a.y + 1) as usize;
        let tiles = (0..tiles_x * tiles_y)
            .map(|_| vec![T::default(); TILE_AREA].into_boxed_slice())
            .collect();
        Self {
            region,
            first: a,
            tiles_x,
            tiles_y,
            tiles,
        }
    }

    /// Samples `f(x, y)` at every position of the region, once each, in
    /// row order (x fastest).
    pub fn from_fn(region: Rect, mut f: impl FnMut(i32, i32) -> T) -> Result<Self, ContourError> {
        let mut field = Self::empty(region);
        for y in region.min[1]..=region.max[1] {
            for x in region.min[0]..=region.max[0] {
                let v = f(x, y);
                if !v.is_finite() {
                    return Err(ContourError::NonFiniteSample { x, y });
                }
                // Every region position has a tile slot (see `empty`).
                if let Some(slot) = field.slot(TilePos::of(x, y)) {
                    field.tiles[slot][tile_index(x, y)] = v;
                }
            }
        }
        Ok(field)
    }

    /// Builds a field from whole tiles, in row order (x fastest) from the
    /// tile of `region.min`; each tile holds [`TILE_AREA`] samples, x fastest.
    pub fn from_tiles(region: Rect, tiles: Vec<Vec<T>>) -> Result<Self, ContourError> {
        let mut field = Self::empty(region);
        if tiles.len() != field.tiles.len() {
            return Err(ContourError::TileCountMismatch {
                expected: field.tiles.len(),
                got: tiles.len(),
            });
        }
        for (k, tile) in tiles.iter().enumerate() {
            if tile.len() != TILE_AREA {
                let tp = field.tile_at(k);
                return Err(ContourError::BadTileLength {
                    x: tp.x,
                    y: tp.y,
                    got: tile.len(),
                });
            }
        }
        for (k, tile) in tiles.into_iter().enumerate() {
            field.tiles[k] = tile.into_boxed_slice();
            field.clear_outside(k);
        }
        for y in region.min[1]..=region.max[1] {
            for x in region.min[0]..=region.max[0] {
                if field.get(x, y).is_some_and(|v| !v.is_finite()) {
                    return Err(ContourError::NonFiniteSample { x, y });
                }
            }
        }
        Ok(field)
    }

    /// Resets tile `k`'s slots outside the region to the default value.
    fn clear_outside(&mut self, k: usize) {
        let [x0, y0] = self.tile_at(k).origin();
        let r = self.region;
        let inside = r.contains(x0, y0) && r.contains(x0 + (TILE_SIZE - 1), y0 + (TILE_SIZE - 1));
        if inside {
            return;
        }
        for y in y0..=y0 + (TILE_SIZE - 1) {
            for x in x0..=x0 + (TILE_SIZE - 1) {
                if !r.contains(x, y) {
                    self.tiles[k][tile_index(x, y)] = T::default();
                }
            }
        }
    }

    /// Re-tiles a grid (region = the grid's rectangle).
    pub fn from_grid(grid: &GridView<'_, T>) -> Result<Self, ContourError> {
        let [ox, oy] = grid.origin();
        let region = Rect::new(
            ox,
            oy,
            ox + (grid.width() - 1) as i32,
            oy + (grid.height() - 1) as i32,
        )?;
        Self::from_fn(region, |x, y| {
            // In range by construction of the region.
            grid.get((x - ox) as u32, (y - oy) as u32)
                .unwrap_or_default()
        })
    }

    pub fn region(&self) -> Rect {
        self.region
    }

    fn tile_at(&self, k: usize) -> TilePos {
        TilePos {
            x: self.first.x + (k % self.tiles_x) as i32,
            y: self.first.y + (k / self.tiles_x) as i32,
        }
    }

    fn slot(&self, tp: TilePos) -> Option<usize> {
        let dx = usize::try_from(i64::from(tp.x) - i64::from(self.first.x)).ok()?;
        let dy = usize::try_from(i64::from(tp.y) - i64::from(self.first.y)).ok()?;
        (dx < self.tiles_x && dy < self.tiles_y).then_some(dy * self.tiles_x + dx)
    }

    /// Tiles touching the region, in row order (x fastest).
    pub fn tiles(&self) -> impl Iterator<Item = TilePos> + '_ {
        (0..self.tiles.len()).map(|k| self.tile_at(k))
    }

    /// A tile's samples (x fastest), if the tile touches the region.
    pub fn tile(&self, tp: TilePos) -> Option<&[T]> {
        self.slot(tp).map(|k| &*self.tiles[k])
    }

    /// The sample at `(x, y)`, if inside the region.
    #[inline]
    pub fn get(&self, x: i32, y: i32) -> Option<T> {
        if !self.region.contains(x, y) {
            return None;
        }
        self.slot(TilePos::of(x, y))
            .map(|k| self.tiles[k][tile_index(x, y)])
    }

    /// Fills `buf` with the samples tile `tp`'s cells need and returns the
    /// buffer's grid shape, or `None` if the tile owns no cell.
    fn gather(&self, tp: TilePos, buf: &mut Vec<T>) -> Option<(u32, u32, [i32; 2])> {
        let [tx0, ty0] = tp.origin();
        let r = &self.region;
        // Owned cells: lower corner in this tile and strictly below the max.
        let x0 = tx0.max(r.min[0]);
        let y0 = ty0.max(r.min[1]);
        let x1 = (tx0 + (TILE_SIZE - 1)).min(r.max[0].checked_sub(1)?);
        let y1 = (ty0 + (TILE_SIZE - 1)).min(r.max[1].checked_sub(1)?);
        if x0 > x1 || y0 > y1 {
            return None;
        }
        let own = self.tile(tp)?;
        let last = tx0 + (TILE_SIZE - 1);
        buf.clear();
        // Sample rows y0 ..= y1 + 1; the last row may be the +y neighbour's
        // first row (the gap row), the last column the +x neighbour's first
        // column (the gap column), and their crossing the +x+y corner.
        for y in y0..=y1 + 1 {
            let row_tile = if y > ty0 + (TILE_SIZE - 1) {
                self.tile(TilePos {
                    x: tp.x,
                    y: tp.y + 1,
                })?
            } else {
                own
            };
            let start = tile_index(x0, y);
            let own_end = x1 + 1;
            if own_end <= last {
                buf.extend_from_slice(&row_tile[start..=tile_index(own_end, y)]);
            } else {
                buf.extend_from_slice(&row_tile[start..=tile_index(last, y)]);
                let gap_tile = self.tile(TilePos {
                    x: tp.x + 1,
                    y: TilePos::of(x0, y).y,
                })?;
                buf.push(gap_tile[tile_index(own_end, y)]);
            }
        }
        Some(((x1 - x0 + 2) as u32, (y1 - y0 + 2) as u32, [x0, y0]))
    }
}

/// The segments of the cells tile `tp` owns: interior cells plus the gap
/// cells along +x, +y and the +x+y corner. Empty for a tile outside the
/// field or owning no cell.
pub fn tile_segments<T: Sample>(
    field: &TiledField<T>,
    tp: TilePos,
    iso: f32,
) -> Result<Vec<Segment>, ContourError> {
    if !iso.is_finite() {
        return Err(ContourError::NonFiniteIso(iso));
    }
    let mut out = Vec::new();
    tile_segments_into(field, tp, iso, &mut Vec::new(), &mut out);
    Ok(out)
}

fn tile_segments_into<T: Sample>(
    field: &TiledField<T>,
    tp: TilePos,
    iso: f32,
    buf: &mut Vec<T>,
    out: &mut Vec<Segment>,
) {
    if let Some((w, h, origin)) = field.gather(tp, buf) {
        let view = GridView::trusted(buf, w, h, origin);
        view.march_cells((0, w - 1), (0, h - 1), iso, out);
    }
}

/// Contours a tiled field tile by tile (in parallel) and stitches the
/// pieces; equal to [`super::contour`] on the same samples.
pub fn contour_tiled<T: Sample>(
    field: &TiledField<T>,
    iso: f32,
) -> Result<Vec<Polyline>, ContourError> {
    if !iso.is_finite() {
        return Err(ContourError::NonFiniteIso(iso));
    }
    let tiles: Vec<TilePos> = field.tiles().collect();
    // Each tile's result is independent and `stitch` sorts, so the output
    // does not depend on scheduling.
    let pieces: Vec<Vec<Segment>> = tiles
        .par_iter()
        .map_init(Vec::new, |buf, &tp| {
            let mut out = Vec::new();
            tile_segments_into(field, tp, iso, buf, &mut out);
            out
        })
        .collect();
    stitch(pieces.into_iter().flatten().collect())
}
