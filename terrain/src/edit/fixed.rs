//! Fixed-point coordinates for edits: Q.8 voxel units in an `i32`.
//!
//! Edits travel over the network and must apply identically everywhere, so
//! they carry no floats: every amount is an integer and every coordinate a
//! multiple of 1/256 voxel.

use serde::{Deserialize, Serialize};

/// Fractional bits of [`Fixed`].
pub const FRAC_BITS: u32 = 8;
/// One voxel in [`Fixed`] units.
pub const ONE: i32 = 1 << FRAC_BITS;
/// Largest allowed |coordinate| of any edit, in voxels. Keeps every
/// intermediate product far from overflow.
pub const COORD_LIMIT_VOXELS: i32 = 1 << 22;

/// A fixed-point length or coordinate in 1/256 voxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Fixed(pub i32);

impl Fixed {
    pub const fn from_voxels(v: i32) -> Self {
        Fixed(v.wrapping_mul(ONE))
    }

    /// Nearest fixed value to `v` (ties away from zero); `None` if not finite or out of range.
    pub fn from_f64(v: f64) -> Option<Self> {
        let scaled = (v * ONE as f64).round();
        (scaled.is_finite() && scaled.abs() <= i32::MAX as f64).then_some(Fixed(scaled as i32))
    }

    pub fn to_f64(self) -> f64 {
        self.0 as f64 / ONE as f64
    }

    /// Largest voxel coordinate not above this value.
    pub const fn floor_voxel(self) -> i32 {
        self.0 >> FRAC_BITS
    }

    /// Smallest voxel coordinate not below this value.
    pub const fn ceil_voxel(self) -> i32 {
        (self.0 >> FRAC_BITS) + ((self.0 & (ONE - 1)) != 0) as i32
    }

    pub fn in_coord_range(self) -> bool {
        self.0.unsigned_abs() < (COORD_LIMIT_VOXELS as u32) << FRAC_BITS
    }
}

/// A fixed-point point in world voxel space.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct FixedVec3 {
    pub x: Fixed,
    pub y: Fixed,
    pub z: Fixed,
}

impl FixedVec3 {
    pub const fn new(x: Fixed, y: Fixed, z: Fixed) -> Self {
        Self { x, y, z }
    }

    pub const fn from_voxels(x: i32, y: i32, z: i32) -> Self {
        Self::new(
            Fixed::from_voxels(x),
            Fixed::from_voxels(y),
            Fixed::from_voxels(z),
        )
    }

    pub fn from_f64(p: [f64; 3]) -> Option<Self> {
        Some(Self::new(
            Fixed::from_f64(p[0])?,
            Fixed::from_f64(p[1])?,
            Fixed::from_f64(p[2])?,
        ))
    }

    pub fn to_f64(self) -> [f64; 3] {
        [self.x.to_f64(), self.y.to_f64(), self.z.to_f64()]
    }

    pub fn in_coord_range(self) -> bool {
        self.x.in_coord_range() && self.y.in_coord_range() && self.z.in_coord_range()
    }
}

/// Integer square root: the largest `r` with `r * r <= n`.
pub fn isqrt(n: u64) -> u64 {
    // The float root (IEEE `sqrt` is correctly rounded everywhere), then
    // corrected to the exact integer root: the conversion of `n` rounds
    // above 2^53, so the estimate may be off by one. About 2.4x faster
    // than Newton's divisions, and exact, so every platform agrees.
    let mut r = (n as f64).sqrt() as u64;
    let square = |r: u64| u128::from(r) * u128::from(r);
    while square(r) > u128::from(n) {
        r -= 1;
    }
    while square(r + 1) <= u128::from(n) {
        r += 1;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isqrt_exact() {
        for n in 0..10_000u64 {
            let r = isqrt(n);
            assert!(r * r <= n && (r + 1) * (r + 1) > n, "n={n} r={r}");
        }
        for n in [u64::MAX, u64::MAX - 1, 1 << 62, (1 << 32) - 1, 1 << 32] {
            let r = isqrt(n) as u128;
            assert!(r * r <= n as u128 && (r + 1) * (r + 1) > n as u128);
        }
        // Squares and their neighbours, where a rounded float root errs.
        for r in (0..1u64 << 32).step_by(9_973).chain([(1 << 32) - 1]) {
            for n in [r * r, (r * r).saturating_sub(1), r * r + 1] {
                assert_eq!(isqrt(n), n.isqrt(), "n={n}");
            }
        }
        let mut n = 1u64;
        for _ in 0..100_000 {
            n = n.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1);
            assert_eq!(isqrt(n), n.isqrt(), "n={n}");
        }
    }

    #[test]
    fn floor_ceil_and_range() {
        assert_eq!(Fixed(-1).floor_voxel(), -1);
        assert_eq!(Fixed(-1).ceil_voxel(), 0);
        assert_eq!(Fixed(256).ceil_voxel(), 1);
        assert_eq!(Fixed(257).ceil_voxel(), 2);
        assert_eq!(Fixed::from_f64(1.5), Some(Fixed(384)));
        assert_eq!(Fixed::from_f64(f64::NAN), None);
        assert_eq!(Fixed::from_f64(1e12), None);
        assert!(Fixed::from_voxels(COORD_LIMIT_VOXELS - 1).in_coord_range());
        assert!(!Fixed::from_voxels(COORD_LIMIT_VOXELS).in_coord_range());
        assert!(!Fixed(i32::MIN).in_coord_range());
    }
}
