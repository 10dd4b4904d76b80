//! Seeded gradient noise built only from integer hashing and `+ - * floor`.
//!
//! Why not a crate: the `noise` crate calls platform `sin`/`cos`/`powf`,
//! whose last bits differ between libms. Everything here uses IEEE-exact
//! f64 operations in a fixed order and never fused multiply-add, so every
//! platform produces the same bits.

/// A 64-bit avalanche mix (the splitmix64 finaliser): every input bit flips
/// about half of the output bits.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Odd constants that spread each coordinate over the whole word before mixing.
const KX: u64 = 0x9e37_79b9_7f4a_7c15;
const KY: u64 = 0xc2b2_ae3d_27d4_eb4f;
const KZ: u64 = 0x1656_67b1_9e37_79f9;

/// Hash of a seed and a 2D integer lattice point.
#[inline]
pub fn hash2(seed: u64, x: i64, z: i64) -> u64 {
    mix64(seed ^ (x as u64).wrapping_mul(KX) ^ (z as u64).wrapping_mul(KZ).rotate_left(32))
}

/// Hash of a seed and a 3D integer lattice point.
#[inline]
pub fn hash3(seed: u64, x: i64, y: i64, z: i64) -> u64 {
    mix64(
        seed ^ (x as u64).wrapping_mul(KX)
            ^ (y as u64).wrapping_mul(KY).rotate_left(21)
            ^ (z as u64).wrapping_mul(KZ).rotate_left(42),
    )
}

/// A derived seed for one noise layer, so layers (hills, caves, ore, each
/// octave) are independent even though they share the world seed.
#[inline]
pub fn sub_seed(seed: u64, layer: u64) -> u64 {
    mix64(seed ^ mix64(layer.wrapping_add(0x5851_f42d_4c95_7f2d)))
}

/// Quintic fade 6t⁵ − 15t⁴ + 10t³: zero first and second derivatives at the
/// lattice points, so the field has no creases there.
#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn lerp(a: f64, b: f64, t: f64) -> f64 {
    a + (b - a) * t
}

/// 1/√2: a compile-time constant, so no platform function computes it.
const FRAC_1_SQRT_2: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// The eight 2D gradient directions (unit length).
const GRAD2: [(f64, f64); 8] = [
    (1.0, 0.0),
    (-1.0, 0.0),
    (0.0, 1.0),
    (0.0, -1.0),
    (FRAC_1_SQRT_2, FRAC_1_SQRT_2),
    (FRAC_1_SQRT_2, -FRAC_1_SQRT_2),
    (-FRAC_1_SQRT_2, FRAC_1_SQRT_2),
    (-FRAC_1_SQRT_2, -FRAC_1_SQRT_2),
];

/// The twelve cube-edge directions of Perlin's improved noise, padded to 16
/// so a 4-bit hash picks one without a modulo bias.
const GRAD3: [(f64, f64, f64); 16] = [
    (1.0, 1.0, 0.0),
    (-1.0, 1.0, 0.0),
    (1.0, -1.0, 0.0),
    (-1.0, -1.0, 0.0),
    (1.0, 0.0, 1.0),
    (-1.0, 0.0, 1.0),
    (1.0, 0.0, -1.0),
    (-1.0, 0.0, -1.0),
    (0.0, 1.0, 1.0),
    (0.0, -1.0, 1.0),
    (0.0, 1.0, -1.0),
    (0.0, -1.0, -1.0),
    (1.0, 1.0, 0.0),
    (0.0, -1.0, 1.0),
    (-1.0, 1.0, 0.0),
    (0.0, -1.0, -1.0),
];

/// `floor` as an integer, exact for |v| < 2^53 (all the generator uses).
///
/// `f64::floor` is a libm call on baseline x86-64 and showed up as 15% of
/// generation time; truncation plus a correction is one instruction pair
/// and gives the same value.
#[inline]
pub fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    if (t as f64) > v {
        t - 1
    } else {
        t
    }
}

/// Splits a noise-space coordinate into its lattice cell and the fraction.
#[inline]
fn cell(v: f64) -> (i64, f64) {
    let f = floor_i64(v);
    (f, v - f as f64)
}

#[inline]
fn g2(seed: u64, x: i64, z: i64, dx: f64, dz: f64) -> f64 {
    let (gx, gz) = GRAD2[(hash2(seed, x, z) >> 61) as usize];
    gx * dx + gz * dz
}

#[inline]
fn g3(seed: u64, x: i64, y: i64, z: i64, dx: f64, dy: f64, dz: f64) -> f64 {
    let (gx, gy, gz) = GRAD3[(hash3(seed, x, y, z) >> 60) as usize];
    gx * dx + gy * dy + gz * dz
}

/// 2D gradient noise at a noise-space point, in `[-1, 1]`.
///
/// The raw Perlin range with unit gradients is ±1/√2; it is scaled by √2 and
/// clamped so the bound is a guarantee the generator's fast paths rely on.
pub fn gradient2(seed: u64, x: f64, z: f64) -> f64 {
    let (ix, fx) = cell(x);
    let (iz, fz) = cell(z);
    let n00 = g2(seed, ix, iz, fx, fz);
    let n10 = g2(seed, ix + 1, iz, fx - 1.0, fz);
    let n01 = g2(seed, ix, iz + 1, fx, fz - 1.0);
    let n11 = g2(seed, ix + 1, iz + 1, fx - 1.0, fz - 1.0);
    let (u, w) = (fade(fx), fade(fz));
    let v = lerp(lerp(n00, n10, u), lerp(n01, n11, u), w);
    (v * (1.0 / FRAC_1_SQRT_2)).clamp(-1.0, 1.0)
}

/// 3D gradient noise at a noise-space point, clamped to `[-1, 1]`.
pub fn gradient3(seed: u64, x: f64, y: f64, z: f64) -> f64 {
    let (ix, fx) = cell(x);
    let (iy, fy) = cell(y);
    let (iz, fz) = cell(z);
    let (u, v, w) = (fade(fx), fade(fy), fade(fz));
    let c = |ox: i64, oy: i64, oz: i64| {
        g3(
            seed,
            ix + ox,
            iy + oy,
            iz + oz,
            fx - ox as f64,
            fy - oy as f64,
            fz - oz as f64,
        )
    };
    let x00 = lerp(c(0, 0, 0), c(1, 0, 0), u);
    let x10 = lerp(c(0, 1, 0), c(1, 1, 0), u);
    let x01 = lerp(c(0, 0, 1), c(1, 0, 1), u);
    let x11 = lerp(c(0, 1, 1), c(1, 1, 1), u);
    lerp(lerp(x00, x10, v), lerp(x01, x11, v), w).clamp(-1.0, 1.0)
}

/// Per-octave seeds for [`fbm2`]/[`fbm3`], derived once per generator so the
/// hot loops do not re-hash them.
pub fn octave_seeds(seed: u64, layer: u64, octaves: u32) -> Vec<u64> {
    let base = sub_seed(seed, layer);
    (0..octaves as u64).map(|o| sub_seed(base, o)).collect()
}

/// Fractal Brownian motion: one layer of [`gradient2`] per seed, each at
/// twice the frequency and half the amplitude of the last (both exact in
/// f64), normalised by the amplitude sum so the result stays in `[-1, 1]`.
pub fn fbm2(seeds: &[u64], x: f64, z: f64) -> f64 {
    octaves(seeds, |s, freq| gradient2(s, x * freq, z * freq))
}

/// The 3D counterpart of [`fbm2`], also in `[-1, 1]`.
pub fn fbm3(seeds: &[u64], x: f64, y: f64, z: f64) -> f64 {
    octaves(seeds, |s, freq| gradient3(s, x * freq, y * freq, z * freq))
}

/// Sums one noise octave per seed, halving the amplitude and doubling the
/// frequency each time, normalised to the noise's own range.
fn octaves(seeds: &[u64], noise: impl Fn(u64, f64) -> f64) -> f64 {
    let (mut sum, mut amp, mut freq, mut norm) = (0.0, 1.0, 1.0, 0.0);
    for &s in seeds {
        sum += amp * noise(s, freq);
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    if norm == 0.0 {
        0.0
    } else {
        sum / norm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_at_lattice_points_and_bounded() {
        // Gradient noise vanishes on the integer lattice.
        assert_eq!(gradient2(7, 3.0, -4.0), 0.0);
        assert_eq!(gradient3(7, 3.0, -4.0, 11.0), 0.0);
        let mut seen_large = false;
        for i in 0..2000 {
            let t = i as f64 * 0.173;
            let a = gradient2(99, t, t * 0.61 - 40.0);
            let b = gradient3(99, t * 0.37, -t, t * 0.71 + 3.0);
            assert!((-1.0..=1.0).contains(&a) && (-1.0..=1.0).contains(&b));
            seen_large |= a.abs() > 0.4 && b.abs() > 0.3;
        }
        assert!(seen_large, "noise should use a good part of its range");
    }

    #[test]
    fn seeds_and_octaves_matter() {
        let p = (12.3, 45.6);
        let (a, b) = (octave_seeds(1, 0, 4), octave_seeds(2, 0, 4));
        assert_ne!(fbm2(&a, p.0, p.1), fbm2(&b, p.0, p.1));
        assert_ne!(fbm2(&a[..1], p.0, p.1), fbm2(&a, p.0, p.1));
        assert_eq!(fbm2(&[], p.0, p.1), 0.0);
        assert_ne!(octave_seeds(1, 0, 2), octave_seeds(1, 1, 2));
        assert_ne!(sub_seed(5, 0), sub_seed(5, 1));
        assert_ne!(hash3(0, 1, 0, 0), hash3(0, 0, 1, 0));
        assert_ne!(hash2(0, 1, 0), hash2(0, 0, 1));
    }

    #[test]
    fn floor_i64_matches_floor() {
        for v in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.999,
            -2.999,
            1e15 + 0.5,
            -1e15 - 0.5,
            -3.0,
        ] {
            assert_eq!(floor_i64(v), v.floor() as i64, "{v}");
        }
    }

    #[test]
    fn continuous_across_cells() {
        // Values just either side of a lattice line are nearly equal.
        let seeds = octave_seeds(3, 0, 3);
        let a = fbm3(&seeds, 4.999_999, 1.5, 2.25);
        let b = fbm3(&seeds, 5.000_001, 1.5, 2.25);
        assert!((a - b).abs() < 1e-4);
    }
}
