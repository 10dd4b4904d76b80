//! Where players the server does not remember may appear: a square of
//! columns around a spawn column (`[validation.spawn]`).

use serde::{Deserialize, Serialize};
use strata_protocol::Start;
use strata_terrain::edit::COORD_LIMIT_VOXELS;

/// Default half-width of the spawn square, in voxels: room for a large
/// crowd of new players (the bots' default area fits inside).
pub const DEFAULT_SPAWN_RADIUS: u32 = 2048;
/// Largest accepted centre coordinate or half-width: the position range.
pub const MAX_SPAWN_COORD: i32 = COORD_LIMIT_VOXELS - 1;

/// Most chunk rows above the eye's that a first report's open sky is
/// read in (`open_sky`): 512 voxels of cover whatever the world's height,
/// so a first report never makes a tall world's whole column resident.
pub const MAX_SKY_CHUNKS: i32 = 16;

/// The spawn square: columns within `radius` voxels of (`x`, `z`) on both
/// axes; with `open_sky`, under the open sky (no solid voxel above the
/// eye, up to the world's top or [`MAX_SKY_CHUNKS`] rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpawnArea {
    pub x: i32,
    pub z: i32,
    pub radius: u32,
    /// A new player appears on the surface, never in a sealed room or a
    /// cave beneath it. Off for worlds whose spawn lies under a roof
    /// (a spawn hall, an underground start).
    pub open_sky: bool,
}

impl Default for SpawnArea {
    fn default() -> Self {
        Self {
            x: 0,
            z: 0,
            radius: DEFAULT_SPAWN_RADIUS,
            open_sky: true,
        }
    }
}

impl SpawnArea {
    /// The `Welcome::start` of a player with no remembered position.
    pub fn start(&self) -> Start {
        Start::Spawn {
            x: self.x,
            z: self.z,
            radius: self.radius,
        }
    }
}
