//! Reach: the edit's target must be near the player's eye.

use glam::DVec3;
use strata_protocol::RejectReason;
use strata_terrain::edit::Fixed;
use strata_terrain::{Edit, VoxelBox, VoxelPos};

use super::position::to_dvec3;

fn voxel_point(v: VoxelPos) -> DVec3 {
    DVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

/// The point an edit aims at, seen from `eye`: a sphere's centre, or the
/// point of the edit's box nearest the eye.
pub fn target_point(edit: &Edit, bbox: &VoxelBox, eye: DVec3) -> DVec3 {
    match edit {
        Edit::Mine { center, .. }
        | Edit::Explode { center, .. }
        | Edit::Build { center, .. }
        | Edit::Smooth { center, .. } => to_dvec3(*center),
        Edit::FillBox { .. } | Edit::ClearBox { .. } | Edit::PlaceStructure { .. } => {
            eye.clamp(voxel_point(bbox.min), voxel_point(bbox.max))
        }
    }
}

/// Rejects a target farther than `max` voxels from the eye.
pub fn check(eye: DVec3, target: DVec3, max: f64) -> Result<(), RejectReason> {
    let d = eye.distance(target);
    if d <= max {
        Ok(())
    } else {
        let fixed = |v: f64| Fixed::from_f64(v).unwrap_or(Fixed(i32::MAX));
        Err(RejectReason::OutOfReach {
            distance: fixed(d),
            max: fixed(max),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_target_is_nearest_point() {
        let b = VoxelBox::from_corners(VoxelPos::new(5, 0, 0), VoxelPos::new(9, 2, 2));
        let e = Edit::ClearBox {
            min: b.min,
            max: b.max,
        };
        let eye = DVec3::new(0.0, 1.0, 1.0);
        let target = DVec3::new(5.0, 1.0, 1.0);
        assert_eq!(target_point(&e, &b, eye), target);
        assert!(check(eye, target, 5.0).is_ok());
        assert!(matches!(
            check(eye, target, 4.5),
            Err(RejectReason::OutOfReach { .. })
        ));
    }
}
