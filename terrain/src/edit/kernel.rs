//! Per-voxel rules of each edit, in integer arithmetic.
//!
//! A kernel maps (position, old voxel, read access to the pre-edit world)
//! to the new voxel. Chunked and whole-array application share it, which is
//! what makes them agree voxel for voxel.

use super::fixed::{isqrt, Fixed, FixedVec3, FRAC_BITS};
use super::limits::SPHERE_RIM;
use super::structure::Structure;
use super::Edit;
use crate::chunk::Voxel;
use crate::material::{MaterialTable, REFERENCE_HARDNESS};
use crate::pos::VoxelPos;
use crate::world::VoxelRead;

/// Q16 one.
const Q16: i64 = 1 << 16;

/// Squared distance from a fixed-point centre to voxel `p`, in Q32.
fn distance_sq_q32(c: FixedVec3, p: VoxelPos) -> u64 {
    let d = |v: i32, c: i32| ((v as i64) << FRAC_BITS) - c as i64;
    let (dx, dy, dz) = (d(p.x, c.x.0), d(p.y, c.y.0), d(p.z, c.z.0));
    // Q8 squared is Q16; shift to Q32 so the root is Q16.
    ((dx * dx + dy * dy + dz * dz) as u64) << 16
}

/// Distance from a fixed-point centre to voxel `p`, in Q16 voxels.
fn distance_q16(c: FixedVec3, p: VoxelPos) -> i64 {
    isqrt(distance_sq_q32(c, p)) as i64
}

/// Whether voxel `p` lies at or beyond `radius` from `c`, where every
/// sphere brush's weight is 0: exactly `distance_q16 >= radius` (the root
/// is the floor), without the root.
pub(super) fn beyond(c: FixedVec3, p: VoxelPos, radius: Fixed) -> bool {
    let r = q8_to_q16(radius.0);
    r <= 0 || u128::from(distance_sq_q32(c, p)) >= (r as u128) * (r as u128)
}

/// Rim weight in Q16: 1 inside `r - rim`, 0 from `r` on, linear between.
/// The radius is the brush's outer extent, so nothing beyond it changes.
fn rim_weight(d: i64, r_q16: i64) -> i64 {
    let rim = SPHERE_RIM as i64 * Q16;
    ((r_q16 - d) * Q16 / rim).clamp(0, Q16)
}

/// Linear falloff `1 - d/r` in Q16, 0 outside.
fn falloff(d: i64, r_q16: i64) -> i64 {
    if d >= r_q16 {
        0
    } else {
        (r_q16 - d) * Q16 / r_q16
    }
}

fn q8_to_q16(v: i32) -> i64 {
    (v as i64) << 8
}

/// Applies an edit to one voxel. `src` shows the world before the edit.
pub(crate) fn apply_voxel(
    edit: &Edit,
    structure: Option<&Structure>,
    materials: &MaterialTable,
    p: VoxelPos,
    old: Voxel,
    src: &dyn VoxelRead,
    footprint_min: VoxelPos,
) -> Voxel {
    if materials.is_indestructible(old.material) {
        return old;
    }
    // Every sphere brush leaves what lies at or beyond its radius alone.
    if edit
        .sphere()
        .is_some_and(|(center, radius)| beyond(center, p, radius))
    {
        return old;
    }
    match *edit {
        Edit::Mine {
            center,
            radius,
            strength,
        } => {
            let w = rim_weight(distance_q16(center, p), q8_to_q16(radius.0));
            let hardness = materials.hardness(old.material).max(1) as i64;
            let amount = strength as i64 * w * REFERENCE_HARDNESS as i64 / hardness / Q16;
            Voxel::new(
                (old.density as i64 - amount.min(255)).max(0) as u8,
                old.material,
            )
        }
        Edit::Explode {
            center,
            radius,
            power,
        } => {
            let f = falloff(distance_q16(center, p), q8_to_q16(radius.0));
            let damage = (power as i64 * f * f) >> 32;
            Voxel::new((old.density as i64 - damage).max(0) as u8, old.material)
        }
        Edit::Build {
            center,
            radius,
            material,
            strength,
        } => {
            let w = rim_weight(distance_q16(center, p), q8_to_q16(radius.0));
            let amount = strength as i64 * w / Q16;
            if amount == 0 {
                return old;
            }
            let density = (old.density as i64 + amount).min(255) as u8;
            let material = if old.is_solid() {
                old.material
            } else {
                material
            };
            Voxel::new(density, material)
        }
        Edit::FillBox { material, .. } => Voxel::solid(material),
        Edit::ClearBox { .. } => Voxel::AIR,
        Edit::PlaceStructure { rotation, .. } => {
            let s = structure.expect("validated: structure exists");
            let t = s.rotated_voxel(
                rotation,
                (p.x - footprint_min.x) as u16,
                (p.y - footprint_min.y) as u16,
                (p.z - footprint_min.z) as u16,
            );
            if t.density == 0 {
                old
            } else {
                t
            }
        }
        Edit::Smooth {
            center,
            radius,
            strength,
        } => {
            let f = falloff(distance_q16(center, p), q8_to_q16(radius.0));
            if f == 0 {
                return old;
            }
            smooth_voxel(p, old, src, materials, strength as i64 * f / 255)
        }
    }
}

/// Moves density toward the 3×3×3 mean by `weight` (Q16). A voxel made
/// solid takes the most common placeable solid neighbour material; with
/// none (only indestructible ones, say bedrock) it stays below solid, so
/// smoothing never grows what no edit may place.
fn smooth_voxel(
    p: VoxelPos,
    old: Voxel,
    src: &dyn VoxelRead,
    materials: &MaterialTable,
    weight: i64,
) -> Voxel {
    let neighbours = || {
        (-1..=1).flat_map(move |dz| {
            (-1..=1).flat_map(move |dy| {
                (-1..=1).map(move |dx| src.voxel(VoxelPos::new(p.x + dx, p.y + dy, p.z + dz)))
            })
        })
    };
    let sum: i64 = neighbours().map(|n| n.density as i64).sum();
    // Round the mean to nearest; truncate the step toward zero.
    let mean = (sum * 2 + 27) / 54;
    let mut density =
        (old.density as i64 + (mean - old.density as i64) * weight / Q16).clamp(0, 255) as u8;
    let mut material = old.material;
    if !old.is_solid() && density >= crate::chunk::SOLID_THRESHOLD {
        // Newly solid: take the most common placeable solid neighbour
        // material (lowest id on ties), counted only here.
        let mut counts = [0u8; 256];
        for n in neighbours() {
            let placeable =
                materials.get(n.material).is_some() && !materials.is_indestructible(n.material);
            if n.is_solid() && placeable {
                counts[n.material as usize] += 1;
            }
        }
        match counts
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .max_by_key(|(i, c)| (**c, usize::MAX - i))
        {
            Some((m, _)) => material = m as u8,
            None => density = crate::chunk::SOLID_THRESHOLD - 1,
        }
    }
    Voxel::new(density, material)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights() {
        let r = 4 * Q16;
        assert_eq!(rim_weight(0, r), Q16);
        assert_eq!(rim_weight(2 * Q16, r), Q16);
        assert_eq!(rim_weight(3 * Q16, r), Q16 / 2);
        assert_eq!(rim_weight(4 * Q16, r), 0);
        assert_eq!(falloff(0, r), Q16);
        assert_eq!(falloff(2 * Q16, r), Q16 / 2);
        assert_eq!(falloff(r, r), 0);
    }

    #[test]
    fn beyond_is_the_rounded_distance_against_the_radius() {
        let c = FixedVec3::new(Fixed(37), Fixed(-300), Fixed(129));
        for r in [0, 1, 255, 256, 700, 1024, 3 * 256 + 17] {
            for x in -6..=6 {
                for y in -6..=6 {
                    for z in -6..=6 {
                        let p = VoxelPos::new(x, y, z);
                        let far = distance_q16(c, p) >= q8_to_q16(r);
                        assert_eq!(beyond(c, p, Fixed(r)), far, "r={r} p={p:?}");
                    }
                }
            }
        }
        assert!(beyond(c, VoxelPos::new(0, 0, 0), Fixed(-5)));
    }

    #[test]
    fn distance_is_exact_on_axes() {
        let c = FixedVec3::from_voxels(0, 0, 0);
        assert_eq!(distance_q16(c, VoxelPos::new(3, 0, 0)), 3 * Q16);
        assert_eq!(distance_q16(c, VoxelPos::new(3, 4, 0)), 5 * Q16);
        assert_eq!(distance_q16(c, VoxelPos::new(-3, 0, -4)), 5 * Q16);
    }
}
