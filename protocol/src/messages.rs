//! Every message of the protocol. Field order is wire order (bincode).
//!
//! * Control stream (bidirectional, opened by the client): the client sends
//!   [`ClientMessage`], the server answers with [`ServerMessage`].
//! * Updates stream (unidirectional, opened by the server after `Welcome`):
//!   [`WorldUpdate`], in the order the server's sequencer produced them.
//! * Datagrams (client to server): [`PositionUpdate`], unframed.

use serde::{Deserialize, Serialize};
use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::{Edit, EditKind, Fixed, FixedVec3};
use strata_terrain::{ChunkPos, VoxelPos};

/// A player's permission level, carried in the signed token.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Role {
    Player,
    Admin,
}

impl Role {
    pub const fn name(self) -> &'static str {
        match self {
            Role::Player => "player",
            Role::Admin => "admin",
        }
    }

    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "player" => Some(Role::Player),
            "admin" => Some(Role::Admin),
            _ => None,
        }
    }
}

/// First message on the control stream.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    pub protocol_version: u32,
    /// An auth token minted by `strata-admin token issue`.
    pub token: String,
    /// Bit flags (`crate::capabilities`); unknown bits are ignored.
    pub capabilities: u32,
}

/// The server's answer to a valid `Hello`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Welcome {
    pub session: u64,
    pub player: String,
    pub role: Role,
    pub world_seed: u64,
    pub generator_version: u32,
    /// Generator parameters as TOML, so a client can regenerate version-0
    /// chunks exactly.
    pub generator_params: String,
    /// Milliseconds since the Unix epoch.
    pub server_time: u64,
    /// View radius in chunks (Chebyshev distance).
    pub view_radius: u8,
    /// Sequence number of the last durable edit.
    pub last_seq: u64,
    /// Where the player's first position report must be.
    pub start: Start,
}

/// Where a new session starts (`Welcome::start`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Start {
    /// The server remembers where the player last stood: the first report
    /// must be a legal move from `feet`, timed from the `Welcome`.
    Resume { feet: FixedVec3 },
    /// A player the server does not remember: the first report's column must
    /// lie within `radius` voxels (on x and on z) of column (`x`, `z`), at any
    /// height not inside solid terrain.
    Spawn { x: i32, z: i32, radius: u32 },
}

impl Start {
    /// Whether a first report at `feet` fits this start, by its column alone
    /// (a resumed player is checked by speed instead).
    pub fn admits_column(&self, feet: FixedVec3) -> bool {
        match *self {
            Start::Resume { .. } => true,
            Start::Spawn { x, z, radius } => {
                let r = i64::from(radius);
                let dx = i64::from(feet.x.floor_voxel()) - i64::from(x);
                let dz = i64::from(feet.z.floor_voxel()) - i64::from(z);
                dx.abs() <= r && dz.abs() <= r
            }
        }
    }
}

/// An edit the client wants applied.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct EditRequest {
    /// Chosen by the client; echoed in the verdict.
    pub client_edit_id: u64,
    pub edit: Edit,
}

/// Client-to-server control messages.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ClientMessage {
    Hello(Hello),
    /// Explicit interest: chunks within `radius` (Chebyshev) of `center`.
    /// Without it, interest follows the last accepted position.
    Subscribe {
        center: ChunkPos,
        radius: u8,
    },
    Edit(EditRequest),
    /// The client saw a version gap or a hash mismatch: resend the chunk.
    ResyncRequest {
        pos: ChunkPos,
    },
    /// For clients that cannot run the generator: always send full data,
    /// even for version-0 chunks.
    FullSnapshotRequest {
        pos: ChunkPos,
    },
    Ping {
        nonce: u64,
    },
    /// The client dropped these chunks: the server stops sending their
    /// updates until a `ResyncRequest`/`FullSnapshotRequest`, or until they
    /// leave the view and come back. At most
    /// [`crate::limits::MAX_FORGET_CHUNKS`]; chunks not in view are ignored.
    Forget {
        #[serde(deserialize_with = "crate::cautious::vec")]
        chunks: Vec<ChunkPos>,
    },
    /// Sent right after `Welcome` to a node named by another node's
    /// `RegionOwners`: the player continues from the ticket's position
    /// instead of `Welcome::start`. Answered `Arrived`, or
    /// `RequestRefused(BadTicket)` and nothing changes.
    Arrive(Ticket),
}

/// A node's signed statement of where a player stood (`RegionOwners`),
/// accepted by the other nodes of its cluster (they share the auth
/// secret). Valid for [`crate::limits::TICKET_TTL_MS`] after `issued_ms`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ticket {
    pub player: String,
    pub feet: FixedVec3,
    /// Milliseconds since the Unix epoch.
    pub issued_ms: u64,
    /// HMAC-SHA256 of the fields above (PROTOCOL.md, "Tickets").
    pub mac: [u8; 32],
}

/// Who writes one region, as one node sees it (`RegionOwners`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum RegionHolder {
    /// The node that sent the message.
    Here,
    /// No live lease: the first node to write it will claim it.
    Free,
    /// Another node, reachable at `addr` (empty when it advertised none).
    Node { node: String, addr: String },
}

/// One region of a `RegionOwners` message.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RegionOwner {
    pub region_x: i32,
    pub region_z: i32,
    pub holder: RegionHolder,
}

/// Why an edit was refused. Nothing changed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum RejectReason {
    /// The role may not use this edit kind.
    NotPermitted {
        kind: EditKind,
    },
    RadiusTooLarge {
        max: Fixed,
    },
    PowerTooLarge {
        max: u16,
    },
    /// The target is farther than `max` from the last validated position.
    OutOfReach {
        distance: Fixed,
        max: Fixed,
    },
    /// A ray from the eye to the target hits terrain first.
    NoLineOfSight,
    /// Too many edits per second.
    RateLimited,
    /// Too many voxels changed per second.
    VolumeRateLimited,
    /// Outside the world's vertical bounds.
    OutOfBounds,
    /// Inside a protected zone.
    ProtectedZone {
        zone: String,
    },
    /// No validated position yet: send a position first.
    NoPosition,
    /// The terrain core refused it (bad numbers, unknown material...).
    Invalid {
        message: String,
    },
    /// The sequencer queue is full; try again.
    Busy,
    /// The edit touches a region this server does not hold: node `owner`
    /// does (empty: no live node, retry later), reachable at `addr` (may
    /// be empty). Regions are `region_chunks` chunks on a side.
    RegionElsewhere {
        region_x: i32,
        region_z: i32,
        owner: String,
        addr: String,
    },
    /// A cluster node already holds `max_regions` regions (`[cluster]
    /// max_held_regions`) and no node holds the edit's region: another
    /// node may take it, so send the edit there, or here again later.
    /// Nothing was charged.
    NodeFull {
        max_regions: u32,
    },
}

/// Errors that end the connection (sent just before closing it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ErrorCode {
    UnsupportedVersion,
    BadToken,
    ExpiredToken,
    NotAuthenticated,
    Malformed,
    FrameTooLarge,
    Forbidden,
    Kicked,
    ShuttingDown,
    TooManyConnections,
    Internal,
}

impl ErrorCode {
    pub const ALL: [ErrorCode; 11] = [
        ErrorCode::UnsupportedVersion,
        ErrorCode::BadToken,
        ErrorCode::ExpiredToken,
        ErrorCode::NotAuthenticated,
        ErrorCode::Malformed,
        ErrorCode::FrameTooLarge,
        ErrorCode::Forbidden,
        ErrorCode::Kicked,
        ErrorCode::ShuttingDown,
        ErrorCode::TooManyConnections,
        ErrorCode::Internal,
    ];

    /// The QUIC application close code the server uses for this error
    /// (`1 + index`; 0 is a normal close).
    pub const fn close_code(self) -> u32 {
        1 + self as u32
    }

    /// The error behind a close code, if it is one of ours.
    pub fn from_close_code(code: u64) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|c| c.close_code() as u64 == code)
    }
}

/// A chunk at a version: what an accepted edit made durable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ChunkVersion {
    pub pos: ChunkPos,
    pub version: u64,
}

/// Server-to-client control messages.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ServerMessage {
    Welcome(Welcome),
    /// The edit is durable and has global sequence number `seq`.
    EditAccepted {
        client_edit_id: u64,
        seq: u64,
        /// Every chunk the edit changed and the version it moved it to
        /// (empty when the edit changed no voxel).
        changes: Vec<ChunkVersion>,
    },
    EditRejected {
        client_edit_id: u64,
        reason: RejectReason,
    },
    Error {
        code: ErrorCode,
        message: String,
    },
    Pong {
        nonce: u64,
        server_time: u64,
    },
    /// A `Subscribe`, `ResyncRequest`, `FullSnapshotRequest` or `Forget`
    /// was refused; nothing changed and the session goes on.
    RequestRefused(Refusal),
    /// The position report `seq` was refused; the previous position stays.
    /// Rate-bounded by the server: not every refused report is answered,
    /// and stale (older-seq) reports never are. `at` is the position the
    /// server holds for the player (none before its first): a client whose
    /// reports keep being refused moves the player back there.
    PositionRefused {
        seq: u32,
        reason: PositionRefusal,
        at: Option<FixedVec3>,
    },
    /// Cluster nodes only: who writes each region the session's view
    /// overlaps (at most [`crate::limits::MAX_REGION_OWNERS`]). Sent when
    /// that set of regions or any of their holders changes. Regions are
    /// `region_chunks` chunks on a side; region (x, z) holds chunk columns
    /// `x * region_chunks ..` and `z * region_chunks ..`. `ticket`, when
    /// the session has a position, lets the player `Arrive` at another
    /// node of the cluster. `node` is the sender's own node id: another
    /// node naming it (`RegionHolder::Node`) at an address other than the
    /// one the client reached it at is the same node.
    RegionOwners {
        region_chunks: u32,
        regions: Vec<RegionOwner>,
        ticket: Option<Ticket>,
        node: String,
    },
    /// The `Arrive` ticket was accepted: the first position report must
    /// be a legal move from `feet`, the ticket's spot timed from its
    /// `issued_ms`, or where the player was seen more than
    /// [`crate::limits::TICKET_SKEW_MS`] after it, timed then.
    Arrived {
        feet: FixedVec3,
    },
}

/// Why a position report was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PositionRefusal {
    /// Moved `distance` voxels since the last accepted report, more than
    /// the `allowed` distance for the time between them.
    TooFast { distance: Fixed, allowed: Fixed },
    /// The body would be inside solid terrain at `voxel`.
    InsideSolid { voxel: VoxelPos },
    /// A first report outside the spawn square (`Welcome::start`).
    OutsideSpawn { x: i32, z: i32, radius: u32 },
    /// A coordinate beyond 2^22 voxels, or a body voxel outside the
    /// world's vertical bounds.
    OutOfBounds,
    /// Every way from the last accepted position to this one (straight,
    /// bent at a right angle, or a small hop over; PROTOCOL.md, rule 5)
    /// passes the body through solid terrain; `voxel` is where the
    /// straight one does.
    PathBlocked { voxel: VoxelPos },
    /// The feet are above `apex`: off the ground, the highest a jump
    /// (`[validation.gravity] jump_voxels`) from where they last stood
    /// reaches, or where a fall began; standing, a jump above the last
    /// report that stood (PROTOCOL.md, rule 6).
    TooHigh { apex: Fixed },
}

/// Why a request other than an edit was refused.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Refusal {
    /// The `Subscribe` centre is more than `max` chunks (Chebyshev) from
    /// the chunk of the player's last accepted position, or, before any,
    /// from its spawn square's chunk columns: its view would reach past
    /// view radius + hysteresis (`max` is that less the view's radius).
    SubscribeTooFar { center: ChunkPos, max: u8 },
    /// A resync or full snapshot of a chunk outside the session's view.
    NotInInterest { pos: ChunkPos },
    /// A `Forget` naming more than `max` chunks
    /// ([`crate::limits::MAX_FORGET_CHUNKS`]); nothing was forgotten.
    ForgetTooLarge { chunks: u32, max: u32 },
    /// An `Arrive` ticket this node does not accept.
    BadTicket { reason: TicketRefusal },
}

/// Why an `Arrive` ticket was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum TicketRefusal {
    /// Not signed with this cluster's secret for this world (another
    /// cluster's, or this one's before a restore replaced the world).
    BadSignature,
    /// Issued for another player.
    OtherPlayer,
    /// Older than [`crate::limits::TICKET_TTL_MS`], or from the future.
    Expired,
    /// The session already has an accepted position.
    AlreadyPlaced,
    /// A position beyond 2^22 voxels.
    OutOfBounds,
    /// This server is not a node of a cluster: it accepts no tickets.
    NotClustered,
}

/// A chunk change, as broadcast after its edit is durable.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeltaUpdate {
    pub delta: ChunkDelta,
    /// Hash of the server's LOD-0 collision mesh of the new version.
    pub mesh_hash: u64,
    /// Sequence number of the edit that made this change.
    pub seq: u64,
}

/// Messages on the server's updates stream.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum WorldUpdate {
    /// The chunk was never modified: regenerate it from the seed (version 0).
    Generated {
        pos: ChunkPos,
    },
    /// A full chunk in the chunk codec's format.
    Snapshot {
        pos: ChunkPos,
        version: u64,
        hash: u64,
        mesh_hash: u64,
        data: Vec<u8>,
    },
    Delta(DeltaUpdate),
    /// The chunk left the view range; the client may drop it.
    Unsubscribed {
        pos: ChunkPos,
    },
    /// Every delta of the sequencer tick that ended with `last_seq` has been
    /// sent. Mesh hashes in that tick's deltas describe the world as it is
    /// now, so a client meshes its changed chunks here.
    TickEnd {
        last_seq: u64,
    },
    /// A modified chunk as a delta from its generated form: regenerate
    /// version 0 from the seed, check `delta.base_hash`, apply, and hold the
    /// chunk at `delta.to_version`. Sent instead of `Snapshot` to clients
    /// that can regenerate; usually tens of times smaller.
    Patched {
        delta: ChunkDelta,
        mesh_hash: u64,
    },
    /// These chunks left the view range (at most
    /// [`crate::limits::MAX_UNSUBSCRIBED_PER_UPDATE`]), or a cluster node
    /// that took their region over withdraws stale copies it sends again;
    /// the client drops them. Servers send this instead of one
    /// `Unsubscribed` per chunk.
    UnsubscribedMany {
        chunks: Vec<ChunkPos>,
    },
    /// An accepted edit, for sessions with `CAP_OP_REPLAY`: apply `edit` to
    /// the held chunks and check each listed chunk's result. Replaces the
    /// `Delta`s of exactly the listed chunks.
    Op(OpUpdate),
    /// Every chunk of the view around `center` at `radius` (the session's
    /// interest after a `Subscribe` or a re-centre on a position) has been
    /// sent, except those the client forgot: the view is loaded.
    InterestComplete {
        center: ChunkPos,
        radius: u8,
    },
}

/// One edit as an operation (`WorldUpdate::Op`): the client replays it with
/// the terrain core and checks the results against `chunks`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpUpdate {
    /// Sequence number of the edit.
    pub seq: u64,
    pub edit: Edit,
    /// The chunks of this session the edit changed, in (z, y, x) order.
    pub chunks: Vec<OpChunk>,
}

/// One chunk an op changed: the edit takes it from `version - 1` to
/// `version`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpChunk {
    pub pos: ChunkPos,
    /// The version after the edit (the base is `version - 1`).
    pub version: u64,
    /// Chunk hash after the edit.
    pub hash: u64,
    /// LOD-0 mesh hash at the tick's end, as in `Delta`.
    pub mesh_hash: u64,
}

/// A position report, sent as an unreliable datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PositionUpdate {
    /// Increases per report; older reports are ignored.
    pub seq: u32,
    /// Feet position in fixed-point voxels.
    pub pos: FixedVec3,
}
