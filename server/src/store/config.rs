//! Tunables of the sled-backed store.

use serde::{Deserialize, Serialize};

/// Default page cache: enough for the hot chunks of a busy server while
/// staying small next to the in-memory world.
pub const DEFAULT_CACHE_CAPACITY_BYTES: u64 = 64 * 1024 * 1024;
/// sled's background flush period. Every write of the store flushes
/// explicitly before returning, so this is only sled's own housekeeping.
pub const DEFAULT_FLUSH_EVERY_MS: u64 = 500;

/// The `[store]` section of the server config.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct StoreConfig {
    pub cache_capacity_bytes: u64,
    /// `None` turns sled's background flusher off.
    pub flush_every_ms: Option<u64>,
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self {
            cache_capacity_bytes: DEFAULT_CACHE_CAPACITY_BYTES,
            flush_every_ms: Some(DEFAULT_FLUSH_EVERY_MS),
        }
    }
}
