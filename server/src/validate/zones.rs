//! Protected zones: boxes where players may not edit (admins may).

use serde::{Deserialize, Serialize};
use strata_protocol::{RejectReason, Role};
use strata_terrain::{VoxelBox, VoxelPos};
use thiserror::Error;

/// Name of the zone created around the origin by default.
pub const SPAWN_ZONE_NAME: &str = "spawn";
/// Longest zone name, in bytes.
pub const MAX_ZONE_NAME_LEN: usize = 64;
/// Most zones the server holds (each edit is checked against all of them).
pub const MAX_ZONES: usize = 1024;

/// A named protected box (inclusive voxel corners).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Zone {
    pub name: String,
    pub min: VoxelPos,
    pub max: VoxelPos,
}

/// Why a zone could not be added.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ZoneError {
    #[error("zone name must be 1..={MAX_ZONE_NAME_LEN} bytes")]
    BadName,
    #[error("zone {0:?} already exists")]
    Duplicate(String),
    #[error("zone min is above max on some axis")]
    InvertedBox,
    #[error("at most {MAX_ZONES} zones")]
    TooMany,
}

impl Zone {
    /// The default spawn protection: a cube of half-width `radius` voxels around the origin.
    pub fn spawn(radius: i32) -> Self {
        let r = radius.abs();
        Self {
            name: SPAWN_ZONE_NAME.to_string(),
            min: VoxelPos::new(-r, -r, -r),
            max: VoxelPos::new(r, r, r),
        }
    }

    pub fn bounds(&self) -> VoxelBox {
        VoxelBox {
            min: self.min,
            max: self.max,
        }
    }

    fn check_shape(&self) -> Result<(), ZoneError> {
        if self.name.is_empty() || self.name.len() > MAX_ZONE_NAME_LEN {
            return Err(ZoneError::BadName);
        }
        if self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z {
            return Err(ZoneError::InvertedBox);
        }
        Ok(())
    }
}

/// Checks a zone before it joins `existing`.
pub fn check_new(existing: &[Zone], zone: &Zone) -> Result<(), ZoneError> {
    zone.check_shape()?;
    if existing.iter().any(|z| z.name == zone.name) {
        return Err(ZoneError::Duplicate(zone.name.clone()));
    }
    if existing.len() >= MAX_ZONES {
        return Err(ZoneError::TooMany);
    }
    Ok(())
}

/// Rejects a player's edit whose box overlaps any zone; admins are exempt.
pub fn check(zones: &[Zone], role: Role, bbox: &VoxelBox) -> Result<(), RejectReason> {
    if role == Role::Admin {
        return Ok(());
    }
    match zones.iter().find(|z| z.bounds().intersect(bbox).is_some()) {
        Some(z) => Err(RejectReason::ProtectedZone {
            zone: z.name.clone(),
        }),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlap_rejects_players_only() {
        let zones = vec![Zone::spawn(4)];
        let inside = VoxelBox::from_corners(VoxelPos::new(3, 0, 3), VoxelPos::new(6, 1, 6));
        let outside = VoxelBox::from_corners(VoxelPos::new(5, 0, 5), VoxelPos::new(6, 1, 6));
        assert_eq!(
            check(&zones, Role::Player, &inside),
            Err(RejectReason::ProtectedZone {
                zone: "spawn".into()
            })
        );
        assert!(check(&zones, Role::Admin, &inside).is_ok());
        assert!(check(&zones, Role::Player, &outside).is_ok());
    }

    #[test]
    fn new_zone_checks() {
        let zones = vec![Zone::spawn(4)];
        assert_eq!(
            check_new(&zones, &Zone::spawn(1)),
            Err(ZoneError::Duplicate("spawn".into()))
        );
        let bad = Zone {
            name: "x".into(),
            min: VoxelPos::new(1, 0, 0),
            max: VoxelPos::new(0, 0, 0),
        };
        assert_eq!(check_new(&zones, &bad), Err(ZoneError::InvertedBox));
        let empty = Zone {
            name: String::new(),
            ..Zone::spawn(1)
        };
        assert_eq!(check_new(&zones, &empty), Err(ZoneError::BadName));
    }
}
