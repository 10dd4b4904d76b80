//! Line of sight: a ray from the eye must reach the target before terrain.

use glam::DVec3;
use strata_protocol::RejectReason;
use strata_terrain::ChunkPos;

use crate::collision::{ray_chunks, CollisionCache};

/// Chunks whose meshes the sight line from `eye` to `target` needs.
pub fn sight_chunks(eye: DVec3, target: DVec3) -> Vec<ChunkPos> {
    let d = target - eye;
    ray_chunks(eye.to_array(), d.to_array(), d.length())
}

/// Rejects when the first hit lies more than `tolerance` voxels before the
/// target. The caller passes the edit's radius plus the configured slack, so
/// aiming a sphere at a surface, or a box just behind one, still counts as seen.
/// Meshes of [`sight_chunks`] must be in `cache`.
pub fn check(
    cache: &CollisionCache,
    eye: DVec3,
    target: DVec3,
    tolerance: f64,
) -> Result<(), RejectReason> {
    let d = target - eye;
    let dist = d.length();
    if dist <= tolerance {
        return Ok(());
    }
    match cache.raycast(eye.to_array(), d.to_array(), dist) {
        Some(hit) if hit.t < dist - tolerance => Err(RejectReason::NoLineOfSight),
        _ => Ok(()),
    }
}
