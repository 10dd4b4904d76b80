//! Typed edits from glam vectors: each constructor rounds the game's f64
//! coordinates to the wire's Q24.8 once, here, and refuses what cannot be
//! sent (a coordinate that is not finite or is out of range).

use glam::{DVec3, IVec3};
use strata_terrain::edit::StructureId;
use strata_terrain::{Edit, Fixed, MaterialId};
use thiserror::Error;

use crate::coords::{to_fixed, voxel_pos};

/// Why an edit could not be built.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum EditBuildError {
    #[error("the center is not finite or out of the fixed-point range")]
    BadCenter,
    #[error("the radius is not finite or out of the fixed-point range")]
    BadRadius,
}

fn sphere(
    center: DVec3,
    radius: f64,
) -> Result<(strata_terrain::FixedVec3, Fixed), EditBuildError> {
    let c = to_fixed(center).ok_or(EditBuildError::BadCenter)?;
    let r = Fixed::from_f64(radius).ok_or(EditBuildError::BadRadius)?;
    Ok((c, r))
}

/// Removes density in a sphere.
pub fn mine(center: DVec3, radius: f64, strength: u8) -> Result<Edit, EditBuildError> {
    let (center, radius) = sphere(center, radius)?;
    Ok(Edit::Mine {
        center,
        radius,
        strength,
    })
}

/// A crater of `power` in a sphere.
pub fn explode(center: DVec3, radius: f64, power: u16) -> Result<Edit, EditBuildError> {
    let (center, radius) = sphere(center, radius)?;
    Ok(Edit::Explode {
        center,
        radius,
        power,
    })
}

/// Adds density of `material` in a sphere.
pub fn build(
    center: DVec3,
    radius: f64,
    material: MaterialId,
    strength: u8,
) -> Result<Edit, EditBuildError> {
    let (center, radius) = sphere(center, radius)?;
    Ok(Edit::Build {
        center,
        radius,
        material,
        strength,
    })
}

/// Relaxes density toward the local average in a sphere.
pub fn smooth(center: DVec3, radius: f64, strength: u8) -> Result<Edit, EditBuildError> {
    let (center, radius) = sphere(center, radius)?;
    Ok(Edit::Smooth {
        center,
        radius,
        strength,
    })
}

/// Fills the inclusive voxel box `min..=max` solid with `material`.
pub fn fill_box(min: IVec3, max: IVec3, material: MaterialId) -> Edit {
    Edit::FillBox {
        min: voxel_pos(min),
        max: voxel_pos(max),
        material,
    }
}

/// Empties the inclusive voxel box `min..=max` to air.
pub fn clear_box(min: IVec3, max: IVec3) -> Edit {
    Edit::ClearBox {
        min: voxel_pos(min),
        max: voxel_pos(max),
    }
}

/// Stamps structure `structure` at `origin`, turned `rotation` quarter
/// turns about +Y.
pub fn place_structure(structure: StructureId, origin: IVec3, rotation: u8) -> Edit {
    Edit::PlaceStructure {
        structure,
        origin: voxel_pos(origin),
        rotation,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::FixedVec3;

    #[test]
    fn spheres_round_to_the_wire_and_refuse_non_finite_values() {
        let e = mine(DVec3::new(1.0, 2.5, -3.0), 2.0, 40).unwrap();
        assert_eq!(
            e,
            Edit::Mine {
                center: FixedVec3::new(Fixed(256), Fixed(640), Fixed(-768)),
                radius: Fixed(512),
                strength: 40,
            }
        );
        assert_eq!(
            build(DVec3::new(f64::NAN, 0.0, 0.0), 1.0, 3, 9),
            Err(EditBuildError::BadCenter)
        );
        assert_eq!(
            explode(DVec3::ZERO, f64::INFINITY, 9),
            Err(EditBuildError::BadRadius)
        );
    }
}
