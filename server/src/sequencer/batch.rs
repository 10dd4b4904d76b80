//! What one tick produces: applied edits with their deltas, and the batch
//! the shell hands to the store before acknowledging anything.

use strata_protocol::RejectReason;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::{ChunkPos, Edit};

use crate::store::CommitBatch;

/// One chunk changed by one edit.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkUpdate {
    pub pos: ChunkPos,
    pub from_version: u64,
    pub to_version: u64,
    /// Takes the chunk from `from_version` to `to_version`.
    pub delta: ChunkDelta,
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
    /// When the engine took the request.
    pub queued_at: std::time::Instant,
}

/// A queued edit that failed when applied (validation should prevent this).
#[derive(Debug, Clone, PartialEq)]
pub struct RejectedEdit {
    pub session_id: u64,
    pub client_edit_id: u64,
    pub reason: RejectReason,
}

/// The result of one [`super::Sequencer::tick`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TickOutput {
    /// In sequence order.
    pub applied: Vec<AppliedEdit>,
    pub rejected: Vec<RejectedEdit>,
    /// What the store must make durable before anything is acknowledged.
    pub batch: CommitBatch,
    /// Lanes the tick's edits were applied in (see `regions.rs`).
    pub lanes: usize,
    /// Where the apply's time went, for the slow-tick warning.
    pub split: ApplySplit,
}

/// The parts of [`super::Sequencer::tick_apply`], timed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ApplySplit {
    /// Waiting for a worker to take the apply (the engine's `pool.install`).
    pub wait: std::time::Duration,
    /// Validating the edits, grouping them and moving their chunks out.
    pub prepare: std::time::Duration,
    /// The lanes, in parallel.
    pub lanes: std::time::Duration,
    /// Numbering, putting chunks back and copying the neighbourhoods of
    /// the changed chunks and the rewarms.
    pub merge: std::time::Duration,
}
