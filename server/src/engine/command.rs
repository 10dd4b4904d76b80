//! Messages from connection tasks to the engine thread.

use std::sync::Arc;

use strata_protocol::{EditRequest, ErrorCode, Role, Start};
use strata_terrain::ChunkPos;
use tokio::sync::oneshot;

use crate::net::writer::FrameSender;

/// What a session learns when it joins.
#[derive(Debug, Clone, Copy)]
pub struct JoinReply {
    pub last_seq: u64,
    /// Where the player's first position report must be.
    pub start: Start,
}

/// Why the engine ended a session; the session closes its connection with it.
pub type Kick = (ErrorCode, String);

/// Why a player's older session ends for its newer login (`Kicked`), by
/// the engine at the Join or by the session when its slot was taken.
pub const REPLACED: &str = "replaced by a newer login";

/// A request to the engine. Sessions `try_send` these; a full engine
/// queue means the server is overloaded.
#[derive(Debug)]
pub enum Command {
    Join {
        session: u64,
        player: String,
        role: Role,
        control: FrameSender,
        updates: FrameSender,
        reply: oneshot::Sender<JoinReply>,
        /// Fired (or dropped) when the engine ends the session.
        kick: oneshot::Sender<Kick>,
        /// The session's pending position (see [`super::LatestPosition`]).
        position: Arc<super::LatestPosition>,
        /// `Hello::capabilities`, unknown bits already dropped.
        capabilities: u32,
        /// Where the store last has the player, read by the session (off
        /// the engine thread) on a cluster node: another node may have had
        /// it since.
        stored: Option<Box<crate::store::StoredPosition>>,
    },
    Leave {
        session: u64,
    },
    Edit {
        session: u64,
        request: EditRequest,
        /// When the session decoded it.
        received: std::time::Instant,
    },
    /// The session's [`super::LatestPosition`] holds an update.
    Position {
        session: u64,
    },
    Subscribe {
        session: u64,
        center: ChunkPos,
        radius: u8,
    },
    Resync {
        session: u64,
        pos: ChunkPos,
    },
    FullSnapshot {
        session: u64,
        pos: ChunkPos,
    },
    /// The client dropped these chunks (at most `MAX_FORGET_CHUNKS`).
    Forget {
        session: u64,
        chunks: Vec<ChunkPos>,
    },
    /// A verified ticket (`ClientMessage::Arrive`): the session continues
    /// from `feet`, timed from `issued_ms`, unless it has a position.
    Arrive {
        session: u64,
        feet: strata_terrain::edit::FixedVec3,
        issued_ms: u64,
    },
    /// From an admin session only.
    Admin(super::admin::AdminCommand),
    /// Finish the batch in flight, flush, and stop.
    Stop,
    /// Look at the control queue (see `inbox.rs`); carries nothing.
    Wake,
}
