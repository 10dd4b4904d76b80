//! The plain C structs and enums of the API.

use std::ffi::c_char;

/// A chunk and the version an edit moved it to.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StrataChunkVersion {
    pub chunk: [i32; 3],
    pub version: u64,
}

/// What a `StrataEvent` reports.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StrataEventKind {
    /// Nothing happened since the last poll.
    None = 0,
    /// `ticket` was sequenced as `seq`; `changes` lists the chunk versions.
    EditAccepted = 1,
    /// `ticket` was refused: `reject` says why, `message` in words.
    EditRejected = 2,
    /// No verdict will come for `ticket` (connection ended, timeout).
    EditFailed = 3,
    /// The visible copy of `chunk` changed, or it left the view.
    ChunkChanged = 4,
    /// The connection ended; `error_code` is the server's reason (0: none).
    /// Always the last event.
    Disconnected = 5,
    /// Position report `seq` was refused: `position_refusal` says why,
    /// `message` in words, `held` where the server holds the player (move
    /// back there). The server keeps the previous position and answers at
    /// most a few refused reports a second.
    PositionRefused = 6,
    /// Every chunk within `radius` of chunk `chunk` (the view's centre) has
    /// arrived, except forgotten ones: the view is loaded.
    ViewLoaded = 7,
}

/// Why the server refused a position report.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StrataPositionRefusal {
    None = 0,
    /// Farther from the last accepted position than the speed limit allows.
    TooFast = 1,
    /// The body would be inside solid terrain.
    InsideSolid = 2,
    /// A first position outside the spawn square (see `StrataWelcome`).
    OutsideSpawn = 3,
    /// Outside the world's bounds.
    OutOfBounds = 4,
    /// Every way from the held position passes the body through solid
    /// terrain (a wall): move the player back to `held`. For a first
    /// position (no held one): solid terrain above the eye, where a new
    /// player may not appear: pick a spot under the open sky.
    PathBlocked = 5,
    /// Higher than a jump from where the player last stood: move the
    /// player back to `held`.
    TooHigh = 6,
}

/// Why the server refused an edit.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StrataReject {
    None = 0,
    NotPermitted = 1,
    RadiusTooLarge = 2,
    PowerTooLarge = 3,
    OutOfReach = 4,
    NoLineOfSight = 5,
    RateLimited = 6,
    VolumeRateLimited = 7,
    OutOfBounds = 8,
    ProtectedZone = 9,
    /// No validated position yet: send one, then edit again.
    NoPosition = 10,
    Invalid = 11,
    /// The server is busy: edit again.
    Busy = 12,
    /// Another server of the cluster holds the region: the message names
    /// the node and its address. An edit reaching across a border into
    /// it (the region named is not the edit's own) may pass when edited
    /// again a few seconds later: the server asked for the region. One made
    /// while standing in the region named passes only from the edit's side.
    RegionElsewhere = 13,
    /// The cluster server holds as many regions as it may and no server
    /// holds this one: send the edit to another server, or here later.
    NodeFull = 14,
}

/// Bytes of `StrataEvent.message`, its NUL included.
pub const STRATA_MESSAGE_LEN: usize = 256;

/// One event from `strata_poll`. Fields that do not apply to `kind` are 0.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataEvent {
    pub kind: StrataEventKind,
    /// The edit's ticket, from `strata_edit`.
    pub ticket: u64,
    /// EDIT_ACCEPTED: the edit's global sequence number.
    pub seq: u64,
    /// EDIT_ACCEPTED: the chunk versions the edit made durable, owned by
    /// the session and valid until the next `strata_poll` on it from any
    /// thread (poll from one thread if you read them).
    pub changes: *const StrataChunkVersion,
    pub changes_len: usize,
    /// EDIT_REJECTED: why.
    pub reject: StrataReject,
    /// CHUNK_CHANGED: the chunk; VIEW_LOADED: the view's centre chunk.
    pub chunk: [i32; 3],
    /// DISCONNECTED: the server's error code (its QUIC close code), or 0.
    pub error_code: u32,
    /// REJECTED, FAILED, DISCONNECTED, POSITION_REFUSED: a NUL-terminated
    /// explanation, truncated to fit.
    pub message: [c_char; STRATA_MESSAGE_LEN],
    /// POSITION_REFUSED: why (`seq` is the refused report's).
    pub position_refusal: StrataPositionRefusal,
    /// VIEW_LOADED: the view's radius in chunks (`chunk` is its centre).
    pub radius: u8,
    /// POSITION_REFUSED: the feet position (voxels) the server holds for
    /// the player and checks each report from. Move the player back there
    /// when reports go on being refused.
    pub held: [f64; 3],
    /// POSITION_REFUSED: 1 when `held` is set; 0 before the server holds
    /// any position for the player.
    pub held_known: u8,
}

/// Kinds of `StrataEdit`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StrataEditKind {
    /// Sphere at `center`, `radius`, removing `strength` (harder materials less).
    Mine = 0,
    /// Crater at `center`, `radius`, `power`.
    Explode = 1,
    /// Sphere of `material` at `center`, `radius`, `strength`.
    Build = 2,
    /// Inclusive voxel box `min..=max` filled with `material`.
    FillBox = 3,
    /// Inclusive voxel box `min..=max` emptied to air.
    ClearBox = 4,
    /// Structure `structure` at `min`, turned `rotation` quarter turns.
    PlaceStructure = 5,
    /// Relaxes density at `center`, `radius`, `strength`.
    Smooth = 6,
}

/// An edit to send. `kind` is a `StrataEditKind` value; each kind reads
/// only its own fields (listed there). Positions are in voxels, rounded to
/// 1/256 voxel on the wire.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataEdit {
    pub kind: u32,
    pub center: [f64; 3],
    pub radius: f64,
    pub strength: u8,
    pub power: u16,
    pub material: u8,
    pub min: [i32; 3],
    pub max: [i32; 3],
    pub structure: u32,
    pub rotation: u8,
}

/// The server's greeting, from `strata_welcome`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataWelcome {
    pub session: u64,
    pub world_seed: u64,
    /// The last durable edit's sequence number at login.
    pub last_seq: u64,
    /// View radius in chunks.
    pub view_radius: u8,
    /// 1: the server remembers the player at `resume_feet`, and the first
    /// position must be a legal move from there. 0: the first position's
    /// column must lie within `spawn_radius` voxels of (`spawn_x`, `spawn_z`)
    /// on both axes, not inside terrain, and (unless the server turned it
    /// off) under the open sky: no solid voxel above the eye. A byte, not a
    /// `bool`: every language reads it as one (C#'s default `bool` is 4).
    pub resume: u8,
    pub resume_feet: [f64; 3],
    pub spawn_x: i32,
    pub spawn_z: i32,
    pub spawn_radius: u32,
}

/// The replica's counters, from `strata_stats`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataStats {
    /// Chunks held now (on a cluster, by the first node's connection: every
    /// connection holds the whole view). The others are summed over the
    /// connections.
    pub chunks_held: u64,
    /// Deltas applied (after their version and hash checks).
    pub deltas: u64,
    /// Whole chunks taken in (snapshots and patches).
    pub snapshots: u64,
    /// Chunks regenerated from the seed.
    pub generated: u64,
    /// Changed chunks re-meshed and compared with the server's mesh hash.
    pub meshes_checked: u64,
    /// Of those, the ones whose hash differed (a bug: report it).
    pub mesh_mismatches: u64,
    /// Deltas or snapshots that failed their hash check (resynced).
    pub hash_mismatches: u64,
    /// Chunks taken forward by replaying an edit (`STRATA_CAP_OP_REPLAY`).
    pub op_chunks: u64,
    /// Op chunks that did not replay (missing base or another hash) and
    /// were resynced instead.
    pub op_fallbacks: u64,
}

/// Capability bit: every chunk arrives whole (the server's snapshot, hash
/// checked), so the client never runs the world generator.
pub const STRATA_CAP_SNAPSHOTS: u32 = 1;
/// Capability bit: accepted edits arrive as the edit itself, replayed by
/// the library with the server's terrain code and hash-checked, instead
/// of per-chunk deltas.
pub const STRATA_CAP_OP_REPLAY: u32 = 2;

/// The ABI this header describes: raised whenever a struct's layout or a
/// function's signature changes incompatibly. A program checks at startup
/// that `strata_abi_version()` returns the value it was compiled with.
pub const STRATA_ABI_VERSION: u32 = 2;

/// Options of `strata_connect_with`. Set `size` to
/// `sizeof(StrataConnectOptions)` and zero the rest before setting what
/// you want: options added later go after the ones here, with 0 as their
/// default, so a program built against this header keeps working with a
/// later library.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataConnectOptions {
    /// `sizeof(StrataConnectOptions)` in the caller's header: the library
    /// reads that many bytes. Options past it (a header older than the
    /// library) read as 0; bytes past the options this library knows (a
    /// newer header) must be 0, or the connect is refused: an option it
    /// cannot honour is never ignored. At least the size of this first
    /// layout, 12.
    pub size: u32,
    /// Show the player's own edits at once (as `strata_connect`'s
    /// `predict`): nonzero for yes. A byte, not a `bool`: any value a
    /// foreign caller puts there is sound.
    pub predict: u8,
    /// `STRATA_CAP_*` bits; unknown bits are ignored by the server.
    pub capabilities: u32,
}

/// A mesh's arrays, from `strata_mesh_data`: owned by the `StrataMesh`
/// and valid until `strata_mesh_free`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StrataMeshData {
    /// `vertex_count * 3` floats: x, y, z in chunk-local voxels.
    pub positions: *const f32,
    /// `vertex_count * 3` floats: unit normals pointing into air.
    pub normals: *const f32,
    /// `vertex_count` material ids.
    pub materials: *const u8,
    /// `index_count` indices, three per triangle, counter-clockwise seen
    /// from air.
    pub indices: *const u32,
    pub vertex_count: usize,
    pub index_count: usize,
    /// World voxel coordinates of the chunk's local (0, 0, 0).
    pub origin: [i32; 3],
    pub lod: u8,
    /// 1 when all 26 neighbours were held; 0 when not (faces on the
    /// missing sides are provisional). A byte, not a `bool`, as
    /// `StrataWelcome.resume`.
    pub complete: u8,
    /// The mesh hash (at LOD 0 the server's, for the same chunk versions).
    pub hash: u64,
}
