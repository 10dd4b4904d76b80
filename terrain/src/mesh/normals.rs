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

/// Unnormalised normal (pointing into air) at quantized parameter `q / t_one` along an edge
/// whose endpoint gradients are `g0` (lower) and `g1` (upper): the gradient interpolated in
/// exact integer arithmetic, negated. Each component is below 2^24 in magnitude, so the f64
/// values and the sum of their squares are exact.
#[inline(always)]
pub(crate) fn raw_normal(g0: [i32; 3], g1: [i32; 3], q: u32, t_one: u32) -> [f64; 3] {
    let (w0, w1) = (i64::from(t_one - q), i64::from(q));
    // The gradient points towards higher density (into solid); the normal points out of it.
    [0, 1, 2].map(|a| -(i64::from(g0[a]) * w0 + i64::from(g1[a]) * w1) as f64)
}

/// Normal used when the interpolated gradient vanishes (flat plateaus): the edge direction
/// from its solid end towards its air end, so it is still unit length and deterministic.
#[inline(always)]
pub(crate) fn fallback_normal(axis: usize, lower_solid: bool) -> [f32; 3] {
    let sign = if lower_solid { 1.0 } else { -1.0 };
    [0, 1, 2].map(|a| if a == axis { sign } else { 0.0 })
}

/// Normalises the first `n` raw normals of a batch (`raw[axis][vertex]`, from [`raw_normal`])
/// once in f64: `c * (1 / sqrt(len2))`, rounded to f32. Zero vectors take their `flat` normal
/// instead.
///
/// The square roots and reciprocals run as one loop over plain arrays, so they vectorise
/// and overlap; each lane gives the same bits as the scalar formula.
#[inline(always)]
pub(crate) fn normalise<const N: usize>(
    raw: &[[f64; N]; 3],
    flat: &[[f32; 3]; N],
    out: &mut [[f32; 3]; N],
    n: usize,
) {
    let [x, y, z] = raw;
    let mut inv = [0.0f64; N];
    let n = n.min(N);
    for j in 0..n {
        let len2 = x[j] * x[j] + y[j] * y[j] + z[j] * z[j];
        // One division, then multiplies. A zero length gives infinity, replaced below.
        inv[j] = 1.0 / len2.sqrt();
    }
    for j in 0..n {
        out[j] = if inv[j].is_finite() {
            [x[j], y[j], z[j]].map(|c| (c * inv[j]) as f32)
        } else {
            flat[j]
        };
    }
}
