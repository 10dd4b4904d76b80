//! Server caps on sphere radius and explosion power, below the terrain core's hard caps.

use strata_protocol::RejectReason;
use strata_terrain::edit::Fixed;
use strata_terrain::Edit;

/// Rejects a sphere whose radius is over `max_radius` or an explosion over `max_power`.
pub fn check(edit: &Edit, max_radius: Fixed, max_power: u16) -> Result<(), RejectReason> {
    if let Some(r) = edit.radius() {
        if r > max_radius {
            return Err(RejectReason::RadiusTooLarge { max: max_radius });
        }
    }
    if let Edit::Explode { power, .. } = edit {
        if *power > max_power {
            return Err(RejectReason::PowerTooLarge { max: max_power });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::edit::FixedVec3;

    #[test]
    fn radius_and_power() {
        let e = |r: i32, power: u16| Edit::Explode {
            center: FixedVec3::from_voxels(0, 0, 0),
            radius: Fixed::from_voxels(r),
            power,
        };
        let max_r = Fixed::from_voxels(8);
        assert!(check(&e(8, 100), max_r, 100).is_ok());
        assert_eq!(
            check(&e(9, 100), max_r, 100),
            Err(RejectReason::RadiusTooLarge { max: max_r })
        );
        assert_eq!(
            check(&e(8, 101), max_r, 100),
            Err(RejectReason::PowerTooLarge { max: 100 })
        );
    }
}
