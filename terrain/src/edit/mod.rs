//! Edit operations: data that describes a change to the world.
//!
//! An [`Edit`] is validated ([`Edit::validate`]) and then applied with
//! integer arithmetic only, so the same edit on the same world gives the
//! same bytes everywhere. Indestructible materials never change.

mod apply;
mod error;
pub mod fixed;
mod kernel;
mod limits;
mod region;
pub mod structure;

pub use apply::{ChunkChange, EditContext, EditOutcome};
pub use error::EditError;
pub use fixed::{Fixed, FixedVec3, COORD_LIMIT_VOXELS};
pub use limits::*;
pub use region::Region;
pub use structure::{Structure, StructureError, StructureId, StructureLibrary};

use serde::{Deserialize, Serialize};

use crate::material::MaterialId;
use crate::pos::VoxelPos;

/// One edit operation. Spheres are centred on fixed-point positions;
/// voxel `(i, j, k)` sits at the point `(i, j, k)`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Edit {
    /// Removes density in a sphere with a smooth rim just inside the
    /// radius; harder materials lose less (`strength * 16 / hardness`).
    Mine {
        center: FixedVec3,
        radius: Fixed,
        strength: u8,
    },
    /// Seed 000's crater: `damage = power * falloff²`, `falloff = 1 - d/r`.
    Explode {
        center: FixedVec3,
        radius: Fixed,
        power: u16,
    },
    /// Adds density of `material` in a sphere with a smooth rim just inside
    /// the radius.
    Build {
        center: FixedVec3,
        radius: Fixed,
        material: MaterialId,
        strength: u8,
    },
    /// Square stencil that fills an inclusive box solid with `material`.
    FillBox {
        min: VoxelPos,
        max: VoxelPos,
        material: MaterialId,
    },
    /// Square stencil that empties an inclusive box to air.
    ClearBox { min: VoxelPos, max: VoxelPos },
    /// Stamps a structure template at `origin` (its minimum corner after
    /// rotation), turned by `rotation` quarter turns about +Y.
    PlaceStructure {
        structure: StructureId,
        origin: VoxelPos,
        rotation: u8,
    },
    /// Relaxes density toward the 3×3×3 average, weighted by `1 - d/r`.
    Smooth {
        center: FixedVec3,
        radius: Fixed,
        strength: u8,
    },
}

/// The kind of an edit, for permissions, limits and metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum EditKind {
    Mine,
    Explode,
    Build,
    FillBox,
    ClearBox,
    PlaceStructure,
    Smooth,
}

impl EditKind {
    pub const ALL: [EditKind; 7] = [
        EditKind::Mine,
        EditKind::Explode,
        EditKind::Build,
        EditKind::FillBox,
        EditKind::ClearBox,
        EditKind::PlaceStructure,
        EditKind::Smooth,
    ];

    /// Stable lowercase name, used in configs and metrics.
    pub const fn name(self) -> &'static str {
        match self {
            EditKind::Mine => "mine",
            EditKind::Explode => "explode",
            EditKind::Build => "build",
            EditKind::FillBox => "fill_box",
            EditKind::ClearBox => "clear_box",
            EditKind::PlaceStructure => "place_structure",
            EditKind::Smooth => "smooth",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }
}

impl Edit {
    /// The voxel an edit belongs to: its centre, box corner or origin. A
    /// cluster routes it to the node writing this voxel's region.
    pub fn anchor(&self) -> VoxelPos {
        let at =
            |c: FixedVec3| VoxelPos::new(c.x.floor_voxel(), c.y.floor_voxel(), c.z.floor_voxel());
        match self {
            Edit::Mine { center, .. }
            | Edit::Explode { center, .. }
            | Edit::Build { center, .. }
            | Edit::Smooth { center, .. } => at(*center),
            Edit::FillBox { min, .. } | Edit::ClearBox { min, .. } => *min,
            Edit::PlaceStructure { origin, .. } => *origin,
        }
    }

    pub fn kind(&self) -> EditKind {
        match self {
            Edit::Mine { .. } => EditKind::Mine,
            Edit::Explode { .. } => EditKind::Explode,
            Edit::Build { .. } => EditKind::Build,
            Edit::FillBox { .. } => EditKind::FillBox,
            Edit::ClearBox { .. } => EditKind::ClearBox,
            Edit::PlaceStructure { .. } => EditKind::PlaceStructure,
            Edit::Smooth { .. } => EditKind::Smooth,
        }
    }

    /// Radius of a sphere edit, if it is one.
    pub fn radius(&self) -> Option<Fixed> {
        self.sphere().map(|(_, radius)| radius)
    }

    /// Centre and radius of a sphere edit, if it is one.
    pub fn sphere(&self) -> Option<(FixedVec3, Fixed)> {
        match self {
            Edit::Mine { center, radius, .. }
            | Edit::Explode { center, radius, .. }
            | Edit::Build { center, radius, .. }
            | Edit::Smooth { center, radius, .. } => Some((*center, *radius)),
            _ => None,
        }
    }

    /// Voxels outside the affected box that the edit reads (Smooth reads neighbours).
    pub fn read_margin(&self) -> i32 {
        match self {
            Edit::Smooth { .. } => 1,
            _ => 0,
        }
    }
}
