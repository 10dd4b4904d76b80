//! Vertex normals from the density gradient, by central differences over the apron.
//!
//! Gradients are integers (differences of u8 samples one voxel apart), interpolated along the
//! edge with the quantized edge parameter in exact integer arithmetic, and normalised once in
//! f64. So a vertex's normal depends only on its edge's two endpoints and their six
//! neighbours, and is bit-identical in every chunk that shares the edge: no lighting seams.

use super::neighborhood::{STEP_Y, STEP_Z};

/// Density gradient at the sample with neighbourhood index `i` (uses the samples one voxel
/// away on each axis).
#[inline(always)]
pub(crate) fn gradient(density: &[u8], i: usize) -> [i32; 3] {
    let d = |j: usize| density[j] as i32;
    [
        d(i + 1) - d(i - 1),
        d(i + STEP_Y) - d(i - STEP_Y),
        d(i + STEP_Z) - d(i - STEP_Z),
    ]
}

/// Unit normal pointing into air for a vertex at quantized parameter `q / T_ONE` along an edge
/// whose endpoint gradients are `g0` (lower) and `g1` (upper).
///
/// When the interpolated gradient vanishes (flat plateaus), the normal is the edge direction
/// from its solid end towards its air end, so it is still unit length and deterministic.
pub(crate) fn edge_normal(
    g0: [i32; 3],
    g1: [i32; 3],
    q: u32,
    t_one: u32,
    axis: usize,
    lower_solid: bool,
) -> [f32; 3] {
    let (w0, w1) = (i64::from(t_one - q), i64::from(q));
    // The gradient points towards higher density (into solid); the normal points out of it.
    let n = [0, 1, 2].map(|a| -(i64::from(g0[a]) * w0 + i64::from(g1[a]) * w1) as f64);
    let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    if len2 > 0.0 {
        // One division, then multiplies: the normal is on the hot path.
        let inv = 1.0 / len2.sqrt();
        n.map(|c| (c * inv) as f32)
    } else {
        let mut f = [0.0f32; 3];
        f[axis] = if lower_solid { 1.0 } else { -1.0 };
        f
    }
}
