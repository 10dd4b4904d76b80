//! What one tick produces: applied edits with their deltas, and the batch
//! the shell hands to the store before acknowledging anything.

use strata_protocol::RejectReason;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::{Chunk, ChunkPos, Edit};

/// One chunk changed by one edit.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkUpdate {
    pub pos: ChunkPos,
    pub from_version: u64,
    pub to_version: u64,
    /// Takes the chunk from `from_version` to `to_version`.
    pub delta: ChunkDelta,
    /// The chunk at `to_version`.
    pub new_chunk: Chunk,
    /// Hash of the LOD-0 collision mesh right after this edit.
    pub mesh_hash: u64,
}

/// An edit that was applied and got a global sequence number.
#[derive(Debug, Clone, PartialEq)]
pub struct AppliedEdit {
    pub seq: u64,
    pub session_id: u64,
    pub client_edit_id: u64,
    pub player: String,
    pub edit: Edit,
    /// Chunks whose voxels changed, in (z, y, x) order; may be empty.
    pub changes: Vec<ChunkUpdate>,
}

/// A queued edit that failed when applied (validation should prevent this).
#[derive(Debug, Clone, PartialEq)]
pub struct RejectedEdit {
    pub session_id: u64,
    pub client_edit_id: u64,
    pub reason: RejectReason,
}

/// One edit-log entry for the store.
#[derive(Debug, Clone, PartialEq)]
pub struct CommitEntry {
    pub seq: u64,
    pub player: String,
    /// Milliseconds (the tick's `now_ms`).
    pub time_ms: u64,
    pub edit: Edit,
    /// Changed chunks and the versions this edit gave them.
    pub changes: Vec<(ChunkPos, u64)>,
}

/// A chunk's final state after the tick.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredChunk {
    pub pos: ChunkPos,
    pub version: u64,
    pub chunk: Chunk,
}

/// Everything one tick made durable-worthy: written in one store transaction.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CommitBatch {
    /// In sequence order.
    pub entries: Vec<CommitEntry>,
    /// Final state of every chunk changed this tick, in position order.
    pub chunks: Vec<StoredChunk>,
    /// Sequence number of the last entry (the previous last seq if none).
    pub last_seq: u64,
}

impl CommitBatch {
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// The result of one [`super::Sequencer::tick`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TickOutput {
    /// In sequence order.
    pub applied: Vec<AppliedEdit>,
    pub rejected: Vec<RejectedEdit>,
    pub batch: CommitBatch,
}
