//! 3D noise fields (caves, ore) sampled on a coarse lattice per chunk.
//!
//! Evaluating fBm for all 32³ voxels would cost far more than the rest of
//! generation, so each field is evaluated every [`LATTICE_STEP`] voxels and
//! interpolated trilinearly. Lattice points sit at world coordinates that are
//! multiples of the step and the interpolation only uses the voxel's position
//! inside its lattice cell, so a voxel gets the same value whichever chunk
//! computes it: chunk borders are seamless.

use super::noise::{fbm3, octave_seeds};
use crate::pos::CHUNK_SIZE;

/// Voxels between lattice points (divides [`CHUNK_SIZE`]).
pub const LATTICE_STEP: usize = 4;
/// Lattice points per chunk axis, including the far face.
pub const LATTICE_POINTS: usize = CHUNK_SIZE as usize / LATTICE_STEP + 1;
/// Exact fractions of a lattice cell for the 4 voxel offsets.
const FRACTIONS: [f64; LATTICE_STEP] = [0.0, 0.25, 0.5, 0.75];

/// A seeded, anisotropic 3D fBm field.
#[derive(Debug, Clone)]
pub(crate) struct NoiseField {
    seeds: Vec<u64>,
    inv_wavelength: f64,
    y_scale: f64,
}

impl NoiseField {
    /// `flatness` > 1 squashes features vertically.
    pub(crate) fn new(seed: u64, layer: u64, octaves: u32, wavelength: f64, flatness: f64) -> Self {
        let inv_wavelength = 1.0 / wavelength;
        Self {
            seeds: octave_seeds(seed, layer, octaves),
            inv_wavelength,
            y_scale: inv_wavelength * flatness,
        }
    }

    /// The field at a world voxel, in `[-1, 1]`.
    pub(crate) fn at(&self, x: i64, y: i64, z: i64) -> f64 {
        let w = self.inv_wavelength;
        fbm3(
            &self.seeds,
            x as f64 * w,
            y as f64 * self.y_scale,
            z as f64 * w,
        )
    }
}

const N: usize = LATTICE_POINTS;
const SIZE: usize = CHUNK_SIZE as usize;

/// One chunk's lattice of field values, already interpolated along x: for
/// every lattice (z, y) pair, the 32 voxel values of that x row, index
/// `(z * N + y) * SIZE + lx`. Interpolating x once per row (instead of once
/// per column) does the same arithmetic in the same order, so the values are
/// bit-identical to a direct trilinear interpolation, at a third of the cost.
#[derive(Debug, Clone)]
pub(crate) struct Lattice {
    rows: Vec<f64>,
}

impl Lattice {
    /// Samples `field` at the lattice points of the chunk with minimum voxel `origin`.
    pub(crate) fn sample(field: &NoiseField, origin: (i64, i64, i64)) -> Self {
        let step = LATTICE_STEP as i64;
        let mut rows = vec![0.0; N * N * SIZE];
        let mut points = [0.0; N];
        for (zy, row) in rows.chunks_exact_mut(SIZE).enumerate() {
            let (z, y) = ((zy / N) as i64, (zy % N) as i64);
            for (x, p) in points.iter_mut().enumerate() {
                *p = field.at(
                    origin.0 + x as i64 * step,
                    origin.1 + y * step,
                    origin.2 + z * step,
                );
            }
            for (lx, v) in row.iter_mut().enumerate() {
                let (cx, tx) = (lx / LATTICE_STEP, FRACTIONS[lx % LATTICE_STEP]);
                *v = lerp(points[cx], points[cx + 1], tx);
            }
        }
        Self { rows }
    }

    /// Values at every lattice height for every voxel column of the z-row
    /// `lz` (x and z interpolated), lattice height first: `out[y][lx]`.
    /// [`row_at`] then finishes along y.
    pub(crate) fn z_rows(&self, lz: usize) -> [[f64; SIZE]; LATTICE_POINTS] {
        let (cz, tz) = (lz / LATTICE_STEP, FRACTIONS[lz % LATTICE_STEP]);
        let near = &self.rows[cz * N * SIZE..(cz + 1) * N * SIZE];
        let far = &self.rows[(cz + 1) * N * SIZE..(cz + 2) * N * SIZE];
        let mut out = [[0.0; SIZE]; LATTICE_POINTS];
        for (y, o) in out.iter_mut().enumerate() {
            let (n, f) = (
                &near[y * SIZE..(y + 1) * SIZE],
                &far[y * SIZE..(y + 1) * SIZE],
            );
            for ((v, &a), &b) in o.iter_mut().zip(n).zip(f) {
                *v = lerp(a, b, tz);
            }
        }
        out
    }
}

/// The field at local height `ly` of each column of a z-row from
/// [`Lattice::z_rows`].
#[inline]
pub(crate) fn row_at(rows: &[[f64; SIZE]; LATTICE_POINTS], ly: usize) -> [f64; SIZE] {
    let c = ly / LATTICE_STEP;
    let t = FRACTIONS[ly % LATTICE_STEP];
    let mut out = [0.0; SIZE];
    for ((v, &a), &b) in out.iter_mut().zip(&rows[c]).zip(&rows[c + 1]) {
        *v = lerp(a, b, t);
    }
    out
}

#[inline]
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lattice_matches_field_on_points_and_chunks_agree() {
        let f = NoiseField::new(11, 2, 2, 24.0, 1.5);
        let o = (-32, 64, 96);
        let l = Lattice::sample(&f, o);
        let rows = l.z_rows(12);
        assert_eq!(row_at(&rows, 4)[8], f.at(o.0 + 8, o.1 + 4, o.2 + 12));
        // The voxel at the top face of one chunk's lattice is the bottom of the next.
        let above = Lattice::sample(&f, (o.0, o.1 + 32, o.2));
        assert_eq!(rows[LATTICE_POINTS - 1][8], above.z_rows(12)[0][8]);
        // Between points the value lies between the neighbours along y.
        let (a, b, m) = (
            row_at(&rows, 0)[8],
            row_at(&rows, 4)[8],
            row_at(&rows, 2)[8],
        );
        assert!(m >= a.min(b) && m <= a.max(b));
    }
}
