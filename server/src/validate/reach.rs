//! Reach: the edit's target must be near the player's eye.

use strata_protocol::RejectReason;
use strata_terrain::edit::Fixed;
use strata_terrain::{Edit, VoxelBox};

/// The point an edit aims at, seen from `eye`: a sphere's centre, or the
/// point of the edit's box nearest the eye.
pub fn target_point(edit: &Edit, bbox: &VoxelBox, eye: [f64; 3]) -> [f64; 3] {
    match edit {
        Edit::Mine { center, .. }
        | Edit::Explode { center, .. }
        | Edit::Build { center, .. }
        | Edit::Smooth { center, .. } => center.to_f64(),
        Edit::FillBox { .. } | Edit::ClearBox { .. } | Edit::PlaceStructure { .. } => {
            let lo = [bbox.min.x, bbox.min.y, bbox.min.z];
            let hi = [bbox.max.x, bbox.max.y, bbox.max.z];
            std::array::from_fn(|i| eye[i].clamp(lo[i] as f64, hi[i] as f64))
        }
    }
}

pub fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Rejects a target farther than `max` voxels from the eye.
pub fn check(eye: [f64; 3], target: [f64; 3], max: f64) -> Result<(), RejectReason> {
    let d = distance(eye, target);
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
    use strata_terrain::VoxelPos;

    #[test]
    fn box_target_is_nearest_point() {
        let b = VoxelBox::from_corners(VoxelPos::new(5, 0, 0), VoxelPos::new(9, 2, 2));
        let e = Edit::ClearBox {
            min: b.min,
            max: b.max,
        };
        assert_eq!(target_point(&e, &b, [0.0, 1.0, 1.0]), [5.0, 1.0, 1.0]);
        assert!(check([0.0, 1.0, 1.0], [5.0, 1.0, 1.0], 5.0).is_ok());
        assert!(matches!(
            check([0.0, 1.0, 1.0], [5.0, 1.0, 1.0], 4.5),
            Err(RejectReason::OutOfReach { .. })
        ));
    }
}
