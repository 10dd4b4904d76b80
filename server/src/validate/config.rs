//! The `[validation]` config section: every limit of the edit and position rules.

use serde::{Deserialize, Serialize};
use strata_terrain::edit::{Fixed, MAX_POWER, MAX_RADIUS};

use super::bounds::WorldBounds;
use super::permissions::PlayerKinds;
use super::ratelimit::BucketConfig;
use super::spawn::SpawnArea;

/// Largest sphere radius a client may ask for, in voxels (terrain's hard cap is 64).
pub const DEFAULT_MAX_RADIUS: u16 = 8;
/// Largest explosion power a client may ask for (terrain's hard cap is 2048).
pub const DEFAULT_MAX_POWER: u16 = 512;
/// How far from the eye an edit's target may be, in voxels.
pub const DEFAULT_REACH: f64 = 10.0;
/// How far before the target a ray may first hit terrain and still see it,
/// in voxels, on top of the edit's radius (the surface sits up to a voxel
/// in front of a target on it).
pub const DEFAULT_LOS_TOLERANCE: f64 = 1.0;
/// Eye height above the feet, in voxels.
pub const DEFAULT_EYE_HEIGHT: f64 = 1.6;
/// Fastest legal movement, in voxels per second (running and falling).
pub const DEFAULT_MAX_SPEED: f64 = 20.0;
/// Extra fraction of the speed-limited distance allowed for jitter.
pub const DEFAULT_SPEED_SLACK_FACTOR: f64 = 0.25;
/// Extra voxels allowed on every move (datagram timing, rounding).
pub const DEFAULT_SPEED_SLACK_VOXELS: f64 = 2.0;
/// The most time a move is allowed for, in ms: a report after a longer
/// silence is allowed only this much walking since the last one. Else a
/// player who stays quiet for a minute could report a spot 1,500 voxels
/// away, through any wall. Twice the longest stall a loaded server
/// should show, so a moving player's next report still passes.
pub const DEFAULT_MAX_MOVE_MS: u64 = 2_000;
/// Largest allowed `max_move_ms`; the longest move it allows with
/// `max_speed` and the slack must be within
/// [`super::position::MAX_SWEPT_MOVE`] too.
pub const MAX_MAX_MOVE_MS: u64 = 60_000;
/// Longest allowed `reach`: an edit's sight ray, the meshes it needs and
/// the chunks it reads grow with it.
pub const MAX_REACH: f64 = 128.0;
/// Largest allowed `los_tolerance`, in voxels.
pub const MAX_LOS_TOLERANCE: f64 = 16.0;
/// Largest allowed `eye_height`, in voxels.
pub const MAX_EYE_HEIGHT: f64 = 16.0;
/// Largest allowed `max_speed` and `speed_slack_voxels`.
pub const MAX_SPEED_LIMIT: f64 = 1024.0;
/// Largest allowed `speed_slack_factor`.
pub const MAX_SPEED_SLACK_FACTOR: f64 = 16.0;
/// Half-width of the default spawn protection cube around the origin, in voxels.
pub const DEFAULT_SPAWN_PROTECTION_RADIUS: i32 = 32;
/// Burst of edits per player.
pub const DEFAULT_EDIT_BURST: u64 = 10;
/// Sustained edits per second per player.
pub const DEFAULT_EDITS_PER_SECOND: u64 = 5;
/// Burst of edited voxels (bounding-box volume) per player.
pub const DEFAULT_VOLUME_BURST: u64 = 100_000;
/// Sustained edited voxels per second per player.
pub const DEFAULT_VOLUME_PER_SECOND: u64 = 50_000;
/// Refused edits a player may pile up before the session is disconnected.
pub const DEFAULT_REJECT_BURST: u64 = 100;
/// Refused edits per second that never add up to a disconnect.
pub const DEFAULT_REJECTS_PER_SECOND: u64 = 10;
/// Default burst of a session's requests, in chunks they touch (a
/// subscription costs its whole view, (2r+1)^3 chunks; see
/// `net::session::request_cost`): ten radius-8 views at once.
pub const DEFAULT_REQUEST_BURST: u64 = 50_000;
/// Default refill of a session's request bucket, chunks per second.
pub const DEFAULT_REQUESTS_PER_SECOND: u64 = 10_000;
/// Default burst of position reports the engine handles per session.
pub const DEFAULT_POSITION_BURST: u64 = 30;
/// Default position reports per second the engine handles per session
/// (game clients send 10 to 60).
pub const DEFAULT_POSITIONS_PER_SECOND: u64 = 60;
/// Default burst of a player's first placements (reports of a session
/// with no position yet).
pub const DEFAULT_PLACEMENT_BURST: u64 = 10;
/// Default first placements per second per player.
pub const DEFAULT_PLACEMENTS_PER_SECOND: u64 = 2;
/// Default burst of a player's logins: a client that lost its connection
/// comes back several times in a minute.
pub const DEFAULT_JOIN_BURST: u64 = 10;
/// Default logins per second per player, past the burst.
pub const DEFAULT_JOINS_PER_SECOND: u64 = 1;
/// Largest capacity and refill of any `[validation.*_rate]` bucket.
pub const MAX_REQUEST_RATE: u64 = 1 << 32;
/// Least milliseconds between two `PositionRefused` answers to one session.
pub const DEFAULT_POSITION_REFUSAL_MS: u64 = 500;
/// Players whose last position the server remembers after they leave.
pub const DEFAULT_REMEMBERED_PLAYERS: usize = 100_000;

/// Limits of the validation rules (`[validation]` in the server config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ValidationConfig {
    /// Edit kinds players may use (lowercase names); admins may use all.
    pub player_kinds: PlayerKinds,
    /// See [`DEFAULT_MAX_RADIUS`]; clamped to the terrain's hard cap.
    pub max_radius: u16,
    /// See [`DEFAULT_MAX_POWER`]; clamped to the terrain's hard cap.
    pub max_power: u16,
    /// See [`DEFAULT_REACH`].
    pub reach: f64,
    /// See [`DEFAULT_LOS_TOLERANCE`].
    pub los_tolerance: f64,
    /// See [`DEFAULT_EYE_HEIGHT`].
    pub eye_height: f64,
    /// See [`DEFAULT_MAX_SPEED`].
    pub max_speed: f64,
    /// See [`DEFAULT_SPEED_SLACK_FACTOR`].
    pub speed_slack_factor: f64,
    /// See [`DEFAULT_SPEED_SLACK_VOXELS`].
    pub speed_slack_voxels: f64,
    /// See [`DEFAULT_MAX_MOVE_MS`].
    pub max_move_ms: u64,
    /// Vertical world bounds for edits and positions.
    #[serde(skip)]
    pub bounds: WorldBounds,
    /// See [`DEFAULT_SPAWN_PROTECTION_RADIUS`]; used when no zones are stored.
    pub spawn_protection_radius: i32,
    /// Where players the server does not remember may appear.
    pub spawn: SpawnArea,
    /// Edits per player: burst and refill per second.
    pub edit_rate: BucketConfig,
    /// Edited voxels per player: burst and refill per second. An edit costs
    /// its bounding-box volume times its kind's weight, capped at the burst
    /// so any legal edit can pass.
    pub volume_rate: BucketConfig,
    /// Bucket voxels per voxel of an edit's box, by kind.
    pub volume_weight: super::VolumeWeights,
    /// Refused edits per player: burst and refill per second. Each refusal
    /// takes one token; a player with none left is disconnected and logged.
    pub reject_rate: BucketConfig,
    /// A player's requests (subscriptions, resyncs, forgets, snapshots,
    /// tickets, pings, and 1 for each edit), in chunks they touch: burst
    /// and refill per second, one bucket for all of the player's sessions
    /// (a reconnect does not refill it). A session out of tokens is not
    /// read until it has them again, so QUIC's flow control slows its
    /// client down.
    pub request_rate: BucketConfig,
    /// A session's position reports handed to the engine: burst and
    /// refill per second. A datagram past them is dropped (the next one
    /// supersedes it anyway), so a client sending at line rate costs the
    /// engine no more than one sending at this rate.
    pub position_rate: BucketConfig,
    /// A player's placements: position reports of a session that has no
    /// position yet (a player the server does not remember, anywhere in
    /// the spawn square at any height), each of which loads and may
    /// generate the chunks around the body before it can be refused.
    /// Burst and refill per second, one bucket for all of the player's
    /// sessions; a report past them is dropped before anything is loaded.
    /// An honest client places once.
    pub placement_rate: BucketConfig,
    /// A player's logins: Hellos with a valid token that would join.
    /// Burst and refill per second, one bucket a player, kept across its
    /// sessions; a Hello past it is refused (`TooManyConnections`) before
    /// the engine hears of it. Each login ends the player's older session
    /// and starts a view over, which the player's requests pay for.
    pub join_rate: BucketConfig,
    /// Players whose last position is kept after their sessions end, so a
    /// reconnect resumes there ([`DEFAULT_REMEMBERED_PLAYERS`]).
    pub remembered_players: usize,
    /// A refused position report is answered with `PositionRefused` at most
    /// once per this many milliseconds per session
    /// ([`DEFAULT_POSITION_REFUSAL_MS`]); 0 never answers.
    pub position_refusal_ms: u64,
    /// Players' feet held to the ground (`[validation.gravity]`).
    pub gravity: super::gravity::GravityConfig,
}

impl ValidationConfig {
    /// The longest move speed allows after a silence of `max_move_ms`,
    /// slack included, in voxels.
    pub fn longest_move(&self) -> f64 {
        self.max_speed * (self.max_move_ms as f64 / 1000.0) * (1.0 + self.speed_slack_factor)
            + self.speed_slack_voxels
    }
}

impl Default for ValidationConfig {
    fn default() -> Self {
        Self {
            player_kinds: PlayerKinds::default(),
            max_radius: DEFAULT_MAX_RADIUS,
            max_power: DEFAULT_MAX_POWER,
            reach: DEFAULT_REACH,
            los_tolerance: DEFAULT_LOS_TOLERANCE,
            eye_height: DEFAULT_EYE_HEIGHT,
            max_speed: DEFAULT_MAX_SPEED,
            speed_slack_factor: DEFAULT_SPEED_SLACK_FACTOR,
            speed_slack_voxels: DEFAULT_SPEED_SLACK_VOXELS,
            max_move_ms: DEFAULT_MAX_MOVE_MS,
            bounds: WorldBounds::default(),
            spawn_protection_radius: DEFAULT_SPAWN_PROTECTION_RADIUS,
            spawn: SpawnArea::default(),
            edit_rate: BucketConfig {
                capacity: DEFAULT_EDIT_BURST,
                per_second: DEFAULT_EDITS_PER_SECOND,
            },
            volume_rate: BucketConfig {
                capacity: DEFAULT_VOLUME_BURST,
                per_second: DEFAULT_VOLUME_PER_SECOND,
            },
            volume_weight: super::VolumeWeights::default(),
            reject_rate: BucketConfig {
                capacity: DEFAULT_REJECT_BURST,
                per_second: DEFAULT_REJECTS_PER_SECOND,
            },
            request_rate: BucketConfig {
                capacity: DEFAULT_REQUEST_BURST,
                per_second: DEFAULT_REQUESTS_PER_SECOND,
            },
            position_rate: BucketConfig {
                capacity: DEFAULT_POSITION_BURST,
                per_second: DEFAULT_POSITIONS_PER_SECOND,
            },
            placement_rate: BucketConfig {
                capacity: DEFAULT_PLACEMENT_BURST,
                per_second: DEFAULT_PLACEMENTS_PER_SECOND,
            },
            join_rate: BucketConfig {
                capacity: DEFAULT_JOIN_BURST,
                per_second: DEFAULT_JOINS_PER_SECOND,
            },
            remembered_players: DEFAULT_REMEMBERED_PLAYERS,
            position_refusal_ms: DEFAULT_POSITION_REFUSAL_MS,
            gravity: super::gravity::GravityConfig::default(),
        }
    }
}

impl ValidationConfig {
    /// The radius cap in fixed point, never above the terrain's hard cap.
    pub fn max_radius_fixed(&self) -> Fixed {
        Fixed::from_voxels(self.max_radius as i32).min(MAX_RADIUS)
    }

    /// The power cap, never above the terrain's hard cap.
    pub fn max_power_capped(&self) -> u16 {
        self.max_power.min(MAX_POWER)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_clamp_to_terrain_and_json_round_trips() {
        let mut c = ValidationConfig {
            max_radius: 1000,
            max_power: u16::MAX,
            ..Default::default()
        };
        assert_eq!(c.max_radius_fixed(), MAX_RADIUS);
        assert_eq!(c.max_power_capped(), MAX_POWER);
        c.max_radius = 3;
        let back: ValidationConfig =
            serde_json::from_str(&serde_json::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        let partial: ValidationConfig = serde_json::from_str(r#"{"reach": 4.0}"#).unwrap();
        assert_eq!(partial.reach, 4.0);
        assert_eq!(partial.max_radius, DEFAULT_MAX_RADIUS);
    }
}
