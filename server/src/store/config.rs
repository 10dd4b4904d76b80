//! Tunables of the sled-backed store (`[store]` in the server config).

use serde::{Deserialize, Serialize};

/// Default page cache: enough for the hot chunks of a busy server while
/// staying small next to the in-memory world.
pub const DEFAULT_CACHE_CAPACITY_BYTES: u64 = 64 * 1024 * 1024;
/// Smallest allowed page cache.
pub const MIN_CACHE_CAPACITY_BYTES: u64 = 1024 * 1024;
/// sled's background flush period. Every write of the store flushes
/// explicitly before returning, so this thread only cleans segments (and
/// syncs). Each pass may rewrite pages for half a period, and a group
/// commit waits for whatever it wrote: a short period keeps that work in
/// small slices. sled's own default, 500 ms, stalled commits for up to
/// 140 ms at 500 edits/s (BENCHMARKS.md).
pub const DEFAULT_FLUSH_EVERY_MS: u64 = 20;
/// Longest allowed background flush period.
pub const MAX_FLUSH_EVERY_MS: u64 = 60_000;

/// The `[store]` section of the server config.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StoreConfig {
    /// sled's page cache in bytes.
    pub cache_capacity_bytes: u64,
    /// Period of sled's background thread in ms; 0 turns it off (and with
    /// it segment cleaning: the file then only grows).
    pub flush_every_ms: u64,
}

impl StoreConfig {
    /// sled's setting: `None` is no background thread.
    pub fn flush_period(&self) -> Option<u64> {
        (self.flush_every_ms > 0).then_some(self.flush_every_ms)
    }
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self {
            cache_capacity_bytes: DEFAULT_CACHE_CAPACITY_BYTES,
            flush_every_ms: DEFAULT_FLUSH_EVERY_MS,
        }
    }
}
