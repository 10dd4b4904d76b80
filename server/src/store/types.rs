//! Records the store keeps: world metadata, chunks, the edit log and batches.

use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::{Chunk, ChunkPos, Edit};

/// Layout version of the store written by this build; bumped on any change
/// to [`crate::store::keys`] or to a record's encoding. 2 added the `deltas`
/// tree; 3 lets a delta span several versions (a tick stores one per
/// chunk) and writes the sled log as one page a commit (`log_pages.rs`);
/// 4 lets a chunk record (sled) or row (PostgreSQL) say "generated"
/// (version 0), with the deltas of a chunk's first changes after it
/// (`CommitBatch::generated`).
/// Older stores are upgraded when opened: their records stay valid.
pub const STORE_FORMAT_VERSION: u32 = 4;

/// What a world was generated from, plus how far its edit log goes.
///
/// A world must never be reopened with a different seed, generator version
/// or generator parameters: unmodified chunks are regenerated on load, so
/// the world would silently change under the stored edits.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorldMeta {
    /// [`STORE_FORMAT_VERSION`] of the build that created the store.
    pub format_version: u32,
    pub seed: u64,
    pub generator_version: u32,
    /// The generator parameters as TOML text, compared byte for byte.
    pub generator_params: String,
    /// Seq of the last committed edit; 0 before the first one.
    pub last_seq: u64,
}

impl WorldMeta {
    /// Metadata for a new world at the current store format, no edits yet.
    pub fn new(seed: u64, generator_version: u32, generator_params: impl Into<String>) -> Self {
        Self {
            format_version: STORE_FORMAT_VERSION,
            seed,
            generator_version,
            generator_params: generator_params.into(),
            last_seq: 0,
        }
    }
}

/// A modified chunk and its version (the count of edits that changed it).
/// A chunk the store does not hold was never modified: it is the
/// generator's output at version 0.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoredChunk {
    pub chunk: Chunk,
    pub version: u64,
}

/// A stored chunk without decoding: what a snapshot streams.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawChunk {
    pub pos: ChunkPos,
    pub version: u64,
    /// [`strata_terrain::chunk_codec::encode_chunk`] bytes.
    pub encoded: Vec<u8>,
}

/// One accepted edit, as the sequencer ordered it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LogEntry {
    pub seq: u64,
    pub player: String,
    /// Server wall-clock time of acceptance, ms since the Unix epoch.
    pub time_ms: u64,
    pub edit: Edit,
    /// Each chunk the edit changed and the version it moved that chunk to.
    pub changes: Vec<(ChunkPos, u64)>,
}

/// A player's last validated position, as stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StoredPosition {
    pub feet: strata_terrain::FixedVec3,
    /// When (ms since the Unix epoch) the server last knew the player
    /// there: a ticket issued before it cannot move the player. 0 when not
    /// known (a store written before this was kept).
    pub known_ms: u64,
}

/// Everything one sequencer tick commits, written atomically and made
/// durable together (group commit).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CommitBatch {
    /// Consecutive seqs, the first one just after the store's `last_seq`.
    pub entries: Vec<LogEntry>,
    /// The final state, at the highest version the entries gave it, of
    /// each changed chunk written whole: at least every chunk the store
    /// does not hold yet (version 0 before the batch).
    pub chunks: Vec<(ChunkPos, u64, Arc<Chunk>)>,
    /// For some of `chunks` (those at version 0 before the batch): the
    /// change from the generated state to the version written, one delta
    /// each. A store that can regenerate chunks (a generator attached,
    /// [`crate::store::ChunkStore::attach_generator`]) writes these and a
    /// "generated" record instead of the whole states, which its checkpoint
    /// writes later; any other store writes the whole states.
    pub generated: Vec<ChunkDelta>,
    /// For every other changed chunk, one delta per change, in version
    /// order: the tick's durable record is the log plus these, and a
    /// checkpoint later folds them into the chunk's record.
    pub deltas: Vec<ChunkDelta>,
    /// The seq of the last entry.
    pub last_seq: u64,
    /// A cluster node's engine: the lease epoch under which it last loaded
    /// each region the batch writes or its edits read (`take_fresh_regions`).
    /// The commit is fenced by all of these, so a batch built before the
    /// node took a region back, or on one another node took since, is
    /// refused. `None`: by the epochs the store holds now (one
    /// node alone, tools, tests).
    pub epochs: Option<std::collections::BTreeMap<crate::sequencer::regions::RegionId, u64>>,
}

impl CommitBatch {
    /// True when the tick accepted no edit (nothing to write).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// What one commit cost, for metrics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CommitStats {
    /// Encoded bytes written: the log records, deltas and chunk values.
    pub bytes_written: u64,
    /// Time to encode the batch (zstd of the chunks, bincode of the log).
    pub encode: Duration,
    /// Time to apply the transaction in memory.
    pub apply: Duration,
    /// Time sled's `flush` took (its writes and `sync_file_range`).
    pub flush: Duration,
    /// Time the fsyncs after it took (see `disk_sync`): the commit is
    /// durable only once they return.
    pub fsync: Duration,
}

/// What one checkpoint pass did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CheckpointStats {
    /// Chunks whose deltas were folded into their records.
    pub chunks: u64,
    /// Delta records removed.
    pub deltas: u64,
    /// Chunk record bytes written.
    pub bytes_written: u64,
    /// Chunks left unfolded because their records do not read
    /// ([`crate::store::StoreError::is_chunk_local`], each logged): their
    /// deltas stay, and the other chunks are folded all the same.
    pub skipped: u64,
}

/// Whether this node may write the regions an edit touches
/// ([`crate::store::ChunkStore::acquire_regions`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RegionAccess {
    /// It holds every one of them (now, or after claiming them).
    Granted,
    /// Another node holds `region` (`owner` empty: the row names none),
    /// reachable at `addr` (may be empty).
    Elsewhere {
        region: crate::sequencer::regions::RegionId,
        owner: String,
        addr: String,
    },
    /// Claiming them would pass `[cluster] max_held_regions` (`max`), and
    /// no other node holds any of them.
    AtCapacity { held: usize, max: usize },
    /// A region row is locked by another node's commit: try again shortly.
    Contended,
}

/// A free region's mark: the epoch of its last claim and the last seq
/// committed into it ([`crate::store::ChunkStore::free_region_marks`]).
pub type RegionMark = (u64, u64);

/// Who writes a region, as this node sees it
/// ([`crate::store::ChunkStore::region_holders`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RegionHolder {
    /// This node.
    Here,
    /// No live lease: the first node to write it claims it.
    Free,
    /// Node `owner`, reachable at `addr` (may be empty).
    Node { owner: String, addr: String },
}
