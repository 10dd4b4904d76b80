//! Material layers: grass over dirt over stone (with ore), bedrock below.

use super::noise::{hash2, sub_seed};
use super::params::GenParams;
use crate::material::{ids, MaterialId};

/// Seed layer of the bedrock floor's unevenness.
const BEDROCK_LAYER: u64 = 4;

/// The layer thicknesses of one world.
#[derive(Debug, Clone)]
pub(crate) struct Layers {
    grass: i64,
    soil: i64,
    bedrock_base: i64,
    bedrock_jitter: u64,
    bedrock_seed: u64,
}

impl Layers {
    pub(crate) fn new(p: &GenParams) -> Self {
        Self {
            grass: p.grass_layers as i64,
            soil: (p.grass_layers + p.dirt_layers) as i64,
            bedrock_base: p.min_y as i64 + p.bedrock_layers as i64,
            bedrock_jitter: p.bedrock_jitter as u64,
            bedrock_seed: sub_seed(p.seed, BEDROCK_LAYER),
        }
    }

    /// Voxels below this y are bedrock in column `(x, z)`: `min_y` plus the
    /// base thickness plus a hashed 0..=jitter extra.
    pub(crate) fn bedrock_top(&self, x: i64, z: i64) -> i64 {
        let extra = hash2(self.bedrock_seed, x, z) % (self.bedrock_jitter + 1);
        self.bedrock_base + extra as i64
    }

    /// Below this y every column is bedrock.
    pub(crate) fn bedrock_min_top(&self) -> i64 {
        self.bedrock_base
    }

    /// Above this y no column is bedrock.
    pub(crate) fn bedrock_max_top(&self) -> i64 {
        self.bedrock_base + self.bedrock_jitter as i64
    }

    /// Grass plus dirt thickness: stone (and ore) starts this far below the top voxel.
    pub(crate) fn soil(&self) -> i64 {
        self.soil
    }

    /// Material of a non-air, non-bedrock voxel `layer` voxels below its
    /// column's top solid voxel. Negative layers (the partly filled voxels
    /// just above the surface) take the top material, so both corners of a
    /// surface edge agree on it.
    #[inline]
    pub(crate) fn material(&self, layer: i64, ore: bool) -> MaterialId {
        if layer < self.grass {
            ids::GRASS
        } else if layer < self.soil {
            ids::DIRT
        } else if ore {
            ids::ORE
        } else {
            ids::STONE
        }
    }
}
