//! A small seeded random source (SplitMix64): each bot's choices are
//! reproducible from `--seed` and its index.

#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut r = Rng(seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        r.next_u64();
        r
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `lo..=hi`.
    pub fn range(&mut self, lo: i32, hi: i32) -> i32 {
        let span = (hi - lo) as u64 + 1;
        lo + (self.next_u64() % span) as i32
    }

    /// Uniform in `[0, 1)`.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproducible_and_in_range() {
        let (mut a, mut b) = (Rng::new(7, 3), Rng::new(7, 3));
        assert_eq!(a.next_u64(), b.next_u64());
        assert_ne!(Rng::new(7, 4).next_u64(), Rng::new(7, 3).next_u64());
        for _ in 0..1000 {
            let v = a.range(-2, 3);
            assert!((-2..=3).contains(&v));
            assert!((0.0..1.0).contains(&a.unit()));
        }
    }
}
