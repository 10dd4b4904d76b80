//! 2D contouring (Marching Squares) for map slices and height maps.
//!
//! The admin CLI's map renderer draws cave outlines on horizontal slices of
//! the world and height contour lines on top-down maps; both come from here.
//!
//! # Conventions
//! - A sample at grid position `(x, y)` sits at the point `(x, y)`. A sample is
//!   *inside* when its value is strictly greater than the iso level, exactly as
//!   in 3D: with [`DENSITY_ISO`] (127.5) a u8 density is inside when it is
//!   solid (`>= 128`), and no u8 sample can equal the iso level.
//! - A cell is the square between samples `(x, y)` and `(x + 1, y + 1)`.
//!   Contour points lie on cell edges, linearly interpolated between the two
//!   samples, always from the lower-coordinate sample to the higher one so
//!   both cells sharing an edge compute bit-identical points.
//! - **Saddle rule** (cells whose two inside corners are diagonal): the
//!   cell-centre value is the average of the four corners; if that average
//!   is inside (`> iso`) the two inside corners are *connected* through the
//!   centre, otherwise (including a tie) they are *separated*. The rule is the
//!   same for both diagonal configurations and symmetric under swapping
//!   inside and outside except on exact ties.
//! - **Orientation**: walking along a polyline, the inside is on the left
//!   (in a frame with x to the right and y up). A closed loop around an
//!   inside blob is counter-clockwise (positive shoelace area); a loop around
//!   an outside hole (a cave in rock) is clockwise (negative area).
//! - Open polylines start and end on the border of the sampled region;
//!   closed ones are loops whose first point is *not* repeated at the end.
//!
//! Everything is deterministic: only `+ - * /` on floats, and output order
//! depends only on the input values and region, never on tiling or threads.

mod cell;
mod chunked;
mod grid;
mod slice;
mod stitch;

pub use chunked::{contour_tiled, tile_segments, Rect, TilePos, TiledField, TILE_AREA, TILE_SIZE};
pub use grid::{contour, contour_levels, grid_segments, GridView, LevelContours};
pub use slice::{slice_contours, slice_grid, slice_grid_chunks, Axis, SliceGrid, SliceSpec};
pub use stitch::stitch;

use thiserror::Error;

/// Iso level for u8 densities: the surface between air (`<= 127`) and solid.
pub const DENSITY_ISO: f32 = 127.5;

/// Largest grid or region side, in samples (256 chunks).
pub const MAX_SIDE: u32 = 8192;

/// Most levels one [`contour_levels`] call accepts.
pub const MAX_LEVELS: usize = 1024;

/// A scalar sample type the contourer can read: u8 densities, f32 heights.
pub trait Sample: Copy + Default + Send + Sync {
    /// The value as f32 (exact for the integer types).
    fn value(self) -> f32;

    /// Whether the sample is usable (finite); integers always are.
    fn is_finite(self) -> bool {
        true
    }
}

impl Sample for u8 {
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}

impl Sample for u16 {
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}

impl Sample for i16 {
    #[inline]
    fn value(self) -> f32 {
        f32::from(self)
    }
}

impl Sample for f32 {
    #[inline]
    fn value(self) -> f32 {
        self
    }

    fn is_finite(self) -> bool {
        f32::is_finite(self)
    }
}

/// Which grid axis an edge runs along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EdgeAxis {
    /// From sample `(x, y)` to `(x + 1, y)`.
    X,
    /// From sample `(x, y)` to `(x, y + 1)`.
    Y,
}

/// Global identity of a cell edge: its lower sample and its direction.
///
/// Two cells sharing an edge produce the same key, which is how segments from
/// different tiles are stitched together.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct EdgeKey {
    pub x: i32,
    pub y: i32,
    pub axis: EdgeAxis,
}

/// One contour piece inside one cell, from edge `from` to edge `to`, with the
/// inside on its left.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub from: EdgeKey,
    pub to: EdgeKey,
    /// Point on edge `from`.
    pub a: [f32; 2],
    /// Point on edge `to`.
    pub b: [f32; 2],
}

/// A contour line in grid units.
///
/// Points are f32: exact to about 1/256 of a cell within ±32768 of the
/// origin, coarser far out (f32 has 24 significant bits).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Polyline {
    /// Points in order; for a closed loop the first point is not repeated.
    pub points: Vec<[f32; 2]>,
    /// True for a loop, false for a line ending on the region border.
    pub closed: bool,
}

impl Polyline {
    /// Shoelace signed area of a closed loop: positive when it runs
    /// counter-clockwise (around inside), negative around a hole. Zero for
    /// open polylines.
    pub fn signed_area(&self) -> f64 {
        if !self.closed || self.points.len() < 3 {
            return 0.0;
        }
        let n = self.points.len();
        let mut twice = 0.0f64;
        for i in 0..n {
            let [x0, y0] = self.points[i];
            let [x1, y1] = self.points[(i + 1) % n];
            twice += f64::from(x0) * f64::from(y1) - f64::from(x1) * f64::from(y0);
        }
        twice / 2.0
    }
}

/// Why a contouring request was refused. Nothing is computed on error.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ContourError {
    #[error("iso level {0} is not finite")]
    NonFiniteIso(f32),
    #[error("grid is {width}x{height}; each side must be 1..={MAX_SIDE}")]
    BadGridSize { width: u32, height: u32 },
    #[error("grid holds {got} samples but {width}x{height} needs {expected}")]
    LengthMismatch {
        width: u32,
        height: u32,
        expected: usize,
        got: usize,
    },
    #[error("grid origin ({x}, {y}) plus its size overflows i32")]
    OriginOverflow { x: i32, y: i32 },
    #[error("sample at ({x}, {y}) is not finite")]
    NonFiniteSample { x: i32, y: i32 },
    #[error("region min ({min_x}, {min_y}) is above max ({max_x}, {max_y})")]
    InvertedRegion {
        min_x: i32,
        min_y: i32,
        max_x: i32,
        max_y: i32,
    },
    #[error("region is {width}x{height} samples; each side must be at most {MAX_SIDE}")]
    RegionTooLarge { width: u64, height: u64 },
    #[error("{got} levels requested; at most {MAX_LEVELS}")]
    TooManyLevels { got: usize },
    #[error("tiled field has {got} tiles but its region needs {expected}")]
    TileCountMismatch { expected: usize, got: usize },
    #[error("tile ({x}, {y}) holds {got} samples; a tile holds {TILE_AREA}")]
    BadTileLength { x: i32, y: i32, got: usize },
    #[error("segments are inconsistent: edge {0:?} starts or ends more than one segment")]
    DuplicateEdge(EdgeKey),
}
