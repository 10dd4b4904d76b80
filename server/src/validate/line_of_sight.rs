//! Line of sight: a ray from the eye must reach the target before terrain.

use strata_protocol::RejectReason;
use strata_terrain::ChunkPos;

use super::reach::distance;
use crate::collision::{ray_chunks, CollisionCache};

/// Chunks whose meshes the sight line from `eye` to `target` needs.
pub fn sight_chunks(eye: [f64; 3], target: [f64; 3]) -> Vec<ChunkPos> {
    let d = [target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]];
    ray_chunks(eye, d, distance(eye, target))
}

/// Rejects when the first hit lies more than `tolerance` voxels before the
/// target. The caller passes the edit's radius plus the configured slack, so
/// aiming a sphere at a surface, or a box just behind one, still counts as seen.
/// Meshes of [`sight_chunks`] must be in `cache`.
pub fn check(
    cache: &CollisionCache,
    eye: [f64; 3],
    target: [f64; 3],
    tolerance: f64,
) -> Result<(), RejectReason> {
    let dist = distance(eye, target);
    if dist <= tolerance {
        return Ok(());
    }
    let d = [target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]];
    match cache.raycast(eye, d, dist) {
        Some(hit) if hit.t < dist - tolerance => Err(RejectReason::NoLineOfSight),
        _ => Ok(()),
    }
}
