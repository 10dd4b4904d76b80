//! Tunables of the store (`[store]` in the server config): which backend,
//! sled's settings, and `[store.postgres]`.

use serde::{Deserialize, Serialize};

use super::pg::PgConfig;

/// Where the world lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StoreBackend {
    /// Embedded sled in the data dir (`world.sled`): the single-node default.
    #[default]
    Sled,
    /// A PostgreSQL database (`[store.postgres]`), the cluster's store.
    Postgres,
}

/// Default page cache: enough for the hot chunks of a busy server while
/// staying small next to the in-memory world.
pub const DEFAULT_CACHE_CAPACITY_BYTES: u64 = 64 * 1024 * 1024;
/// Smallest allowed page cache.
pub const MIN_CACHE_CAPACITY_BYTES: u64 = 1024 * 1024;
/// sled's background flush period. Every write of the store flushes and
/// fsyncs explicitly before returning, so this thread only cleans segments
/// and is not the durability boundary. Each pass may rewrite pages for half a period, and a group
/// commit waits for whatever it wrote: a short period keeps that work in
/// small slices. sled's own default, 500 ms, stalled commits for up to
/// 140 ms at 500 edits/s (BENCHMARKS.md).
pub const DEFAULT_FLUSH_EVERY_MS: u64 = 20;
/// Longest allowed background flush period.
pub const MAX_FLUSH_EVERY_MS: u64 = 60_000;
/// sled's log segment size for new stores. sled writes any page larger
/// than a quarter segment to a file of its own, created inside the commit
/// that wrote it (and fsynced by `disk_sync`); a leaf of 16 chunk records (about 8 KiB each
/// on terrain) passes the 128 KiB of sled's own 512 KiB default. 2 MiB
/// keeps such leaves inline; 8 MiB made commits slower (BENCHMARKS.md).
pub const DEFAULT_SEGMENT_SIZE_BYTES: usize = 2 * 1024 * 1024;
/// Smallest and largest allowed segment size (a power of two, as sled wants).
pub const MIN_SEGMENT_SIZE_BYTES: usize = 512 * 1024;
pub const MAX_SEGMENT_SIZE_BYTES: usize = 16 * 1024 * 1024;

/// How often the background checkpoint folds committed deltas into chunk
/// records. Commits store only the log and deltas, so this bounds how much
/// a read (or a restart) replays, not what is durable. Each fold re-encodes
/// whole chunk records (zstd), so a longer period folds more deltas per
/// record: 5 s instead of 1 s cut the checkpointer's CPU by two thirds at
/// 500 bots (BENCHMARKS.md).
pub const DEFAULT_CHECKPOINT_MS: u64 = 5000;
/// Longest allowed checkpoint period.
pub const MAX_CHECKPOINT_MS: u64 = 3_600_000;
/// Chunks one checkpoint pass folds at most (a pass then fsyncs once).
pub const DEFAULT_CHECKPOINT_CHUNKS: usize = 4096;
/// Largest allowed `checkpoint_chunks` (and `checkpoint_slice_chunks`).
pub const MAX_CHECKPOINT_CHUNKS: usize = 1 << 20;
/// Chunks a pass folds between two flushes, pausing after each slice
/// (`checkpointer.rs`): a commit waits behind at most one slice's writes.
/// Folding a pass's 260 chunks at once, at 300 bots, stalled commits that
/// ran beside it or just after it for up to 430 ms; slices of 8 gave a
/// lower ack p99 than 16 or 32 for a little more checkpoint CPU
/// (BENCHMARKS.md).
pub const DEFAULT_CHECKPOINT_SLICE_CHUNKS: usize = 8;

/// How long the edit log keeps an entry (`[store] log_retention`): its
/// history, not its recovery, so it need not be kept for good. At 1,000
/// edits a second the log grows by about 15 GiB a day.
pub const DEFAULT_LOG_RETENTION: std::time::Duration =
    std::time::Duration::from_secs(30 * 24 * 3600);

/// The `[store]` section of the server config.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StoreConfig {
    /// `"sled"` (default) or `"postgres"`.
    pub backend: StoreBackend,
    /// sled's page cache in bytes.
    pub cache_capacity_bytes: u64,
    /// Period of sled's background thread in ms; 0 turns it off (and with
    /// it segment cleaning: the file then only grows).
    pub flush_every_ms: u64,
    /// sled's log segment size for a new store; an existing store keeps the
    /// size it was created with.
    pub segment_size_bytes: usize,
    /// See [`DEFAULT_CHECKPOINT_MS`]; 0 folds only at shutdown.
    pub checkpoint_ms: u64,
    /// See [`DEFAULT_CHECKPOINT_CHUNKS`].
    pub checkpoint_chunks: usize,
    /// See [`DEFAULT_CHECKPOINT_SLICE_CHUNKS`].
    pub checkpoint_slice_chunks: usize,
    /// See [`DEFAULT_LOG_RETENTION`] ("30d"; "36500d" keeps it for good).
    pub log_retention: crate::auth::HumanDuration,
    /// The PostgreSQL store's settings, read when `backend = "postgres"`.
    pub postgres: PgConfig,
}

impl StoreConfig {
    /// The checkpoint thread's pace.
    pub fn checkpoint_pace(&self) -> super::CheckpointPace {
        super::CheckpointPace {
            every: std::time::Duration::from_millis(self.checkpoint_ms),
            max_chunks: self.checkpoint_chunks,
            slice_chunks: self.checkpoint_slice_chunks,
            log_retention: self.log_retention.0,
        }
    }

    /// sled's setting: `None` is no background thread.
    pub fn flush_period(&self) -> Option<u64> {
        (self.flush_every_ms > 0).then_some(self.flush_every_ms)
    }
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self {
            backend: StoreBackend::Sled,
            cache_capacity_bytes: DEFAULT_CACHE_CAPACITY_BYTES,
            flush_every_ms: DEFAULT_FLUSH_EVERY_MS,
            segment_size_bytes: DEFAULT_SEGMENT_SIZE_BYTES,
            checkpoint_ms: DEFAULT_CHECKPOINT_MS,
            checkpoint_chunks: DEFAULT_CHECKPOINT_CHUNKS,
            checkpoint_slice_chunks: DEFAULT_CHECKPOINT_SLICE_CHUNKS,
            log_retention: crate::auth::HumanDuration(DEFAULT_LOG_RETENTION),
            postgres: PgConfig::default(),
        }
    }
}
