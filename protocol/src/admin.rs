//! The admin protocol (ALPN `strata-admin/1`): a request set that player
//! sessions can never reach. Player connections (ALPN `strata/1`) only ever
//! decode [`crate::ClientMessage`], which has no admin request.
//!
//! One bidirectional stream, opened by the client, framed exactly like the
//! player control stream (u32 LE length, bincode 2 standard config, 16 KiB
//! cap client to server, 1 MiB server to client). The client sends
//! `AdminRequest::Hello` with an admin token; the server answers `Welcome`,
//! or `Error` and closes. Then each request gets its responses in order;
//! a list answer too long for one frame comes in parts
//! ([`crate::admin_parts`]).

use serde::{Deserialize, Serialize};
use strata_terrain::{ChunkPos, FixedVec3, VoxelPos};

use crate::messages::{ErrorCode, Role};

/// ALPN protocol id of admin connections.
pub const ADMIN_ALPN: &[u8] = b"strata-admin/1";
/// Admin protocol version carried in the admin `Hello`.
pub const ADMIN_PROTOCOL_VERSION: u32 = 1;

/// First admin message. The player `Hello` grew capabilities in player
/// protocol 4; the admin protocol keeps its own, unchanged, layout.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AdminHello {
    pub protocol_version: u32,
    pub token: String,
}

/// A protected zone as the admin protocol carries it (inclusive corners).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ZoneSpec {
    pub name: String,
    pub min: VoxelPos,
    pub max: VoxelPos,
}

/// Admin client to server.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum AdminRequest {
    /// First message: protocol version and an admin-role token.
    Hello(AdminHello),
    /// World and server statistics: answered with `Stats`.
    Stats,
    /// Live sessions: answered with `Players`.
    Players,
    /// Ends every session of `player`: answered with `Kicked`.
    Kick { player: String },
    /// Protected zones: answered with `Zones`.
    Zones,
    /// Adds a zone (effective at once, persisted): answered with `Zones`.
    ZoneAdd(ZoneSpec),
    /// Removes a zone by name: answered with `Zones`.
    ZoneRemove { name: String },
    /// One chunk's current state: answered with `Chunk`.
    InspectChunk { pos: ChunkPos },
    /// A consistent snapshot: `SnapshotBegin`, `SnapshotChunk`s, `SnapshotEnd`.
    /// `max_pending_chunks` bounds the server's copy-on-write pre-images
    /// (0: the server's default); past it the snapshot is aborted.
    Snapshot { max_pending_chunks: u32 },
    /// Bans and token revocations: answered with `Access`.
    Access,
    /// Bans `player` until unix second `until` (`None`: for good), persisted,
    /// and ends the player's live sessions: answered with `Access`.
    Ban { player: String, until: Option<u64> },
    /// Lifts a ban: answered with `Access`.
    Unban { player: String },
    /// Refuses every token of `player` issued until now, persisted, and
    /// ends the player's live sessions: answered with `Access`.
    RevokeTokens { player: String },
}

/// The server's bans and revocations, and what a change did.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AccessSpec {
    /// Player and the unix second the ban ends (`None`: never).
    pub bans: Vec<(String, Option<u64>)>,
    /// Player and the unix second at or before which its tokens are refused.
    pub revoked_before: Vec<(String, u64)>,
    /// Live sessions the request ended.
    pub kicked: u32,
}

/// The server's answer to an admin `Hello`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AdminWelcome {
    pub admin: String,
    pub last_seq: u64,
    pub world_seed: u64,
    pub generator_version: u32,
}

/// What `Stats` reports.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ServerStats {
    pub last_seq: u64,
    pub modified_chunks: u64,
    /// Smallest and largest modified chunk coordinates (the edited extent).
    pub modified_extent: Option<(ChunkPos, ChunkPos)>,
    /// Chunks the server holds in memory.
    pub resident_chunks: u64,
    pub store_bytes: u64,
    pub sessions: u32,
    pub queued_edits: u32,
    pub world_seed: u64,
    pub generator_version: u32,
}

/// One live session.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PlayerInfo {
    pub session: u64,
    pub player: String,
    pub role: Role,
    /// Last validated feet position.
    pub position: Option<FixedVec3>,
}

/// What a snapshot captures besides chunks.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SnapshotInfo {
    /// Every edit up to and including this seq is in the snapshot; none after.
    pub seq: u64,
    pub world_seed: u64,
    pub generator_version: u32,
    pub generator_params: String,
    pub zones: Vec<ZoneSpec>,
    /// Modified chunks at the start (for progress; the snapshot may hold fewer).
    pub modified_chunks: u64,
}

/// Admin server to client.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum AdminResponse {
    Welcome(AdminWelcome),
    /// Ends the connection (sent just before closing, like the player `Error`).
    Error {
        code: ErrorCode,
        message: String,
    },
    /// The request failed and changed nothing; the session goes on.
    Refused {
        message: String,
    },
    Stats(ServerStats),
    Players(Vec<PlayerInfo>),
    Kicked {
        sessions: u32,
    },
    Zones(Vec<ZoneSpec>),
    /// A chunk in the chunk codec's format (`version` 0: as generated).
    Chunk {
        pos: ChunkPos,
        version: u64,
        data: Vec<u8>,
    },
    SnapshotBegin(SnapshotInfo),
    /// One modified chunk as it was at the snapshot's seq (chunk codec bytes).
    SnapshotChunk {
        pos: ChunkPos,
        version: u64,
        data: Vec<u8>,
    },
    SnapshotEnd {
        chunks: u64,
    },
    Access(AccessSpec),
    /// A leading part of a `Players` answer over one frame's worth
    /// ([`crate::admin_parts`]); more follow, the last as `Players`.
    PlayersPart(Vec<PlayerInfo>),
    /// A leading part of an `Access` answer; more follow, the last (with
    /// `kicked`) as `Access`.
    AccessPart(AccessSpec),
}
