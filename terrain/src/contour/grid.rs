//! Single-grid Marching Squares: one rectangular array of samples.

use super::cell::emit_cell;
use super::stitch::stitch;
use super::{ContourError, Polyline, Sample, Segment, MAX_LEVELS, MAX_SIDE};

/// A validated, borrowed rectangle of samples, x fastest.
///
/// Sample `values[j * width + i]` sits at `(origin[0] + i, origin[1] + j)`,
/// so grids placed anywhere in the plane (negative coordinates included)
/// give contours in world units.
#[derive(Debug, Clone, Copy)]
pub struct GridView<'a, T> {
    values: &'a [T],
    width: u32,
    height: u32,
    origin: [i32; 2],
}

impl<'a, T: Sample> GridView<'a, T> {
    /// Checks the size, that the far corner fits in i32, and that every
    /// sample is finite.
    pub fn new(
        values: &'a [T],
        width: u32,
        height: u32,
        origin: [i32; 2],
    ) -> Result<Self, ContourError> {
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(ContourError::BadGridSize { width, height });
        }
        let expected = width as usize * height as usize;
        if values.len() != expected {
            return Err(ContourError::LengthMismatch {
                width,
                height,
                expected,
                got: values.len(),
            });
        }
        let fits = |o: i32, n: u32| i64::from(o) + i64::from(n) - 1 <= i64::from(i32::MAX);
        if !fits(origin[0], width) || !fits(origin[1], height) {
            return Err(ContourError::OriginOverflow {
                x: origin[0],
                y: origin[1],
            });
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (i, j) = ((i % width as usize) as i32, (i / width as usize) as i32);
            return Err(ContourError::NonFiniteSample {
                x: origin[0] + i,
                y: origin[1] + j,
            });
        }
        Ok(Self {
            values,
            width,
            height,
            origin,
        })
    }

    /// A view over samples the caller already validated (tile buffers).
    pub(crate) fn trusted(values: &'a [T], width: u32, height: u32, origin: [i32; 2]) -> Self {
        debug_assert_eq!(values.len(), width as usize * height as usize);
        Self {
            values,
            width,
            height,
            origin,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn origin(&self) -> [i32; 2] {
        self.origin
    }

    /// The sample at grid index `(i, j)`.
    #[inline]
    pub fn get(&self, i: u32, j: u32) -> Option<T> {
        (i < self.width && j < self.height)
            .then(|| self.values[j as usize * self.width as usize + i as usize])
    }

    /// Appends the segments of the cells whose lower corner has grid index
    /// in `i0..i1` x `j0..j1` (callers keep these inside the grid's cells).
    pub(crate) fn march_cells(
        &self,
        (i0, i1): (u32, u32),
        (j0, j1): (u32, u32),
        iso: f32,
        out: &mut Vec<Segment>,
    ) {
        let w = self.width as usize;
        let (i0, i1) = (i0 as usize, i1 as usize);
        for j in j0..j1 {
            let lo = &self.values[j as usize * w..][..w];
            let hi = &self.values[(j as usize + 1) * w..][..w];
            // Both coordinates fit in i32: checked in `new`.
            let y = self.origin[1] + j as i32;
            // Slide along the row so each sample is read and classified
            // once; left corners are a (bit 1) and c (bit 4), right corners
            // b (bit 2) and d (bit 8).
            let mut left = [lo[i0].value(), hi[i0].value()];
            let mut left_in = u8::from(left[0] > iso) | u8::from(left[1] > iso) << 2;
            for i in i0..i1 {
                let right = [lo[i + 1].value(), hi[i + 1].value()];
                let right_in = u8::from(right[0] > iso) | u8::from(right[1] > iso) << 2;
                let case = left_in | right_in << 1;
                if case != 0 && case != 15 {
                    let x = self.origin[0] + i as i32;
                    emit_cell(x, y, case, [left[0], right[0], left[1], right[1]], iso, out);
                }
                left = right;
                left_in = right_in;
            }
        }
    }
}

fn check_iso(iso: f32) -> Result<(), ContourError> {
    if iso.is_finite() {
        Ok(())
    } else {
        Err(ContourError::NonFiniteIso(iso))
    }
}

/// Every cell segment of the grid at `iso`, in cell order (rows bottom-up).
pub fn grid_segments<T: Sample>(
    grid: &GridView<'_, T>,
    iso: f32,
) -> Result<Vec<Segment>, ContourError> {
    check_iso(iso)?;
    let mut out = Vec::new();
    grid.march_cells((0, grid.width - 1), (0, grid.height - 1), iso, &mut out);
    Ok(out)
}

/// Contour polylines of the grid at `iso` (see the module docs for the
/// inside, saddle and orientation conventions).
pub fn contour<T: Sample>(grid: &GridView<'_, T>, iso: f32) -> Result<Vec<Polyline>, ContourError> {
    let segments = grid_segments(grid, iso)?;
    stitch(segments)
}

/// The contours at one level of a multi-level request.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelContours {
    pub level: f32,
    pub polylines: Vec<Polyline>,
}

/// Contours at many levels, e.g. height lines of a top-down map, in the
/// order the levels were given. Every level is checked before any work.
pub fn contour_levels<T: Sample>(
    grid: &GridView<'_, T>,
    levels: &[f32],
) -> Result<Vec<LevelContours>, ContourError> {
    if levels.len() > MAX_LEVELS {
        return Err(ContourError::TooManyLevels { got: levels.len() });
    }
    levels.iter().try_for_each(|&l| check_iso(l))?;
    levels
        .iter()
        .map(|&level| {
            Ok(LevelContours {
                level,
                polylines: contour(grid, level)?,
            })
        })
        .collect()
}
