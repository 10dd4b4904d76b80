//! Token buckets: a burst capacity that refills at a steady rate.
//!
//! Tokens are counted in thousandths so refill from integer milliseconds is
//! exact: `rate` tokens per second is `rate` milli-tokens per millisecond.

use serde::{Deserialize, Serialize};

/// Milli-tokens per token.
const MILLI: u64 = 1000;

/// Capacity and refill rate of one bucket (both keys required, no others).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BucketConfig {
    /// Largest burst, in tokens.
    pub capacity: u64,
    /// Tokens added per second.
    pub per_second: u64,
}

/// One bucket; starts full.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TokenBucket {
    cfg: BucketConfig,
    milli_tokens: u64,
    last_ms: u64,
}

impl TokenBucket {
    pub fn new(cfg: BucketConfig, now_ms: u64) -> Self {
        Self {
            cfg,
            milli_tokens: cfg.capacity.saturating_mul(MILLI),
            last_ms: now_ms,
        }
    }

    /// Adds the tokens earned since the last refill. Time never runs backwards
    /// here: an earlier `now_ms` earns nothing.
    pub fn refill(&mut self, now_ms: u64) {
        let elapsed = now_ms.saturating_sub(self.last_ms);
        self.last_ms = self.last_ms.max(now_ms);
        let cap = self.cfg.capacity.saturating_mul(MILLI);
        self.milli_tokens = self
            .milli_tokens
            .saturating_add(elapsed.saturating_mul(self.cfg.per_second))
            .min(cap);
    }

    /// Whole tokens available (after the last refill).
    pub fn available(&self) -> u64 {
        self.milli_tokens / MILLI
    }

    /// Whether `n` tokens could be taken now, without taking them.
    pub fn can_take(&self, n: u64) -> bool {
        self.milli_tokens >= n.saturating_mul(MILLI)
    }

    /// Takes `n` tokens; returns false and takes nothing if there are too few.
    pub fn take(&mut self, n: u64) -> bool {
        let need = n.saturating_mul(MILLI);
        if self.milli_tokens >= need {
            self.milli_tokens -= need;
            true
        } else {
            false
        }
    }

    /// Gives back `n` tokens taken for something that did not happen, up
    /// to the capacity.
    pub fn give(&mut self, n: u64) {
        let cap = self.cfg.capacity.saturating_mul(MILLI);
        self.milli_tokens = self
            .milli_tokens
            .saturating_add(n.saturating_mul(MILLI))
            .min(cap);
    }

    pub fn capacity(&self) -> u64 {
        self.cfg.capacity
    }

    /// Milliseconds until `n` tokens are there (after the last refill), at
    /// least 1 if they are not there now; `None` if they never will be (`n`
    /// above the capacity, or no refill).
    pub fn wait_ms(&self, n: u64) -> Option<u64> {
        let need = n.saturating_mul(MILLI);
        if self.milli_tokens >= need {
            return Some(0);
        }
        if n > self.cfg.capacity || self.cfg.per_second == 0 {
            return None;
        }
        Some((need - self.milli_tokens).div_ceil(self.cfg.per_second))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn says_how_long_until_tokens_are_there() {
        let cfg = BucketConfig {
            capacity: 10,
            per_second: 4,
        };
        let mut b = TokenBucket::new(cfg, 0);
        assert_eq!(b.wait_ms(10), Some(0));
        assert!(b.take(10));
        // 4 per second: one token in 250 ms, ten in 2.5 s.
        assert_eq!(b.wait_ms(1), Some(250));
        assert_eq!(b.wait_ms(10), Some(2500));
        b.refill(100);
        assert_eq!(b.wait_ms(1), Some(150));
        b.refill(250);
        assert_eq!(b.wait_ms(1), Some(0));
        assert_eq!(b.wait_ms(11), None, "above the capacity: never");
        let dry = TokenBucket::new(
            BucketConfig {
                capacity: 1,
                per_second: 0,
            },
            0,
        );
        assert_eq!(dry.wait_ms(1), Some(0));
        assert_eq!(dry.wait_ms(2), None);
    }

    #[test]
    fn tokens_given_back_stop_at_the_capacity() {
        let cfg = BucketConfig {
            capacity: 10,
            per_second: 0,
        };
        let mut b = TokenBucket::new(cfg, 0);
        assert!(b.take(7));
        b.give(4);
        assert_eq!(b.available(), 7);
        b.give(u64::MAX);
        assert_eq!(b.available(), 10);
    }

    #[test]
    fn drains_and_refills_with_time() {
        let mut b = TokenBucket::new(
            BucketConfig {
                capacity: 3,
                per_second: 2,
            },
            1_000,
        );
        assert!(b.take(3));
        assert!(!b.take(1));
        b.refill(1_499);
        assert!(!b.can_take(1), "0.998 tokens after 499 ms");
        b.refill(1_500);
        assert!(b.take(1));
        b.refill(100_000);
        assert_eq!(b.available(), 3, "capped at capacity");
        b.refill(50);
        assert_eq!(b.available(), 3, "time going backwards adds nothing");
    }
}
