//! Where a bot can stand and what it can aim at, read from its replica:
//! positions must not be inside solid terrain, and edits must be within
//! reach and in sight of the eye.

use strata_terrain::VoxelPos;

use super::rng::Rng;
use crate::replica::Replica;

/// Voxels scanned above and below the hint when looking for the ground.
pub const SCAN_UP: i32 = 40;
pub const SCAN_DOWN: i32 = 60;
/// Largest height change a bot walks over in one step, in voxels.
pub const MAX_STEP: f64 = 4.0;
/// Horizontal distance of edit targets from the feet, in voxels.
pub const TARGET_MIN: i32 = 3;
pub const TARGET_MAX: i32 = 5;
/// Largest height difference between the feet's ground and a target.
pub const TARGET_MAX_DROP: i32 = 3;
/// Columns tried before a bot skips an edit.
pub const TARGET_TRIES: usize = 8;

/// The highest solid voxel of column `(x, z)` near `hint_y` that has
/// non-solid voxels above it. Unheld voxels above count as air; the ground
/// voxel itself must be held.
pub fn ground(replica: &Replica, x: i32, z: i32, hint_y: i32) -> Option<i32> {
    let mut above_free = true;
    for y in (hint_y - SCAN_DOWN..=hint_y + SCAN_UP).rev() {
        match replica.voxel(VoxelPos::new(x, y, z)) {
            Some(v) if v.is_solid() => {
                if above_free {
                    return Some(y);
                }
            }
            _ => above_free = true,
        }
    }
    None
}

/// The feet position of a bot standing on column `(x, z)`.
pub fn stand(replica: &Replica, x: f64, z: f64, hint_y: f64) -> Option<[f64; 3]> {
    let (cx, cz) = (x.round() as i32, z.round() as i32);
    let g = ground(replica, cx, cz, hint_y.round() as i32)?;
    Some([x, g as f64 + 1.0, z])
}

/// A ground voxel a few voxels away at about the feet's height.
pub fn pick_target(replica: &Replica, feet: [f64; 3], rng: &mut Rng) -> Option<VoxelPos> {
    let (fx, fz) = (feet[0].round() as i32, feet[2].round() as i32);
    let own = feet[1].round() as i32 - 1;
    for _ in 0..TARGET_TRIES {
        let (dx, dz) = (
            rng.range(-TARGET_MAX, TARGET_MAX),
            rng.range(-TARGET_MAX, TARGET_MAX),
        );
        let d2 = dx * dx + dz * dz;
        if !(TARGET_MIN * TARGET_MIN..=TARGET_MAX * TARGET_MAX).contains(&d2) {
            continue;
        }
        let Some(gy) = ground(replica, fx + dx, fz + dz, own) else {
            continue;
        };
        if (gy - own).abs() <= TARGET_MAX_DROP {
            return Some(VoxelPos::new(fx + dx, gy, fz + dz));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use strata_protocol::WorldUpdate;
    use strata_terrain::gen::{GenParams, Generator};
    use strata_terrain::ChunkGenerator;

    #[test]
    fn stands_on_the_generated_surface_and_aims_nearby() {
        let g = Arc::new(Generator::fractal(GenParams::default()).unwrap());
        let (x, z) = (600, 600);
        let surface = g.surface_height(x, z).floor() as i32;
        let mut replica = Replica::new(Some(g.clone() as Arc<dyn ChunkGenerator>));
        let center = VoxelPos::new(x, surface, z).chunk();
        for dy in -2..=2 {
            for dz in -1..=1 {
                for dx in -1..=1 {
                    let pos = center.offset(dx, dy, dz).unwrap();
                    replica.apply(WorldUpdate::Generated { pos });
                }
            }
        }
        let feet = stand(&replica, x as f64, z as f64, surface as f64).unwrap();
        let gy = feet[1] as i32 - 1;
        assert!(replica.voxel(VoxelPos::new(x, gy, z)).unwrap().is_solid());
        for y in gy + 1..gy + 4 {
            assert!(!replica.voxel(VoxelPos::new(x, y, z)).unwrap().is_solid());
        }
        let mut rng = Rng::new(3, 0);
        let t = pick_target(&replica, feet, &mut rng).expect("flat enough nearby");
        let d2 = (t.x - x).pow(2) + (t.z - z).pow(2);
        assert!((TARGET_MIN.pow(2)..=TARGET_MAX.pow(2)).contains(&d2));
        assert!(replica.voxel(t).unwrap().is_solid());
        // Nothing is held far away: no footing there.
        assert!(stand(&replica, 5000.0, 5000.0, 0.0).is_none());
    }
}
