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
    // Explicit lanes: `array::map` was sometimes left as an out-of-line call.
    let n = |a: usize| -(i64::from(g0[a]) * w0 + i64::from(g1[a]) * w1) as f64;
    [n(0), n(1), n(2)]
}

/// Normal used when the interpolated gradient vanishes (flat plateaus): the edge direction
/// from its solid end towards its air end, so it is still unit length and deterministic.
#[inline(always)]
pub(crate) fn fallback_normal(axis: usize, lower_solid: bool) -> [f32; 3] {
    let sign = if lower_solid { 1.0 } else { -1.0 };
    let c = |a: usize| if a == axis { sign } else { 0.0 };
    [c(0), c(1), c(2)]
}

/// Normalises the first `n` raw normals of a batch (`raw[axis][vertex]`, from
/// [`raw_normal`]) once in f64: `c * (1 / sqrt(len2))`, rounded to f32. Zero vectors take
/// `flat(vertex)` instead.
///
/// The square roots and reciprocals run as one loop over plain arrays, so they vectorise
/// and overlap; each lane gives the same bits as the scalar formula. A full batch takes a
/// fixed-length path (no remainder loop).
#[inline(always)]
pub(crate) fn normalise<const N: usize>(
    raw: &[[f64; N]; 3],
    flat: impl Fn(usize) -> [f32; 3],
    out: &mut [[f32; 3]; N],
    n: usize,
) {
    if n >= N {
        normalise_lanes(raw, flat, out, N);
    } else {
        normalise_lanes(raw, flat, out, n);
    }
}

#[inline(always)]
fn normalise_lanes<const N: usize>(
    raw: &[[f64; N]; 3],
    flat: impl Fn(usize) -> [f32; 3],
    out: &mut [[f32; 3]; N],
    n: usize,
) {
    let [x, y, z] = raw;
    let mut inv = [0.0f64; N];
    for j in 0..n {
        let len2 = x[j] * x[j] + y[j] * y[j] + z[j] * z[j];
        // One division, then multiplies. A zero length gives infinity, replaced below.
        inv[j] = 1.0 / len2.sqrt();
    }
    for j in 0..n {
        out[j] = if inv[j].is_finite() {
            [
                (x[j] * inv[j]) as f32,
                (y[j] * inv[j]) as f32,
                (z[j] * inv[j]) as f32,
            ]
        } else {
            flat(j)
        };
    }
}
