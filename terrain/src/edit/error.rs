use thiserror::Error;

use super::fixed::Fixed;
use super::structure::StructureId;
use crate::material::MaterialId;

/// Why an edit was refused. A refused edit changes nothing.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum EditError {
    #[error("coordinates out of range: |coordinate| must stay below {limit} voxels")]
    CoordinateOutOfRange { limit: i32 },
    #[error("radius {radius} voxels is outside {min}..={max}", radius = .radius.to_f64(), min = .min.to_f64(), max = .max.to_f64())]
    RadiusOutOfRange {
        radius: Fixed,
        min: Fixed,
        max: Fixed,
    },
    #[error("explosion power {power} is over the cap {max}")]
    PowerOutOfRange { power: u16, max: u16 },
    #[error("strength must be at least 1")]
    ZeroStrength,
    #[error("box min is above max on some axis")]
    InvertedBox,
    #[error("box edge of {edge} voxels is over the cap {max}")]
    BoxTooLarge { edge: i64, max: i32 },
    #[error("a build of material 0 (air) would be an invisible solid")]
    AirBuild,
    #[error("unknown material id {0}")]
    UnknownMaterial(MaterialId),
    #[error("material id {0} is indestructible and cannot be placed")]
    IndestructibleMaterial(MaterialId),
    #[error("unknown structure id {0}")]
    UnknownStructure(StructureId),
    #[error("rotation must be 0..=3 quarter turns, got {0}")]
    BadRotation(u8),
    #[error("the sphere holds no voxel centre strictly inside its radius")]
    NoVoxel,
    #[error("chunk ({}, {}, {}) is at the highest version a chunk may have", .pos.x, .pos.y, .pos.z)]
    VersionExhausted { pos: crate::ChunkPos },
}
