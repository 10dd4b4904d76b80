//! Where the surface is: a fractal height field or a heightmap.

use std::sync::Arc;

use super::heightmap::Heightmap;
use super::noise::{fbm2, octave_seeds};
use super::params::GenParams;

/// The source of column surface heights.
#[derive(Debug, Clone)]
pub enum HeightSource {
    /// Seeded fBm hills from the `GenParams` hill settings.
    Fractal,
    /// A decoded heightmap (seed 002); shared, since maps can be large.
    Heightmap(Arc<Heightmap>),
}

impl HeightSource {
    pub fn heightmap(map: Heightmap) -> Self {
        HeightSource::Heightmap(Arc::new(map))
    }
}

/// The fractal height field: `base + amplitude * fbm(x / wavelength, z / wavelength)`.
#[derive(Debug, Clone)]
pub(crate) struct FractalHills {
    seeds: Vec<u64>,
    base: f64,
    amplitude: f64,
    inv_wavelength: f64,
}

/// Seed layer of the height field (see [`super::noise::sub_seed`]).
const HILL_LAYER: u64 = 1;

impl FractalHills {
    pub(crate) fn new(p: &GenParams) -> Self {
        Self {
            seeds: octave_seeds(p.seed, HILL_LAYER, p.octaves),
            base: p.base_height,
            amplitude: p.hill_amplitude,
            inv_wavelength: 1.0 / p.hill_wavelength,
        }
    }

    pub(crate) fn height(&self, x: i64, z: i64) -> f64 {
        let n = fbm2(
            &self.seeds,
            x as f64 * self.inv_wavelength,
            z as f64 * self.inv_wavelength,
        );
        self.base + self.amplitude * n
    }

    /// Upper bound of [`Self::height`]: fBm is clamped to [-1, 1].
    pub(crate) fn max_height(&self) -> f64 {
        self.base + self.amplitude
    }
}

impl HeightSource {
    /// Unclamped surface height of a column.
    pub(crate) fn raw_height(&self, hills: &FractalHills, x: i64, z: i64) -> f64 {
        match self {
            HeightSource::Fractal => hills.height(x, z),
            HeightSource::Heightmap(m) => m.height_at_wide(x, z),
        }
    }

    /// An upper bound of [`Self::raw_height`] over the whole world.
    pub(crate) fn max_raw_height(&self, hills: &FractalHills) -> f64 {
        match self {
            HeightSource::Fractal => hills.max_height(),
            HeightSource::Heightmap(m) => m.max_height(),
        }
    }
}
