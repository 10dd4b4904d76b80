//! Generation parameters: what a server config carries to pick a world.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Default world seed ("STRATA" in ASCII).
pub const DEFAULT_SEED: u64 = 0x5354_5241_5441;
/// Default lowest voxel layer of the world (bedrock starts here).
pub const DEFAULT_MIN_Y: i32 = -128;
/// Default highest voxel layer of the world (always air above).
pub const DEFAULT_MAX_Y: i32 = 255;
/// Default mean surface height.
pub const DEFAULT_BASE_HEIGHT: f64 = 32.0;
/// Default hill amplitude: the surface stays within base ± this.
pub const DEFAULT_HILL_AMPLITUDE: f64 = 48.0;
/// Default size of the broadest hills, in voxels per noise cell.
pub const DEFAULT_HILL_WAVELENGTH: f64 = 256.0;
/// Default fBm octaves of the height field.
pub const DEFAULT_OCTAVES: u32 = 5;
/// Default density change per voxel across the surface (band ≈ ±2.7 voxels).
pub const DEFAULT_SURFACE_SHARPNESS: f64 = 48.0;
/// Default cave noise cell size, in voxels.
pub const DEFAULT_CAVE_WAVELENGTH: f64 = 48.0;
/// Default vertical squash of caves (>1 gives wider-than-tall caverns).
pub const DEFAULT_CAVE_FLATNESS: f64 = 1.5;
/// Default cave fBm octaves.
pub const DEFAULT_CAVE_OCTAVES: u32 = 2;
/// Default cave threshold: caves open where cave noise exceeds it.
pub const DEFAULT_CAVE_THRESHOLD: f64 = 0.3;
/// Default density change per unit of cave noise.
pub const DEFAULT_CAVE_SHARPNESS: f64 = 1024.0;
/// Default depth (voxels) below the surface over which caves are suppressed.
pub const DEFAULT_CAVE_GUARD_DEPTH: f64 = 12.0;
/// Default extra threshold right at the surface; only the strongest caves
/// break through, giving occasional entrances instead of a perforated skin.
pub const DEFAULT_CAVE_GUARD: f64 = 0.3;
/// Default grass thickness.
pub const DEFAULT_GRASS_LAYERS: u32 = 1;
/// Default dirt thickness under the grass.
pub const DEFAULT_DIRT_LAYERS: u32 = 3;
/// Default minimum bedrock thickness at the bottom of the world.
pub const DEFAULT_BEDROCK_LAYERS: u32 = 3;
/// Default extra bedrock per column, 0..=this, for an uneven floor.
pub const DEFAULT_BEDROCK_JITTER: u32 = 2;
/// Default ore noise cell size, in voxels.
pub const DEFAULT_ORE_WAVELENGTH: f64 = 12.0;
/// Default ore threshold: stone becomes ore where ore noise exceeds it.
pub const DEFAULT_ORE_THRESHOLD: f64 = 0.45;

/// Octave cap for both height and cave fBm.
pub const MAX_OCTAVES: u32 = 10;
/// `|min_y|` and `|max_y|` cap: keeps every height exact in f64 and i32.
pub const WORLD_Y_LIMIT: i32 = 1 << 20;
/// Smallest allowed `max_y - min_y`.
pub const MIN_WORLD_HEIGHT: i32 = 64;
/// Cap on grass, dirt, bedrock layers and bedrock jitter.
pub const MAX_LAYER_THICKNESS: u32 = 64;
/// Smallest noise wavelength: finer noise would alias on the voxel grid.
pub const MIN_WAVELENGTH: f64 = 2.0;
/// Largest noise wavelength.
pub const MAX_WAVELENGTH: f64 = 1_048_576.0;
/// Bounds on the surface sharpness (density per voxel).
pub const MIN_SURFACE_SHARPNESS: f64 = 1.0;
pub const MAX_SURFACE_SHARPNESS: f64 = 255.0;
/// Bounds on the cave sharpness (density per unit of noise).
pub const MIN_CAVE_SHARPNESS: f64 = 16.0;
pub const MAX_CAVE_SHARPNESS: f64 = 65_536.0;
/// Cap on `|base_height|`, `hill_amplitude`, thresholds and guard values.
pub const MAX_PARAM_MAGNITUDE: f64 = 1_048_576.0;

/// Everything that defines a generated world. Missing fields in a config take
/// the `DEFAULT_*` values; unknown fields are rejected to catch typos.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GenParams {
    /// World seed; every noise layer derives its own seed from it.
    pub seed: u64,
    /// Bottom of the world: bedrock from here down.
    pub min_y: i32,
    /// Top of the world: always air above.
    pub max_y: i32,
    /// Mean surface height of the fractal height field.
    pub base_height: f64,
    /// Surface stays within `base_height ± hill_amplitude`.
    pub hill_amplitude: f64,
    /// Voxels per noise cell of the broadest hill octave.
    pub hill_wavelength: f64,
    /// fBm octaves of the height field (1..=MAX_OCTAVES).
    pub octaves: u32,
    /// Density change per voxel across the surface: smaller is smoother.
    pub surface_sharpness: f64,
    /// Voxels per noise cell of the cave field.
    pub cave_wavelength: f64,
    /// Vertical squash of the cave field.
    pub cave_flatness: f64,
    /// Cave fBm octaves (0 disables caves).
    pub cave_octaves: u32,
    /// Caves open where cave noise (in [-1, 1]) exceeds this.
    pub cave_threshold: f64,
    /// Density change per unit of cave noise.
    pub cave_sharpness: f64,
    /// Depth below the surface over which caves fade out.
    pub cave_guard_depth: f64,
    /// Extra cave threshold at the surface, fading to 0 at `cave_guard_depth`.
    pub cave_guard: f64,
    /// Grass voxels at the top of each column.
    pub grass_layers: u32,
    /// Dirt voxels under the grass.
    pub dirt_layers: u32,
    /// Minimum bedrock thickness above `min_y`.
    pub bedrock_layers: u32,
    /// Extra bedrock per column, hashed in 0..=bedrock_jitter.
    pub bedrock_jitter: u32,
    /// Voxels per noise cell of the ore field.
    pub ore_wavelength: f64,
    /// Stone becomes ore where ore noise exceeds this (higher: rarer).
    pub ore_threshold: f64,
}

impl Default for GenParams {
    fn default() -> Self {
        Self {
            seed: DEFAULT_SEED,
            min_y: DEFAULT_MIN_Y,
            max_y: DEFAULT_MAX_Y,
            base_height: DEFAULT_BASE_HEIGHT,
            hill_amplitude: DEFAULT_HILL_AMPLITUDE,
            hill_wavelength: DEFAULT_HILL_WAVELENGTH,
            octaves: DEFAULT_OCTAVES,
            surface_sharpness: DEFAULT_SURFACE_SHARPNESS,
            cave_wavelength: DEFAULT_CAVE_WAVELENGTH,
            cave_flatness: DEFAULT_CAVE_FLATNESS,
            cave_octaves: DEFAULT_CAVE_OCTAVES,
            cave_threshold: DEFAULT_CAVE_THRESHOLD,
            cave_sharpness: DEFAULT_CAVE_SHARPNESS,
            cave_guard_depth: DEFAULT_CAVE_GUARD_DEPTH,
            cave_guard: DEFAULT_CAVE_GUARD,
            grass_layers: DEFAULT_GRASS_LAYERS,
            dirt_layers: DEFAULT_DIRT_LAYERS,
            bedrock_layers: DEFAULT_BEDROCK_LAYERS,
            bedrock_jitter: DEFAULT_BEDROCK_JITTER,
            ore_wavelength: DEFAULT_ORE_WAVELENGTH,
            ore_threshold: DEFAULT_ORE_THRESHOLD,
        }
    }
}

impl GenParams {
    /// Default parameters with another seed.
    pub fn with_seed(seed: u64) -> Self {
        Self {
            seed,
            ..Self::default()
        }
    }

    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), GenError> {
        let bad = |field: &'static str, reason: &'static str| {
            Err(GenError::InvalidParam { field, reason })
        };
        let in_range = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
        if self.min_y.unsigned_abs() > WORLD_Y_LIMIT as u32
            || self.max_y.unsigned_abs() > WORLD_Y_LIMIT as u32
        {
            return bad("min_y/max_y", "must be within ±2^20");
        }
        if self.max_y - self.min_y < MIN_WORLD_HEIGHT {
            return bad("max_y", "must be at least 64 above min_y");
        }
        let mag = MAX_PARAM_MAGNITUDE;
        if !in_range(self.base_height, -mag, mag) {
            return bad("base_height", "must be finite and within ±2^20");
        }
        if !in_range(self.hill_amplitude, 0.0, mag) {
            return bad("hill_amplitude", "must be finite and in 0..=2^20");
        }
        for (field, v) in [
            ("hill_wavelength", self.hill_wavelength),
            ("cave_wavelength", self.cave_wavelength),
            ("ore_wavelength", self.ore_wavelength),
        ] {
            if !in_range(v, MIN_WAVELENGTH, MAX_WAVELENGTH) {
                return bad(field, "must be finite and in 2..=2^20 voxels");
            }
        }
        if self.octaves == 0 || self.octaves > MAX_OCTAVES {
            return bad("octaves", "must be 1..=10");
        }
        if self.cave_octaves > MAX_OCTAVES {
            return bad("cave_octaves", "must be 0..=10");
        }
        if !in_range(
            self.surface_sharpness,
            MIN_SURFACE_SHARPNESS,
            MAX_SURFACE_SHARPNESS,
        ) {
            return bad("surface_sharpness", "must be in 1..=255 density per voxel");
        }
        if !in_range(self.cave_sharpness, MIN_CAVE_SHARPNESS, MAX_CAVE_SHARPNESS) {
            return bad("cave_sharpness", "must be in 16..=65536");
        }
        if !in_range(self.cave_flatness, 1.0 / 16.0, 16.0) {
            return bad("cave_flatness", "must be in 1/16..=16");
        }
        for (field, v) in [
            ("cave_threshold", self.cave_threshold),
            ("cave_guard", self.cave_guard),
            ("ore_threshold", self.ore_threshold),
        ] {
            if !in_range(v, -mag, mag) {
                return bad(field, "must be finite and within ±2^20");
            }
        }
        if !in_range(self.cave_guard_depth, 1.0, mag) {
            return bad("cave_guard_depth", "must be finite and in 1..=2^20");
        }
        for (field, v) in [
            ("grass_layers", self.grass_layers),
            ("dirt_layers", self.dirt_layers),
            ("bedrock_layers", self.bedrock_layers),
            ("bedrock_jitter", self.bedrock_jitter),
        ] {
            if v > MAX_LAYER_THICKNESS {
                return bad(field, "must be at most 64");
            }
        }
        if self.bedrock_layers == 0 {
            return bad(
                "bedrock_layers",
                "must be at least 1: the world needs a floor",
            );
        }
        // The surface must fit between the bedrock and the top band.
        let floor = self.min_y as f64 + (self.bedrock_layers + self.bedrock_jitter) as f64;
        let ceiling = self.max_y as f64 - 128.0 / self.surface_sharpness - 1.0;
        if ceiling <= floor {
            return bad("max_y", "leaves no room for a surface above the bedrock");
        }
        Ok(())
    }
}

/// Why a generator could not be built.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum GenError {
    #[error("invalid generation parameter {field}: {reason}")]
    InvalidParam {
        field: &'static str,
        reason: &'static str,
    },
}
