//! Position rules: stale reports, world bounds, speed, and not inside solid terrain.

use glam::DVec3;
use strata_protocol::{PositionRefusal, PositionUpdate};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{ChunkPos, VoxelPos, VoxelRead, CHUNK_SIZE};
use thiserror::Error;

use super::config::ValidationConfig;
use super::gravity::{self, Air};
use super::spawn::MAX_SKY_CHUNKS;
use super::sweep;

/// The longest move whose path is swept, in voxels: a longer one is
/// refused as too fast whatever `max_speed` and `max_move_ms` allow
/// (the server's config check keeps them within it), so a move's path
/// reads a bounded number of chunks.
pub const MAX_SWEPT_MOVE: f64 = 256.0;

/// How a session got its position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    /// Where the server last knew the player, at the session's start.
    Resumed,
    /// From an accepted `Arrive` ticket.
    Arrived,
    /// From an accepted position report.
    Reported,
}

/// The last position a session reported that passed every rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ValidatedPosition {
    pub feet: FixedVec3,
    pub at_ms: u64,
    pub seq: u32,
    /// The jitter slack still unspent, in thousandths of a voxel
    /// ([`check_motion`]).
    pub slack_milli: u64,
    /// How the session got it: a ticket may replace only a resume.
    pub placement: Placement,
    /// When the player was last known to stand at `feet` or on the way to
    /// it: the report's time, the ticket's `issued_ms`, or for a resume the
    /// resumed position's (0 when unknown). A ticket older than it would
    /// take the player back in time.
    pub known_ms: u64,
    /// When the session's last report past the order rule was handled
    /// (accepted or refused), or it was placed: the silence a move may
    /// count runs from here ([`Self::credited_ms`]).
    pub heard_ms: u64,
    /// Time counted for reports refused since `at_ms` (each silence before
    /// one capped): a player refused once (a stall, lost datagrams) is
    /// allowed more with every report it goes on sending, and catches up.
    pub credit_ms: u64,
    /// Time the next silence may count beyond `[validation] max_move_ms`:
    /// for an arrival until its first report, the age of the spot it was
    /// placed at when taken (the player walked on meanwhile, on another
    /// node), as far as it was seen walking and at most
    /// [`MAX_ARRIVAL_GRACE_MS`]; else 0.
    pub grace_ms: u64,
    /// Whether the feet stood, and how high they may rise
    /// (`[validation.gravity]`).
    pub air: Air,
}

/// Most of a ticket's age an arrival's first move may count beyond
/// `max_move_ms`: nodes issue a ticket every 10 s, so an honest client's
/// newest is at most that old, and 2 s more for its join. An older ticket
/// (they live 30 s) gives no more.
pub const MAX_ARRIVAL_GRACE_MS: u64 = 12_000;

impl ValidatedPosition {
    /// A resumed position, timed from `at_ms`, with its whole slack; the
    /// player was last known there at `known_ms`.
    pub fn resumed(feet: FixedVec3, at_ms: u64, known_ms: u64, cfg: &ValidationConfig) -> Self {
        Self {
            feet,
            at_ms,
            seq: 0,
            slack_milli: full_slack_milli(cfg),
            placement: Placement::Resumed,
            known_ms,
            heard_ms: at_ms,
            credit_ms: 0,
            grace_ms: 0,
            air: Air::Unsettled,
        }
    }

    /// An arrival placed at `feet`, where the player was at `issued_ms`
    /// (the ticket's spot and issue, or a newer sighting), taken at
    /// `now_ms`, with its whole slack; its grace is that spot's age, at
    /// most `walked` (how long after it the player may have walked on) and
    /// [`MAX_ARRIVAL_GRACE_MS`].
    pub fn arrived(
        feet: FixedVec3,
        issued_ms: u64,
        now_ms: u64,
        walked: u64,
        cfg: &ValidationConfig,
    ) -> Self {
        let grace_ms = now_ms
            .saturating_sub(issued_ms)
            .min(walked)
            .min(MAX_ARRIVAL_GRACE_MS);
        Self {
            feet,
            at_ms: issued_ms,
            seq: 0,
            slack_milli: full_slack_milli(cfg),
            placement: Placement::Arrived,
            known_ms: issued_ms,
            heard_ms: issued_ms,
            credit_ms: 0,
            grace_ms,
            air: Air::Unsettled,
        }
    }

    /// The time a move reported at `now_ms` may count since `at_ms`: what
    /// refused reports earned, and the silence since the last one heard,
    /// capped at `max_move_ms` (plus any grace). Else a player could go
    /// quiet and then report a spot as far as the silence was long.
    ///
    /// The whole is capped at `max_move_ms` (plus any grace) as well: a
    /// player refused for longer (a long stall, a path through a wall)
    /// gains nothing by reporting on, and is told where the server holds
    /// it (`PositionRefused::at`) to move back there.
    pub fn credited_ms(&self, now_ms: u64, cfg: &ValidationConfig) -> u64 {
        let most = cfg.max_move_ms.saturating_add(self.grace_ms);
        let silence = now_ms.saturating_sub(self.heard_ms).min(most);
        self.credit_ms.saturating_add(silence).min(most)
    }

    /// This position still, after a report at `now_ms` was refused: the
    /// time since the last report heard is credited.
    ///
    /// An arrival's grace goes with its first report, refused or not: one
    /// try, and the next ones are checked from where it was placed, where
    /// the client is told it stands.
    pub fn heard(self, now_ms: u64, cfg: &ValidationConfig) -> Self {
        Self {
            credit_ms: self.credited_ms(now_ms, cfg),
            heard_ms: now_ms.max(self.heard_ms),
            grace_ms: 0,
            ..self
        }
    }
}

/// How long the jitter slack (`speed_slack_voxels`) takes to refill from
/// empty. Reports closer together share it, so sending more of them buys
/// no extra distance: over any time `t` a player moves at most
/// `max_speed * (1 + speed_slack_factor) * t` plus the slack, plus the
/// slack again for every `SLACK_REFILL_MS` of `t`.
pub const SLACK_REFILL_MS: u64 = 250;

fn full_slack_milli(cfg: &ValidationConfig) -> u64 {
    (cfg.speed_slack_voxels.max(0.0) * 1000.0) as u64
}

/// Why a position report was not accepted. The previous position stays.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PositionReject {
    #[error("no such session")]
    UnknownSession,
    #[error("stale report {seq} (last accepted {last}); ignored")]
    Stale { seq: u32, last: u32 },
    #[error("position outside the world bounds")]
    OutOfBounds,
    #[error(
        "a first position must lie in the spawn area ({radius} voxels around column {x}, {z})"
    )]
    OutsideSpawn { x: i32, z: i32, radius: u32 },
    #[error("moved {distance:.2} voxels, at most {allowed:.2} allowed")]
    TooFast { distance: f64, allowed: f64 },
    #[error("body inside solid terrain at {voxel:?}")]
    InsideSolid { voxel: VoxelPos },
    #[error(
        "every way from the last accepted position passes through solid terrain (at {voxel:?})"
    )]
    PathBlocked { voxel: VoxelPos },
    #[error("feet above {apex:.2}, the highest a jump from the last ground reaches")]
    TooHigh { apex: f64 },
    #[error("chunk {pos:?} must be loaded from the store first")]
    ChunkNotLoaded { pos: ChunkPos },
    #[error("past the player's [validation.placement_rate]; dropped before loading anything")]
    PlacementLimited,
}

impl PositionReject {
    /// What the client is told, if anything: stale reports and the
    /// server's own conditions get no answer.
    pub fn refusal(&self) -> Option<PositionRefusal> {
        let fixed = |v: f64| Fixed::from_f64(v).unwrap_or(Fixed(i32::MAX));
        match *self {
            PositionReject::OutOfBounds => Some(PositionRefusal::OutOfBounds),
            PositionReject::OutsideSpawn { x, z, radius } => {
                Some(PositionRefusal::OutsideSpawn { x, z, radius })
            }
            PositionReject::TooFast { distance, allowed } => Some(PositionRefusal::TooFast {
                distance: fixed(distance),
                allowed: fixed(allowed),
            }),
            PositionReject::InsideSolid { voxel } => Some(PositionRefusal::InsideSolid { voxel }),
            PositionReject::PathBlocked { voxel } => Some(PositionRefusal::PathBlocked { voxel }),
            PositionReject::TooHigh { apex } => {
                Some(PositionRefusal::TooHigh { apex: fixed(apex) })
            }
            PositionReject::UnknownSession
            | PositionReject::Stale { .. }
            | PositionReject::ChunkNotLoaded { .. }
            | PositionReject::PlacementLimited => None,
        }
    }
}

/// A fixed-point position as a glam vector, in voxels (exact).
pub fn to_dvec3(p: FixedVec3) -> DVec3 {
    DVec3::from_array(p.to_f64())
}

/// Voxel whose sample point is nearest to `p` (voxel `i` sits at point `i`).
pub fn nearest_voxel(p: DVec3) -> VoxelPos {
    let v = (p + 0.5).floor().as_ivec3();
    VoxelPos::new(v.x, v.y, v.z)
}

/// The voxel containing the feet.
pub fn feet_voxel(feet: FixedVec3) -> VoxelPos {
    VoxelPos::new(
        feet.x.floor_voxel(),
        feet.y.floor_voxel(),
        feet.z.floor_voxel(),
    )
}

/// Eye position in world voxel units.
pub fn eye(feet: FixedVec3, cfg: &ValidationConfig) -> DVec3 {
    to_dvec3(feet) + DVec3::Y * cfg.eye_height
}

/// How far above the feet the body's lowest voxel is looked for, in
/// voxels: the nearest to this point is the first voxel wholly above the
/// feet. It is judged by the surface in its column ([`low_blocks`]), so
/// feet on a slope stand while feet sunk under a wall's lowest voxel do
/// not: a one-voxel gap is never room for a body.
pub const BODY_LOW: f64 = 0.5;
/// How far the feet may be below the surface in the body's column, in
/// voxels (as `gravity::GROUND_SINK` lets them stand).
pub const BODY_SINK: f64 = 0.5;

/// Whether the body's lowest voxel `low` (the first wholly above feet at
/// height `feet_y`) is in the way: solid, and the surface in its column,
/// where the density crosses the threshold between it and the voxel above
/// (as the mesh's surface does), more than [`BODY_SINK`] above the feet.
/// Reads `low` and the voxel above it (air above `max_y`, the world's top).
pub fn low_blocks(voxels: &impl VoxelRead, low: VoxelPos, feet_y: f64, max_y: i32) -> bool {
    let here = voxels.voxel(low);
    if !here.is_solid() {
        return false;
    }
    let over = VoxelPos::new(low.x, low.y.saturating_add(1), low.z);
    let above = match over.y > max_y {
        true => strata_terrain::Voxel::AIR,
        false => voxels.voxel(over),
    };
    if above.is_solid() {
        return true;
    }
    let (d, up) = (f64::from(here.density), f64::from(above.density));
    let surface = f64::from(low.y) + (d - SURFACE_DENSITY) / (d - up);
    surface - feet_y > BODY_SINK
}

/// The density the surface passes through (between solid and air).
const SURFACE_DENSITY: f64 = 127.5;

/// The first of the body's voxels at `feet` in the way: the lowest judged
/// by [`low_blocks`], the others solid.
pub fn body_blocked(
    voxels: &impl VoxelRead,
    feet: FixedVec3,
    cfg: &ValidationConfig,
) -> Option<VoxelPos> {
    let [low, mid, eye] = body_voxels(feet, cfg);
    if low_blocks(voxels, low, feet.y.to_f64(), cfg.bounds.max_y) {
        return Some(low);
    }
    [mid, eye].into_iter().find(|v| voxels.voxel(*v).is_solid())
}

/// The voxels [`body_blocked`] may read at `feet`: the body's and the one
/// above its lowest (when in the world).
pub fn body_reads(feet: FixedVec3, cfg: &ValidationConfig) -> Vec<VoxelPos> {
    let [low, mid, eye] = body_voxels(feet, cfg);
    let over = VoxelPos::new(low.x, low.y.saturating_add(1), low.z);
    let over = (over.y <= cfg.bounds.max_y).then_some(over);
    [low, mid, eye].into_iter().chain(over).collect()
}

/// The voxels the body occupies: the first wholly above the feet (judged
/// by [`low_blocks`]), the one nearest a voxel above them, and the eye's
/// (which must not be solid).
pub fn body_voxels(feet: FixedVec3, cfg: &ValidationConfig) -> [VoxelPos; 3] {
    body_at(to_dvec3(feet), cfg)
}

/// [`body_voxels`] of feet at any point (a point of a move's path).
pub fn body_at(feet: DVec3, cfg: &ValidationConfig) -> [VoxelPos; 3] {
    [
        nearest_voxel(feet + DVec3::Y * BODY_LOW),
        nearest_voxel(feet + DVec3::Y),
        nearest_voxel(feet + DVec3::Y * cfg.eye_height),
    ]
}

/// A first report (a player the server does not remember) is open to the
/// sky: no solid voxel above the eye up to the world's top (at most
/// [`MAX_SKY_CHUNKS`] rows above the eye's), so a new player appears on
/// the surface, never inside a sealed room or cave beneath it
/// (`PathBlocked` at the lowest such voxel). `path` as for the sweep: a
/// cluster node does not judge another node's regions.
fn open_sky(
    feet: FixedVec3,
    cfg: &ValidationConfig,
    path: &impl VoxelRead,
) -> Result<(), PositionReject> {
    let [.., eye] = body_voxels(feet, cfg);
    let top = sky_top(eye, cfg);
    for y in eye.y.saturating_add(1)..=top {
        let v = VoxelPos::new(eye.x, y, eye.z);
        if path.voxel(v).is_solid() {
            return Err(PositionReject::PathBlocked { voxel: v });
        }
    }
    Ok(())
}

/// The highest voxel [`open_sky`] reads above `eye`.
fn sky_top(eye: VoxelPos, cfg: &ValidationConfig) -> i32 {
    let rows_up =
        (eye.chunk().y + MAX_SKY_CHUNKS) as i64 * CHUNK_SIZE as i64 + CHUNK_SIZE as i64 - 1;
    (cfg.bounds.max_y as i64).min(rows_up) as i32
}

/// The chunks [`open_sky`] reads above `feet`: the eye's column, up to the
/// world's top row (at most [`MAX_SKY_CHUNKS`] rows above the eye's).
pub fn sky_chunks(feet: FixedVec3, cfg: &ValidationConfig) -> impl Iterator<Item = ChunkPos> {
    let [.., eye] = body_voxels(feet, cfg);
    let from = eye.chunk();
    let top = match cfg.spawn.open_sky {
        true => sky_top(eye, cfg).div_euclid(CHUNK_SIZE),
        false => from.y - 1,
    };
    (from.y..=top).map(move |y| ChunkPos::new(from.x, y, from.z))
}

fn in_bounds(feet: FixedVec3, cfg: &ValidationConfig) -> bool {
    feet.in_coord_range()
        && body_voxels(feet, cfg)
            .iter()
            .chain([&nearest_voxel(to_dvec3(feet))])
            .all(|v| cfg.bounds.contains_y(v.y))
}

/// The distance speed allows in `elapsed_ms`, without the slack.
fn speed_distance(elapsed_ms: u64, cfg: &ValidationConfig) -> f64 {
    cfg.max_speed * (elapsed_ms as f64 / 1000.0) * (1.0 + cfg.speed_slack_factor)
}

/// The slack `prev` left, refilled for `elapsed_ms`, in thousandths of a voxel.
fn slack_available(prev: &ValidatedPosition, elapsed_ms: u64, cfg: &ValidationConfig) -> u64 {
    let full = full_slack_milli(cfg);
    let refill = full.saturating_mul(elapsed_ms) / SLACK_REFILL_MS;
    prev.slack_milli.saturating_add(refill).min(full)
}

/// The rules that need no terrain: order, bounds and speed against the
/// previous validated position. Run before any chunk is loaded. Returns
/// the slack the move leaves ([`ValidatedPosition::slack_milli`]): a move
/// may go as far as speed allows since the previous report plus the slack
/// left, and what it goes beyond speed is spent from the slack.
pub fn check_motion(
    prev: Option<&ValidatedPosition>,
    upd: &PositionUpdate,
    now_ms: u64,
    cfg: &ValidationConfig,
) -> Result<u64, PositionReject> {
    if let Some(p) = prev {
        if upd.seq <= p.seq {
            return Err(PositionReject::Stale {
                seq: upd.seq,
                last: p.seq,
            });
        }
    }
    if !in_bounds(upd.pos, cfg) {
        return Err(PositionReject::OutOfBounds);
    }
    let Some(p) = prev else {
        // A player the server does not remember appears in the spawn area.
        let spawn = cfg.spawn;
        if !spawn.start().admits_column(upd.pos) {
            return Err(PositionReject::OutsideSpawn {
                x: spawn.x,
                z: spawn.z,
                radius: spawn.radius,
            });
        }
        return Ok(full_slack_milli(cfg));
    };
    let elapsed = p.credited_ms(now_ms, cfg);
    let d = to_dvec3(p.feet).distance(to_dvec3(upd.pos));
    let speed = speed_distance(elapsed, cfg);
    let slack = slack_available(p, elapsed, cfg);
    // Its path is swept: bounded whatever the config says.
    let allowed = (speed + slack as f64 / 1000.0).min(MAX_SWEPT_MOVE);
    if d > allowed {
        return Err(PositionReject::TooFast {
            distance: d,
            allowed,
        });
    }
    let spent = ((d - speed).max(0.0) * 1000.0).ceil() as u64;
    Ok(slack.saturating_sub(spent))
}

/// Checks a report against the previous validated position (none when the
/// server does not remember the player: then any in-bounds position in the
/// spawn area not inside solid terrain is fine). `path` is the terrain the
/// way there is swept through (`voxels`, or less of it where this node's
/// copies may be stale). `ground` says which voxels are solid for the
/// gravity rule ([`gravity::ground`]; `None` for a voxel this node does not
/// judge), `None` when the rule does not hold the player (an admin, or
/// `[validation.gravity]` off).
pub fn check(
    prev: Option<&ValidatedPosition>,
    upd: &PositionUpdate,
    now_ms: u64,
    cfg: &ValidationConfig,
    voxels: &impl VoxelRead,
    path: &impl VoxelRead,
    ground: Option<impl Fn(VoxelPos) -> Option<bool>>,
) -> Result<ValidatedPosition, PositionReject> {
    let slack_milli = check_motion(prev, upd, now_ms, cfg)?;
    if let Some(voxel) = body_blocked(voxels, upd.pos, cfg) {
        return Err(PositionReject::InsideSolid { voxel });
    }
    if prev.is_none() && cfg.spawn.open_sky {
        open_sky(upd.pos, cfg, path)?;
    }
    // A state placed without a report (a resume, an arrival) is settled
    // from the ground at its spot first: the way's hops are held to it too.
    let prev_air = prev.map(|p| match (&ground, p.air) {
        (Some(solid), Air::Unsettled) => {
            gravity::settled(p.feet, gravity::ground(p.feet, solid), &cfg.gravity)
        }
        (_, air) => air,
    });
    if let Some(p) = prev {
        // Held to the ground, no hop over a wall goes above the apex.
        let apex = ground.is_some().then(|| {
            let air = prev_air.unwrap_or(p.air);
            gravity::hop_ceiling(air, p.feet, &cfg.gravity, now_ms)
        });
        sweep::check(p.feet, upd.pos, cfg, path, apex)?;
    }
    let air = match ground {
        Some(solid) => {
            // An arrival's first report may have walked up a slope since
            // its spot: as far up as across.
            let climb = prev.filter(|p| p.grace_ms > 0).map_or(0.0, |p| {
                let d = to_dvec3(upd.pos) - to_dvec3(p.feet);
                d.x.hypot(d.z)
            });
            let under = gravity::ground(upd.pos, &solid);
            gravity::check(
                prev.zip(prev_air).map(|(p, air)| (air, p.feet)),
                upd.pos,
                under,
                || prev.map_or(gravity::Ground::None, |p| gravity::ground(p.feet, &solid)),
                climb,
                &cfg.gravity,
                |base| {
                    let (Some(p), gravity::Ground::Top(top)) = (prev, under) else {
                        return None;
                    };
                    let eye = cfg.eye_height;
                    gravity::walked_base(p.feet, upd.pos, top, base, eye, &solid, &cfg.gravity)
                },
                now_ms,
            )?
        }
        None => Air::Free,
    };
    Ok(ValidatedPosition {
        feet: upd.pos,
        at_ms: now_ms,
        seq: upd.seq,
        slack_milli,
        placement: Placement::Reported,
        known_ms: now_ms,
        heard_ms: now_ms,
        credit_ms: 0,
        grace_ms: 0,
        air,
    })
}

#[cfg(test)]
mod tests {
    use strata_terrain::Voxel;

    use super::*;

    /// Smooth terrain whose surface is `y = slope * x + 0.74` (a
    /// generator's density ramp: 128 at the surface, 48 a voxel), and a
    /// wall of whole voxels at x = 40 with a one-voxel window at y = 30.
    struct Slope(f64);

    impl VoxelRead for Slope {
        fn voxel(&self, p: VoxelPos) -> Voxel {
            if p.x == 40 {
                return if p.y == 30 {
                    Voxel::AIR
                } else {
                    Voxel::solid(1)
                };
            }
            let h = self.0 * f64::from(p.x) + 0.74;
            let d = (128.0 + 48.0 * (h - f64::from(p.y))).clamp(0.0, 255.0);
            Voxel::new(d as u8, 1)
        }
    }

    /// Feet on the surface of slopes up to 45° stand wherever they are
    /// across a voxel (the body's column is the nearest, up to half a
    /// voxel uphill); feet under a window's sill do not.
    #[test]
    fn feet_on_a_slope_stand_and_feet_sunk_under_a_sill_do_not() {
        let cfg = ValidationConfig::default();
        for slope in [0.18, 0.577, 1.0] {
            let world = Slope(slope);
            for i in 0..400 {
                let x = 5.0 + f64::from(i) * 0.0625;
                let y = slope * x + 0.74;
                let feet = FixedVec3::from_f64([x, y, 0.3]).unwrap();
                assert_eq!(
                    body_blocked(&world, feet, &cfg),
                    None,
                    "slope {slope} at {x}, {y}"
                );
            }
        }
        // The wall: solid at y = 29 and from 31, air at 30. Feet 0.25
        // under the sill's top voxel (its surface at 29.5) are 0.75 below
        // it: the window is no room for a body.
        let world = Slope(0.0);
        let sunk = FixedVec3::from_f64([40.0, 28.75, 0.0]).unwrap();
        assert_eq!(
            body_blocked(&world, sunk, &cfg),
            Some(VoxelPos::new(40, 29, 0))
        );
        // Standing on the sill, the head is in the wall above it.
        let low = FixedVec3::from_f64([40.0, 29.0, 0.0]).unwrap();
        assert_eq!(
            body_blocked(&world, low, &cfg),
            Some(VoxelPos::new(40, 31, 0))
        );
    }
}
