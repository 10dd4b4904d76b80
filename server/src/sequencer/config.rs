//! The `[sequencer]` config section.

use serde::{Deserialize, Serialize};

use super::regions::DEFAULT_REGION_CHUNKS;
use crate::collision::DEFAULT_COLLISION_CACHE_CAPACITY;

/// Accepted edits waiting for the next tick; a full queue answers `Busy`.
pub const DEFAULT_QUEUE_CAPACITY: usize = 1024;
/// Edits applied per tick at most; the rest wait for the next tick, which
/// bounds the size of one store batch.
pub const DEFAULT_MAX_EDITS_PER_TICK: usize = 256;

/// Limits of the sequencer (`[sequencer]` in the server config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SequencerConfig {
    /// See [`DEFAULT_QUEUE_CAPACITY`].
    pub queue_capacity: usize,
    /// See [`DEFAULT_MAX_EDITS_PER_TICK`].
    pub max_edits_per_tick: usize,
    /// Collision meshes kept (see [`DEFAULT_COLLISION_CACHE_CAPACITY`]).
    pub collision_cache_capacity: usize,
    /// Side of a region in chunks ([`DEFAULT_REGION_CHUNKS`]): the unit of
    /// ordering; edits of regions no edit joins apply in parallel.
    pub region_chunks: u32,
}

impl Default for SequencerConfig {
    fn default() -> Self {
        Self {
            queue_capacity: DEFAULT_QUEUE_CAPACITY,
            max_edits_per_tick: DEFAULT_MAX_EDITS_PER_TICK,
            collision_cache_capacity: DEFAULT_COLLISION_CACHE_CAPACITY,
            region_chunks: DEFAULT_REGION_CHUNKS,
        }
    }
}
