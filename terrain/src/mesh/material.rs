//! Per-vertex material.
//!
//! A vertex sits on one sign-changing edge, which has exactly one solid endpoint, so seed 001's
//! "dominant material of the solid corners" becomes the material of that endpoint, and every
//! chunk sharing the edge computes the same value (no material seams).
//!
//! On coarse edges (longer than one voxel, i.e. LOD >= 1 or the coarse side of a transition
//! cell) seed 001's LOD surface scan applies: climb +Y (up) from the solid endpoint while the
//! samples stay solid, at most [`MAX_SURFACE_SCAN`] voxels, and take the last solid material.
//! Strided corners often sit below a thin grass layer; the scan finds the grass above them, so
//! grass stays grass at coarse LOD. With one solid corner per vertex, "the highest surface among
//! the solid corners" is this single scan.

use super::neighborhood::{MAX_SURFACE_SCAN, STEP_Y};

/// Material of a vertex whose edge has its solid endpoint at neighbourhood index `solid_at`
/// and is `len` voxels long.
#[inline]
pub(crate) fn vertex_material(
    density: &[u8],
    material: &[u8],
    iso: f32,
    solid_at: usize,
    len: u32,
) -> u8 {
    let mut i = solid_at;
    let mut last = material[i];
    if len > 1 {
        for _ in 0..MAX_SURFACE_SCAN {
            i += STEP_Y;
            if f32::from(density[i]) > iso {
                last = material[i];
            } else {
                break;
            }
        }
    }
    last
}
