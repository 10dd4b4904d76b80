//! `[engine]`: the engine's limits, their defaults and bounds.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::premesh::{
    self, DEFAULT_PREMESH_INFLIGHT, DEFAULT_PREMESH_RADIUS, DEFAULT_PREMESH_THREADS,
};
use super::residency::DEFAULT_RESIDENT_CHUNKS;
use super::session_share::DEFAULT_SESSION_COMMANDS;
use super::{frame_cache, snapshot, stream};

/// Default tick period.
pub const DEFAULT_TICK_MS: u64 = 10;
/// A tick longer than this many periods is logged with its phases.
pub const SLOW_TICK_PERIODS: u64 = 3;
/// Default microseconds of snapshot streaming per tick, for all sessions.
pub const DEFAULT_STREAM_US: u64 = 2_000;
/// Longest allowed streaming time per tick.
pub const MAX_STREAM_US: u64 = 1_000_000;
/// Longest allowed tick period.
pub const MAX_TICK_MS: u64 = 1000;
/// How often the positions of players who moved are stored (fsynced): a
/// crash loses at most this much of anyone's movement.
pub const POSITION_SAVE_EVERY: Duration = Duration::from_secs(1);
/// Default live sessions per player: a new login replaces the old one.
pub const DEFAULT_SESSIONS_PER_PLAYER: usize = 1;
/// Default capacity of the session-to-engine queue of players' traffic.
pub const DEFAULT_COMMAND_QUEUE: usize = 8192;
/// Default capacity of the queue of joins, leaves and admin requests,
/// which the engine serves first (see `inbox.rs`).
pub const DEFAULT_CONTROL_QUEUE: usize = 4096;
/// Largest allowed command or edit queue.
pub const MAX_COMMAND_QUEUE: usize = 1 << 20;
/// Largest allowed premesh backlog, generated-chunk cache or snapshot cache.
pub const MAX_ENGINE_CACHE: usize = 1 << 20;
/// Most worker threads `[engine] workers` may ask for.
pub const MAX_WORKERS: usize = 256;

/// Engine limits (`[engine]` in the config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EngineConfig {
    /// Milliseconds between ticks.
    pub tick_ms: u64,
    /// Microseconds of snapshot streaming per tick, for all sessions
    /// ([`DEFAULT_STREAM_US`]); the rest waits for later ticks.
    pub stream_us: u64,
    /// Player commands (edits, positions, subscriptions) queued from
    /// sessions before new ones are refused.
    pub command_queue: usize,
    /// Player commands one session may have in that queue at once
    /// ([`DEFAULT_SESSION_COMMANDS`]; position notices apart, one each at
    /// most), so no client fills it for everyone; at most `command_queue`
    /// takes effect.
    pub session_commands: usize,
    /// Joins, leaves and admin requests queued ([`DEFAULT_CONTROL_QUEUE`]);
    /// served before any player command.
    pub control_queue: usize,
    /// Live sessions one player may have ([`DEFAULT_SESSIONS_PER_PLAYER`]);
    /// a new login past it ends the player's oldest session.
    pub sessions_per_player: usize,
    /// Chunks around each player meshed in the background ([`DEFAULT_PREMESH_RADIUS`]).
    pub premesh_radius: u8,
    /// Background mesh jobs in flight at most ([`DEFAULT_PREMESH_INFLIGHT`]).
    pub premesh_inflight: usize,
    /// Player chunks whose surroundings wait for the background mesher
    /// ([`premesh::DEFAULT_PREMESH_BACKLOG`]); past it the oldest are dropped.
    pub premesh_backlog: usize,
    /// Generated chunks the background mesher keeps for reuse
    /// ([`premesh::DEFAULT_PREMESH_GENERATED_CHUNKS`]).
    pub premesh_generated_chunks: usize,
    /// Threads building background meshes ([`DEFAULT_PREMESH_THREADS`]).
    pub premesh_threads: usize,
    /// Generated chunks kept as patch bases for the chunk stream
    /// ([`stream::DEFAULT_PATCH_BASE_CHUNKS`]).
    pub patch_base_chunks: usize,
    /// Encoded snapshot frames kept for reuse
    /// ([`frame_cache::DEFAULT_SNAPSHOT_CACHE_ENTRIES`]).
    pub snapshot_cache_entries: usize,
    /// Whole-chunk frames kept, apart from those, for the clients that ask
    /// for whole chunks in a world clients regenerate
    /// ([`frame_cache::DEFAULT_FULL_FRAME_CACHE_ENTRIES`]).
    pub full_frame_cache_entries: usize,
    /// Chunks held in memory before cold ones are dropped ([`DEFAULT_RESIDENT_CHUNKS`]).
    pub resident_chunks: usize,
    /// Pre-images one online snapshot may hold when its request names no
    /// limit ([`snapshot::DEFAULT_SNAPSHOT_PREIMAGES`]).
    pub snapshot_preimages: usize,
    /// Encoded bytes of pre-images one online snapshot may hold, whatever
    /// its request ([`snapshot::DEFAULT_SNAPSHOT_PREIMAGE_BYTES`]).
    pub snapshot_preimage_bytes: usize,
    /// Threads that apply region lanes, mesh, encode for the store and fan
    /// deltas out, the engine thread among them when 2 or more; 0 means
    /// one per available core.
    pub workers: usize,
}

impl Default for EngineConfig {
    fn default() -> Self {
        Self {
            tick_ms: DEFAULT_TICK_MS,
            stream_us: DEFAULT_STREAM_US,
            command_queue: DEFAULT_COMMAND_QUEUE,
            session_commands: DEFAULT_SESSION_COMMANDS,
            control_queue: DEFAULT_CONTROL_QUEUE,
            sessions_per_player: DEFAULT_SESSIONS_PER_PLAYER,
            premesh_radius: DEFAULT_PREMESH_RADIUS,
            premesh_inflight: DEFAULT_PREMESH_INFLIGHT,
            premesh_backlog: premesh::DEFAULT_PREMESH_BACKLOG,
            premesh_generated_chunks: premesh::DEFAULT_PREMESH_GENERATED_CHUNKS,
            premesh_threads: DEFAULT_PREMESH_THREADS,
            patch_base_chunks: stream::DEFAULT_PATCH_BASE_CHUNKS,
            snapshot_cache_entries: frame_cache::DEFAULT_SNAPSHOT_CACHE_ENTRIES,
            full_frame_cache_entries: frame_cache::DEFAULT_FULL_FRAME_CACHE_ENTRIES,
            resident_chunks: DEFAULT_RESIDENT_CHUNKS,
            snapshot_preimages: snapshot::DEFAULT_SNAPSHOT_PREIMAGES,
            snapshot_preimage_bytes: snapshot::DEFAULT_SNAPSHOT_PREIMAGE_BYTES,
            workers: 0,
        }
    }
}

/// How chunks are streamed to sessions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamPolicy {
    /// Snapshot bytes each session may be sent per tick (`net.send_budget_bytes_per_tick`).
    pub send_budget: usize,
    /// Clients can regenerate version-0 chunks from `Welcome`'s parameters;
    /// false for heightmap worlds, which then get full snapshots.
    pub regenerable: bool,
}
