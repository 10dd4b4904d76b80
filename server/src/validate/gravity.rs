//! Gravity: a player's feet stay near the ground. Off it, they rise no
//! higher than a jump from where they last stood, and a report standing
//! on something is no more than a jump above the last one. Else a client
//! could report its way up, over any wall the path rule stops, and down
//! again. Admins are not held to it.

use serde::{Deserialize, Serialize};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{ChunkPos, VoxelPos};

use super::position::PositionReject;

/// Default height the feet may rise above the last ground they stood on,
/// in voxels: a jump, or a step onto a ledge between two reports.
pub const DEFAULT_JUMP_VOXELS: f64 = 4.0;
/// Largest `jump_voxels` a config may set.
pub const MAX_JUMP_VOXELS: f64 = 256.0;
/// Default time a player may stay off the ground at its apex before it
/// must sink, in ms: a whole jump, up and across, with room to spare.
pub const DEFAULT_HANG_MS: u64 = 1_500;
/// Largest `hang_ms` a config may set.
pub const MAX_HANG_MS: u64 = 600_000;
/// Default fall the limits assume past the hang, in voxels per second
/// squared: well below any game's gravity (an honest fall is faster), so
/// only a player that does not come down at all is refused.
pub const DEFAULT_FALL_VOXELS_PER_S2: f64 = 8.0;
/// Least and most `fall_voxels_per_s2` a config may set.
pub const FALL_RANGE: (f64, f64) = (0.1, 1_000.0);
/// Most a fall lowers the limits, in voxels: far below any world.
const MAX_SINK_VOXELS: f64 = 1_048_576.0;

/// How far below the feet a ground voxel may lie, in voxels: feet a
/// little above the surface (a bot's stand on the top voxel's top, a
/// client's capsule) still stand.
pub const GROUND_REACH: f64 = 2.5;
/// How far into the ground the feet may have sunk, in voxels.
pub const GROUND_SINK: f64 = 0.5;
/// How far above the top voxel of the ground feet may stand and jump
/// from there, in voxels: a client's feet on the surface between that
/// voxel and the one above, or a voxel over it (the bots stand on the top
/// voxel's top). Feet reported higher, within [`GROUND_REACH`], still
/// stand but jump from here.
pub const JUMP_BASE: i32 = 2;

/// `[validation.gravity]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GravityConfig {
    /// Whether players are held to the ground at all (a game whose
    /// players fly turns it off).
    pub enabled: bool,
    /// See [`DEFAULT_JUMP_VOXELS`].
    pub jump_voxels: f64,
    /// See [`DEFAULT_HANG_MS`].
    pub hang_ms: u64,
    /// See [`DEFAULT_FALL_VOXELS_PER_S2`].
    pub fall_voxels_per_s2: f64,
}

impl Default for GravityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            jump_voxels: DEFAULT_JUMP_VOXELS,
            hang_ms: DEFAULT_HANG_MS,
            fall_voxels_per_s2: DEFAULT_FALL_VOXELS_PER_S2,
        }
    }
}

impl GravityConfig {
    fn jump(&self) -> i32 {
        Fixed::from_f64(self.jump_voxels).map_or(0, |f| f.0)
    }

    /// How far the limits of a player off the ground since `since` have
    /// sunk at `now_ms` (raw fixed-point): nothing for [`Self::hang_ms`],
    /// then a fall at [`Self::fall_voxels_per_s2`].
    fn sink(&self, since: u64, now_ms: u64) -> i32 {
        let falling = now_ms.saturating_sub(since).saturating_sub(self.hang_ms);
        let t = falling as f64 / 1000.0;
        let voxels = (0.5 * self.fall_voxels_per_s2 * t * t).min(MAX_SINK_VOXELS);
        Fixed::from_f64(voxels).map_or(0, |f| f.0)
    }
}

/// How high a player's next report may be, after an accepted one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Air {
    /// Not held to the ground (an admin, or the rule off).
    Free,
    /// Placed without a report (a resume, an arrival), or last seen over
    /// ground this node does not judge: settled at the next report from
    /// the ground at the spot ([`check`]).
    Unsettled,
    Limits {
        /// The highest feet off the ground may be: a jump above the ground
        /// they last stood on, lowered to where a fall began.
        apex: Fixed,
        /// The highest feet standing on something may be: the apex, or a
        /// jump above the spot when a jump was not known to be spent.
        step: Fixed,
        /// Off the ground: when the first report there came (ms), and the
        /// apex then. Past `hang_ms` no report is higher than that apex
        /// less a fall from it (`GravityConfig::sink`), so no player
        /// hovers; `None` while the last report stood.
        aloft: Option<Aloft>,
    },
}

/// When a player left the ground, as [`Air::Limits`] holds it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Aloft {
    /// The first report off the ground (ms).
    pub since: u64,
    /// The apex then: the height a fall past the hang is counted from.
    pub top: Fixed,
}

impl Aloft {
    /// The highest feet may be at `now_ms`: `top` less the fall past the
    /// hang.
    fn ceiling(self, now_ms: u64, cfg: &GravityConfig) -> Fixed {
        add(self.top, -cfg.sink(self.since, now_ms))
    }
}

/// What lies under feet: the top of the ground (`y` of its highest solid
/// voxel with a non-solid one above, within reach), none, or terrain this
/// node does not judge (another cluster node's region).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ground {
    Top(i32),
    None,
    Unknown,
}

fn add(y: Fixed, d: i32) -> Fixed {
    Fixed(y.0.saturating_add(d))
}

impl Air {
    /// Standing at `feet` on ground whose top is `top`: a jump above the
    /// lower of the feet and [`JUMP_BASE`] above the top (feet reported
    /// up to the ground's reach above it gain nothing more).
    pub fn stood(feet: FixedVec3, top: i32, cfg: &GravityConfig) -> Self {
        let y = jump_from(feet, top, cfg);
        Air::Limits {
            apex: y,
            step: y,
            aloft: None,
        }
    }
}

/// The limits of a player placed without a report (a resume, an
/// arrival) at `last`, over `ground`: a jump above the ground it stands
/// on; in the air, no higher than it is (a reconnect is no fresh jump, nor
/// a step up onto a ledge); over ground another node judges, it may stand
/// a jump higher (its ground may lie over there), not rise off the ground.
pub fn settled(last: FixedVec3, ground: Ground, cfg: &GravityConfig) -> Air {
    let (apex, step) = settled_limits(last, ground, cfg);
    Air::Limits {
        apex,
        step,
        aloft: None,
    }
}

/// [`settled`]'s apex and step.
fn settled_limits(last: FixedVec3, ground: Ground, cfg: &GravityConfig) -> (Fixed, Fixed) {
    match ground {
        Ground::Top(top) => {
            let y = jump_from(last, top, cfg);
            (y, y)
        }
        Ground::None => (last.y, last.y),
        Ground::Unknown => (last.y, add(last.y, cfg.jump())),
    }
}

/// The highest the feet of a path's hop may go from `last` in state `air`
/// at `now_ms`: the apex (sunk, off the ground), or a jump above an
/// unsettled spot.
pub fn hop_ceiling(air: Air, last: FixedVec3, cfg: &GravityConfig, now_ms: u64) -> f64 {
    match air {
        Air::Limits { apex, aloft, .. } => {
            let ceiling = aloft.map_or(apex, |a| a.ceiling(now_ms, cfg));
            apex.min(ceiling).to_f64()
        }
        Air::Free | Air::Unsettled => add(last.y, cfg.jump()).to_f64(),
    }
}

/// A jump above the lower of `feet` and [`JUMP_BASE`] above `top`.
fn jump_from(feet: FixedVec3, top: i32, cfg: &GravityConfig) -> Fixed {
    let base = top.saturating_add(JUMP_BASE);
    let base = Fixed(base.saturating_mul(strata_terrain::edit::fixed::ONE));
    add(feet.y.min(base), cfg.jump())
}

/// The voxels whose solidity decides whether feet at `feet` stand: in the
/// four columns around the feet (those within a voxel on x and z), from
/// [`GROUND_REACH`] below the feet to [`GROUND_SINK`] above them, each with
/// the voxel above it.
fn columns(feet: FixedVec3) -> (std::ops::RangeInclusive<i32>, [(i32, i32); 4]) {
    let [x, y, z] = feet.to_f64();
    let (x0, z0) = (x.floor() as i32, z.floor() as i32);
    let lowest = (y - GROUND_REACH).ceil() as i32;
    let highest = (y + GROUND_SINK).floor() as i32;
    let cols = [(x0, z0), (x0 + 1, z0), (x0, z0 + 1), (x0 + 1, z0 + 1)];
    (lowest..=highest, cols)
}

/// The ground under feet at `feet` (see [`columns`]): the highest top of
/// the ground among them (solid with non-solid above; a wall's face is no
/// ground). `solid` answers `None` for a voxel this node does not judge:
/// then the ground is [`Ground::Unknown`].
pub fn ground(feet: FixedVec3, solid: impl Fn(VoxelPos) -> Option<bool>) -> Ground {
    let (ys, cols) = columns(feet);
    match highest_top(cols, ys, &solid) {
        Some(Some(top)) => Ground::Top(top),
        Some(None) => Ground::None,
        None => Ground::Unknown,
    }
}

/// The highest top of the ground in columns `cols` between `ys` (a solid
/// voxel there with a non-solid one above), if any; `None` when a voxel
/// read is one this node does not judge.
fn highest_top(
    cols: [(i32, i32); 4],
    ys: std::ops::RangeInclusive<i32>,
    solid: &impl Fn(VoxelPos) -> Option<bool>,
) -> Option<Option<i32>> {
    let mut top = None;
    for (x, z) in cols {
        let mut above = solid(VoxelPos::new(x, ys.end().saturating_add(1), z));
        for y in ys.clone().rev() {
            let here = solid(VoxelPos::new(x, y, z));
            match (here, above) {
                (None, _) | (_, None) => return None,
                (Some(true), Some(false)) => {
                    top = top.max(Some(y));
                    break;
                }
                _ => {}
            }
            above = here;
        }
    }
    Some(top)
}

/// The chunks [`ground`] may read for feet at `feet`.
pub fn chunks(feet: FixedVec3) -> Vec<ChunkPos> {
    let (ys, cols) = columns(feet);
    let mut out: Vec<ChunkPos> = Vec::with_capacity(4);
    for (x, z) in cols {
        for y in [*ys.start(), ys.end() + 1] {
            let c = VoxelPos::new(x, y, z).chunk();
            if !out.contains(&c) {
                out.push(c);
            }
        }
    }
    out
}

/// Farthest a standing report above the step may be caught up along the
/// ground ([`walked_base`]), across and up, in voxels: a client whose
/// reports were lost for a few seconds while it climbed.
pub const CATCH_UP_VOXELS: f64 = 32.0;
/// Longest step between two points of a catch-up walk, in voxels: a point
/// in each column the way crosses.
const CATCH_UP_STEP: f64 = 0.5;
/// How far below the lower end's ground a catch-up walk may go down, in
/// voxels (a dip between two reports).
pub const CATCH_UP_DIP: i32 = 4;

type Column = (i32, i32);

/// A catch-up walk from one report to the next: the body's column at
/// each point across (the start's first and the end's last, at most
/// [`CATCH_UP_STEP`] apart), the heights it looks for ground in, and the
/// highest voxel it may read.
struct Walk {
    columns: Vec<Column>,
    ground: std::ops::RangeInclusive<i32>,
    ceiling: i32,
}

/// The body's column at `x`, `z`: that of its voxels (nearest, as the
/// position rule's).
fn body_column(x: f64, z: f64) -> Column {
    ((x + 0.5).floor() as i32, (z + 0.5).floor() as i32)
}

/// The [`Walk`] from `from` to `to` for a body `eye` high, or `None` for a
/// move too long to be caught up.
fn walk_points(from: FixedVec3, to: FixedVec3, eye: f64) -> Option<Walk> {
    let ([ax, ay, az], [bx, by, bz]) = (from.to_f64(), to.to_f64());
    let across = (bx - ax).hypot(bz - az);
    if !(across <= CATCH_UP_VOXELS && by - ay <= CATCH_UP_VOXELS) {
        return None;
    }
    let n = (across / CATCH_UP_STEP).ceil().max(1.0) as u32;
    let columns = (0..=n)
        .map(|i| {
            let t = f64::from(i) / f64::from(n);
            body_column(ax + (bx - ax) * t, az + (bz - az) * t)
        })
        .collect();
    let lowest = (ay.min(by) - GROUND_REACH).ceil() as i32 - CATCH_UP_DIP;
    let highest = (by + GROUND_SINK).floor() as i32;
    let ceiling = (ay.max(by) + GROUND_SINK).floor() as i32 + 2 + eye.max(0.0).ceil() as i32;
    Some(Walk {
        columns,
        ground: lowest..=highest,
        ceiling,
    })
}

/// Most tops of the ground a catch-up walk keeps at each point, the
/// highest: the ways over and under a slab or a bridge are both followed.
pub const CATCH_UP_TOPS: usize = 4;

/// Walks the ground from `from`, where a jump may start at `base`, toward
/// `to` (feet over ground whose top is `top`), as a body `eye` high. It
/// starts on the highest top within the held feet's reach in the body's
/// column with room for the body (none, in the air: no walk). At each
/// point of the way it keeps the tops of the ground in the body's column
/// (the highest [`CATCH_UP_TOPS`]; never above `to`'s feet, down to
/// [`CATCH_UP_DIP`] below the lower end) with room for the body above,
/// that a top kept at the last point reaches: a jump up at most, with
/// room on the way (up in the last column, or across and down in this
/// one; round a corner, through one of the two columns beside it). Returns
/// where a jump may start at the last point, from the best of those that
/// reach `to`'s ground the same way, or `None` where none does, a voxel
/// read is one this node does not judge, or the way is too long
/// ([`CATCH_UP_VOXELS`]). So a standing report no higher than a jump above
/// that is one a player could have walked to and jumped, each step at most
/// a jump up, never through a wall, floor or ceiling.
pub fn walked_base(
    from: FixedVec3,
    to: FixedVec3,
    top: i32,
    base: f64,
    eye: f64,
    solid: impl Fn(VoxelPos) -> Option<bool>,
    cfg: &GravityConfig,
) -> Option<f64> {
    let walk = walk_points(from, to, eye)?;
    let (first, rest) = walk.columns.split_first()?;
    let (last, between) = rest.split_last()?;
    let step = Step {
        solid: &solid,
        head: eye.max(0.0).floor() as i32 + 1,
    };
    let jump = cfg.jump_voxels;
    let reach = |b: f64| (b + jump + GROUND_SINK).floor() as i32;
    let ay = from.y.to_f64();
    let held = (ay - GROUND_REACH).ceil() as i32..=(ay + GROUND_SINK).floor() as i32;
    let start = *step.tops(*first, held)?.first()?;
    let (mut kept, mut prev) = (vec![(start, base)], *first);
    for &col in between {
        let highest = kept.iter().map(|&(_, b)| reach(b)).max()?;
        let mut next = Vec::with_capacity(CATCH_UP_TOPS);
        for t in step.tops(col, *walk.ground.start()..=highest.min(*walk.ground.end()))? {
            let mut best: Option<f64> = None;
            for &(s, b) in &kept {
                if t <= reach(b) && step.moves((prev, s), (col, t))? {
                    let b = (b + jump).min(f64::from(t.saturating_add(JUMP_BASE)));
                    best = Some(best.map_or(b, |x| x.max(b)));
                }
            }
            if let Some(b) = best {
                next.push((t, b));
                if next.len() == CATCH_UP_TOPS {
                    break;
                }
            }
        }
        if next.is_empty() {
            return None;
        }
        (kept, prev) = (next, col);
    }
    // The last leg, onto the report's ground.
    if !step.room(*last, top)? {
        return None;
    }
    let mut best: Option<f64> = None;
    for &(s, b) in &kept {
        if step.moves((prev, s), (*last, top))? {
            best = Some(best.map_or(b, |x| x.max(b)));
        }
    }
    best
}

/// Room checks of a catch-up walk: `head` voxels above a top the body
/// needs free.
struct Step<'a, F> {
    solid: &'a F,
    head: i32,
}

impl<F: Fn(VoxelPos) -> Option<bool>> Step<'_, F> {
    fn solid(&self, (x, z): Column, y: i32) -> Option<bool> {
        (self.solid)(VoxelPos::new(x, y, z))
    }

    /// Whether column `col` is free from `low` to `high`.
    fn free(&self, col: Column, low: i32, high: i32) -> Option<bool> {
        for y in low..=high {
            if self.solid(col, y)? {
                return Some(false);
            }
        }
        Some(true)
    }

    /// Whether a body standing on top `t` of column `col` has room.
    fn room(&self, col: Column, t: i32) -> Option<bool> {
        self.free(col, t.saturating_add(1), t.saturating_add(self.head))
    }

    /// The tops of the ground in `col` between `ys` with room for the
    /// body above, the highest first.
    fn tops(&self, col: Column, ys: std::ops::RangeInclusive<i32>) -> Option<Vec<i32>> {
        let mut out = Vec::new();
        let mut above = self.solid(col, ys.end().saturating_add(1))?;
        for y in ys.rev() {
            let here = self.solid(col, y)?;
            if here && !above && self.room(col, y)? {
                out.push(y);
            }
            above = here;
        }
        Some(out)
    }

    /// Whether a body standing on top `a.1` in column `a.0` may go to
    /// top `b.1` in the next column `b.0` (which has room for it): up in
    /// its own column first, or across at its height and down.
    fn moves(&self, (ac, at): (Column, i32), (bc, bt): (Column, i32)) -> Option<bool> {
        let up = at.max(bt);
        let head = up.saturating_add(self.head);
        let room = if bt > at {
            self.free(ac, at.saturating_add(1), head)?
        } else {
            self.free(bc, bt.saturating_add(1), head)?
        };
        if !room || (ac.0 == bc.0 || ac.1 == bc.1) {
            return Some(room);
        }
        // Round a corner: through one of the columns beside it, at the
        // height the body crosses.
        let low = up.saturating_add(1);
        Some(self.free((ac.0, bc.1), low, head)? || self.free((bc.0, ac.1), low, head)?)
    }
}

/// Whether a report at `feet` after one at `last` in state `air` may need
/// a catch-up walk ([`walked_base`]): above the step (for a placed
/// player, at least a jump above its spot less the half voxel its feet
/// may be above their ground's reach).
pub fn may_walk(air: Air, last: FixedVec3, feet: FixedVec3, cfg: &GravityConfig) -> bool {
    match air {
        Air::Limits { step, .. } => feet.y > step,
        Air::Unsettled => feet.y > add(last.y, cfg.jump() - strata_terrain::edit::fixed::ONE),
        Air::Free => false,
    }
}

/// The chunks [`walked_base`] may read from `from` to `to` for a body
/// `eye` high.
pub fn walk_chunks(from: FixedVec3, to: FixedVec3, eye: f64) -> Vec<ChunkPos> {
    let Some(walk) = walk_points(from, to, eye) else {
        return Vec::new();
    };
    let (low, high) = (*walk.ground.start(), walk.ceiling);
    let mut out: Vec<ChunkPos> = Vec::new();
    for pair in walk.columns.windows(2) {
        let ((ax, az), (bx, bz)) = (pair[0], pair[1]);
        for (x, z) in [(ax, az), (bx, bz), (ax, bz), (bx, az)] {
            let mut y = low;
            loop {
                let c = VoxelPos::new(x, y.min(high), z).chunk();
                if !out.contains(&c) {
                    out.push(c);
                }
                if y >= high {
                    break;
                }
                y = y.saturating_add(strata_terrain::CHUNK_SIZE);
            }
        }
    }
    out
}

/// Checks a report of `feet` over `under` against `prev`, the state after
/// the last accepted report at `last` (none for a first position).
/// `settle` is the ground at `last`, read only when `prev` is
/// [`Air::Unsettled`]. Standing, the feet may be up to the step (`climb`
/// more: an arrival's first report, for the slope it may have walked up);
/// off the ground, up to the apex, and a fall lowers the apex to where it
/// began. A standing report above the step is still fine when `walk`,
/// given where the step's jump starts, finds ground the player could have
/// walked to from there ([`walked_base`]) a jump below the feet: reports
/// lost on the way up a slope. Over ground this node does not judge,
/// nothing is checked and the state is unsettled again. Off the ground,
/// both limits sink after the hang (`now_ms` against [`Aloft`]).
// The rule's inputs, each read lazily or not at all: no struct of them
// would be reused.
#[allow(clippy::too_many_arguments)]
pub fn check(
    prev: Option<(Air, FixedVec3)>,
    feet: FixedVec3,
    under: Ground,
    settle: impl FnOnce() -> Ground,
    climb: f64,
    cfg: &GravityConfig,
    walk: impl FnOnce(f64) -> Option<f64>,
    now_ms: u64,
) -> Result<Air, PositionReject> {
    if under == Ground::Unknown {
        return Ok(Air::Unsettled);
    }
    let (apex, step, last, aloft) = match prev {
        // A first position: anywhere in the spawn square, then as placed.
        None => match under {
            Ground::Top(top) => return Ok(Air::stood(feet, top, cfg)),
            _ => {
                return Ok(Air::Limits {
                    apex: feet.y,
                    step: feet.y,
                    aloft: Some(Aloft {
                        since: now_ms,
                        top: feet.y,
                    }),
                })
            }
        },
        Some((Air::Limits { apex, step, aloft }, last)) => (apex, step, last, aloft),
        Some((Air::Free | Air::Unsettled, last)) => {
            let (apex, step) = settled_limits(last, settle(), cfg);
            (apex, step, last, None)
        }
    };
    // Off the ground since the first report there (a player whose last
    // report stood may have stood until now): no higher than a fall from
    // the apex then allows.
    let ceiling = aloft.map(|a| a.ceiling(now_ms, cfg));
    let (apex_now, step_now) = match ceiling {
        Some(c) => (apex.min(c), step.min(c)),
        None => (apex, step),
    };
    let more = Fixed::from_f64(climb.max(0.0)).map_or(i32::MAX, |f| f.0);
    let limit = match under {
        Ground::Top(_) => add(step_now, more),
        _ => apex_now,
    };
    if feet.y > limit {
        let base = add(step, -cfg.jump()).to_f64();
        let walked = matches!(under, Ground::Top(_))
            && walk(base).is_some_and(|b| feet.y.to_f64() <= b + cfg.jump_voxels);
        if !walked {
            return Err(PositionReject::TooHigh {
                apex: limit.to_f64(),
            });
        }
    }
    Ok(match under {
        Ground::Top(top) => Air::stood(feet, top, cfg),
        _ => {
            // A fall lowers the apex to where it began; the clock and the
            // apex it counts a fall from stay as the first report off the
            // ground set them.
            let apex = if feet.y < last.y {
                apex.min(last.y)
            } else {
                apex
            };
            Air::Limits {
                apex,
                step: apex,
                aloft: Some(aloft.unwrap_or(Aloft {
                    since: now_ms,
                    top: apex,
                })),
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(y: f64) -> FixedVec3 {
        FixedVec3::from_f64([10.5, y, 10.5]).unwrap()
    }

    /// Ground: solid at and below y = 0 in every column; a wall at x = 12
    /// up to y = 20.
    fn world(v: VoxelPos) -> Option<bool> {
        Some(v.y <= 0 || (v.x == 12 && v.y <= 20))
    }

    fn none() -> Ground {
        panic!("not read")
    }

    fn no_walk(_: f64) -> Option<f64> {
        None
    }

    /// [`check`] with the default config, nothing to settle, no climb and
    /// no walk.
    fn plain(
        prev: Option<(Air, FixedVec3)>,
        feet: FixedVec3,
        under: Ground,
    ) -> Result<Air, PositionReject> {
        check(
            prev,
            feet,
            under,
            none,
            0.0,
            &GravityConfig::default(),
            no_walk,
            0,
        )
    }

    fn limits(apex: f64, step: f64) -> Air {
        Air::Limits {
            apex: Fixed::from_f64(apex).unwrap(),
            step: Fixed::from_f64(step).unwrap(),
            aloft: None,
        }
    }

    /// [`limits`] off the ground since `since`, a fall counted from `top`.
    fn aloft_since(apex: f64, step: f64, since: u64, top: f64) -> Air {
        match limits(apex, step) {
            Air::Limits { apex, step, .. } => Air::Limits {
                apex,
                step,
                aloft: Some(Aloft {
                    since,
                    top: Fixed::from_f64(top).unwrap(),
                }),
            },
            other => other,
        }
    }

    /// Off the ground, the limits hold for `hang_ms` from the first report
    /// there, then sink as a fall: a player that stays up (hovering, or
    /// running across a chasm on air) is refused; one that comes down, or
    /// stands again, is not; standing, nothing sinks however long.
    #[test]
    fn off_the_ground_the_limits_sink_after_the_hang() {
        let cfg = GravityConfig::default();
        let (hang, g) = (cfg.hang_ms, cfg.fall_voxels_per_s2);
        let report = |prev, y: f64, under, now| {
            check(
                Some((prev, at(4.0))),
                at(y),
                under,
                none,
                0.0,
                &cfg,
                no_walk,
                now,
            )
        };
        // Up from the ground at 1 to the apex at 5: the first report off
        // the ground starts the clock.
        let stood = limits(5.0, 5.0);
        let up = report(stood, 5.0, Ground::None, 10_000).unwrap();
        assert_eq!(up, aloft_since(5.0, 5.0, 10_000, 5.0));
        // At the apex to the end of the hang, not a moment past it.
        assert!(report(up, 5.0, Ground::None, 10_000 + hang).is_ok());
        let late = 10_000 + hang + 1_000;
        let sunk = 5.0 - 0.5 * g;
        assert_eq!(
            report(up, 5.0, Ground::None, late),
            Err(PositionReject::TooHigh { apex: sunk })
        );
        assert!(report(up, sunk, Ground::None, late).is_ok());
        // Nor standing on a ledge at the apex, after hanging that long.
        assert!(report(up, 5.0, Ground::Top(4), late).is_err());
        // Standing again: nothing sinks, however long it stands.
        let landed = report(up, 1.0, Ground::Top(0), late).unwrap();
        assert_eq!(landed, limits(5.0, 5.0));
        assert!(report(landed, 5.0, Ground::None, late + 60_000).is_ok());
        // Falling, the state keeps the apex lowered to where the fall
        // began, unsunk, and the clock's start.
        assert_eq!(
            report(up, 3.0, Ground::None, 10_000 + hang + 500),
            Ok(aloft_since(4.0, 4.0, 10_000, 5.0))
        );
    }

    /// A long honest fall, slower than any game's, is never refused, nor
    /// the landing and the reports after it: a fall is counted once, from
    /// the apex when the player left the ground.
    #[test]
    fn a_long_fall_and_its_landing_are_never_refused() {
        let cfg = GravityConfig::default();
        let (g, start) = (9.8, 60.0);
        let mut state = plain(None, at(start), Ground::None).unwrap();
        let mut last = at(start);
        let mut landed = false;
        for i in 1..=200u64 {
            let t = i as f64 * 0.05;
            let y = (start - 0.5 * g * t * t).max(1.0);
            let feet = at(y);
            let under = ground(feet, world);
            let r = check(
                Some((state, last)),
                feet,
                under,
                none,
                0.0,
                &cfg,
                no_walk,
                i * 50,
            );
            state = r.unwrap_or_else(|e| panic!("at {t:.2} s, y {y:.2}: {e:?}"));
            last = feet;
            landed |= matches!(under, Ground::Top(_));
        }
        assert!(landed);
        assert_eq!(state, limits(5.0, 5.0));
    }

    #[test]
    fn the_ground_is_the_top_of_solid_voxels_within_reach() {
        assert_eq!(ground(at(1.0), world), Ground::Top(0));
        assert_eq!(ground(at(2.5), world), Ground::Top(0), "a little above");
        assert_eq!(ground(at(3.0), world), Ground::None);
        assert_eq!(ground(at(0.5), world), Ground::Top(0), "sunk half a voxel");
        // Beside the wall (its column within a voxel), above the ground:
        // its face is no ground, its top is.
        let beside = |y| FixedVec3::from_f64([11.5, y, 10.5]).unwrap();
        assert_eq!(ground(beside(10.0), world), Ground::None);
        assert_eq!(ground(beside(21.0), world), Ground::Top(20));
        // A voxel this node does not judge.
        let other = |v: VoxelPos| (v.x != 11).then_some(v.y <= 0);
        assert_eq!(ground(at(1.0), other), Ground::Unknown);
    }

    #[test]
    fn off_the_ground_a_jump_high_and_no_climbing_back_after_a_fall() {
        let stood = plain(None, at(1.0), Ground::Top(0)).unwrap();
        assert_eq!(stood, limits(5.0, 5.0));
        // Up to the apex, 4 above the feet; not past it.
        let up = plain(Some((stood, at(1.0))), at(5.0), Ground::None).unwrap();
        assert!(matches!(
            plain(Some((up, at(5.0))), at(5.5), Ground::None),
            Err(PositionReject::TooHigh { apex }) if apex == 5.0
        ));
        // Nor standing on a ledge above it.
        assert!(plain(Some((up, at(5.0))), at(5.5), Ground::Top(4)).is_err());
        // A fall lowers the apex to where it began.
        let down = plain(Some((up, at(5.0))), at(3.0), Ground::None).unwrap();
        assert_eq!(down, aloft_since(5.0, 5.0, 0, 5.0));
        let lower = plain(Some((down, at(3.0))), at(2.8), Ground::None).unwrap();
        assert_eq!(lower, aloft_since(3.0, 3.0, 0, 5.0));
        assert!(plain(Some((lower, at(2.8))), at(3.5), Ground::None).is_err());
        // Standing again: a new jump.
        let landed = plain(Some((lower, at(2.8))), at(1.0), Ground::Top(0));
        assert_eq!(landed, Ok(limits(5.0, 5.0)));
    }

    /// A jump counts from the ground's surface, not from feet reported
    /// up to the reach above it; standing reports climb a jump at a time.
    #[test]
    fn a_jump_is_from_the_ground_and_standing_climbs_a_jump_at_a_time() {
        let cfg = GravityConfig::default();
        assert_eq!(plain(None, at(2.5), Ground::Top(0)), Ok(limits(6.0, 6.0)));
        let mut air = limits(5.0, 5.0);
        let mut last = at(1.0);
        for (y, top) in [(3.0, 2), (6.5, 5), (10.0, 9), (13.5, 12)] {
            air = plain(Some((air, last)), at(y), Ground::Top(top)).unwrap();
            last = at(y);
        }
        assert!(matches!(
            plain(Some((air, last)), at(25.0), Ground::Top(24)),
            Err(PositionReject::TooHigh { apex }) if apex == 17.5
        ));
        // An arrival's climb allowance.
        assert!(check(
            Some((air, last)),
            at(25.0),
            Ground::Top(24),
            none,
            8.0,
            &cfg,
            no_walk,
            0
        )
        .is_ok());
    }

    /// A placed player's state is settled from the ground at its spot:
    /// standing there, a jump; in the air, it may fall, not rise nor stand
    /// higher; over ground another node judges, it may fall or stand a
    /// jump higher, not rise.
    #[test]
    fn a_placed_player_is_settled_from_the_ground_at_its_spot() {
        let cfg = GravityConfig::default();
        let placed = Some((Air::Unsettled, at(1.0)));
        let settle = || Ground::Top(0);
        assert!(check(placed, at(5.0), Ground::None, settle, 0.0, &cfg, no_walk, 0).is_ok());
        let aloft = Some((Air::Unsettled, at(30.0)));
        for (under, stands_higher) in [(Ground::None, false), (Ground::Unknown, true)] {
            let settle = || under;
            assert!(check(aloft, at(30.5), Ground::None, settle, 0.0, &cfg, no_walk, 0).is_err());
            assert!(check(aloft, at(29.0), Ground::None, settle, 0.0, &cfg, no_walk, 0).is_ok());
            let ledge = check(
                aloft,
                at(34.0),
                Ground::Top(33),
                settle,
                0.0,
                &cfg,
                no_walk,
                0,
            );
            assert_eq!(ledge.is_ok(), stands_higher, "{under:?}");
            assert!(check(
                aloft,
                at(34.5),
                Ground::Top(33),
                settle,
                0.0,
                &cfg,
                no_walk,
                0
            )
            .is_err());
            assert_eq!(
                settled(at(30.0), under, &cfg),
                limits(30.0, if stands_higher { 34.0 } else { 30.0 })
            );
        }
        // Over ground this node does not judge: nothing checked.
        let air = || Ground::None;
        assert_eq!(
            check(aloft, at(99.0), Ground::Unknown, air, 0.0, &cfg, no_walk, 0),
            Ok(Air::Unsettled)
        );
        // A first position in the air may only fall.
        assert_eq!(
            plain(None, at(30.0), Ground::None),
            Ok(aloft_since(30.0, 30.0, 0, 30.0))
        );
    }

    /// Stairs east of x = 10: step `k` (x from 10 + 2k - 1 to 10 + 2k) is
    /// solid up to `rise * k - 1`; flat ground (solid to y = 0) elsewhere.
    fn stairs(rise: i32) -> impl Fn(VoxelPos) -> Option<bool> {
        move |v| {
            let k = (v.x - 9).div_euclid(2);
            Some(v.y <= 0 || ((1..=6).contains(&k) && v.y < rise * k))
        }
    }

    fn feet(x: f64, y: f64, z: f64) -> FixedVec3 {
        FixedVec3::from_f64([x, y, z]).unwrap()
    }

    const EYE: f64 = 1.6;

    /// [`walked_base`] from feet 1 on flat ground at x 10.2 (its jump from
    /// there), with the default config.
    fn walk_to(to: FixedVec3, top: i32, world: impl Fn(VoxelPos) -> Option<bool>) -> Option<f64> {
        let cfg = GravityConfig::default();
        walked_base(feet(10.2, 1.0, 10.5), to, top, 1.0, EYE, world, &cfg)
    }

    /// Reports lost on the way up: a standing report above the step is
    /// caught up when ground a jump at a time leads there, not when a
    /// step of the way is higher than a jump.
    #[test]
    fn a_climb_is_caught_up_along_ground_a_jump_at_a_time() {
        let cfg = GravityConfig::default();
        let from = feet(10.2, 1.0, 10.5);
        let stood = plain(None, from, Ground::Top(0)).unwrap();
        // Steps 3 high: the fourth's top is at 11.
        let to = feet(17.3, 12.0, 10.5);
        assert_eq!(
            walk_to(to, 11, stairs(3)),
            Some(13.0),
            "onto the fourth step"
        );
        let walk = |base| walked_base(from, to, 11, base, EYE, stairs(3), &cfg);
        let report = |walk: &dyn Fn(f64) -> Option<f64>| {
            check(
                Some((stood, from)),
                to,
                Ground::Top(11),
                none,
                0.0,
                &cfg,
                walk,
                0,
            )
        };
        assert_eq!(report(&walk), Ok(limits(16.0, 16.0)));
        assert!(matches!(
            report(&no_walk),
            Err(PositionReject::TooHigh { apex }) if apex == 5.0
        ));
        // Steps 7 high: the first is out of a jump's reach. (Steps 6 high
        // are not: feet may stand up to a voxel above a top and jump from
        // there, as report by report.)
        let to = feet(17.3, 28.0, 10.5);
        assert_eq!(walk_to(to, 27, stairs(7)), None);
        assert_eq!(walk_to(feet(17.3, 24.0, 10.5), 23, stairs(6)), Some(23.0));
        // Down into a dip and up the far side; not below the dip.
        let far = feet(17.2, 1.0, 10.5);
        let dip = |v: VoxelPos| Some(v.y <= if (12..=14).contains(&v.x) { -3 } else { 0 });
        assert_eq!(walk_to(far, 0, dip), Some(2.0));
        let pit = |v: VoxelPos| Some(v.y <= if (12..=14).contains(&v.x) { -9 } else { 0 });
        assert_eq!(walk_to(far, 0, pit), None, "below the dip");
        // Too far across, or ground this node does not judge.
        let beyond = feet(10.2 + CATCH_UP_VOXELS + 1.0, 1.0, 10.5);
        assert_eq!(walk_to(beyond, 0, world), None);
        assert!(walk_chunks(from, beyond, EYE).is_empty());
        let other = |v: VoxelPos| (v.x != 14).then_some(v.y <= 0);
        assert_eq!(walk_to(far, 0, other), None);
    }

    #[test]
    fn a_walk_is_read_for_reports_above_the_step() {
        let cfg = GravityConfig::default();
        assert!(!may_walk(limits(5.0, 5.0), at(1.0), at(5.0), &cfg));
        assert!(may_walk(limits(5.0, 5.0), at(1.0), at(5.1), &cfg));
        assert!(!may_walk(Air::Unsettled, at(1.0), at(4.0), &cfg));
        assert!(may_walk(Air::Unsettled, at(1.0), at(4.1), &cfg));
        assert!(!may_walk(Air::Free, at(1.0), at(99.0), &cfg));
    }

    /// The walk needs room for the body: no ground is reached through a
    /// floor above, inside a wall, or round a corner walled on both sides.
    #[test]
    fn a_walk_goes_through_no_floor_wall_or_corner() {
        // A stairless tower's floors (x 13 to 16, at 3, 7, 11, 15): the
        // first is a ledge a jump up, the rest are above it.
        let floors = |v: VoxelPos| {
            Some(v.y <= 0 || ((13..=16).contains(&v.x) && [3, 7, 11, 15].contains(&v.y)))
        };
        assert_eq!(walk_to(feet(16.3, 16.0, 10.5), 15, floors), None);
        assert_eq!(walk_to(feet(16.3, 4.0, 10.5), 3, floors), Some(5.0));
        // A wall (x = 12, up to 19) with rising ground behind it (x = 13):
        // nothing reaches its top, whatever lies beside.
        let rampart = |v: VoxelPos| {
            let behind = v.x == 13 && v.y <= (2 * (v.z - 13)).min(18);
            Some(v.y <= 0 || (v.x == 12 && v.y <= 19) || behind)
        };
        assert_eq!(walk_to(feet(12.3, 20.0, 26.5), 19, rampart), None);
        // Round a corner (columns 10, 10 to 11, 11): walled on both sides,
        // no way; on one side, a way.
        let to = feet(11.2, 1.0, 11.2);
        let cfg = GravityConfig::default();
        let corner = |open: bool| {
            move |v: VoxelPos| {
                let wall = (v.x, v.z) == (10, 11) || (!open && (v.x, v.z) == (11, 10));
                Some(v.y <= 0 || (wall && v.y <= 10))
            }
        };
        let from = feet(10.2, 1.0, 10.2);
        assert_eq!(
            walked_base(from, to, 0, 1.0, EYE, corner(false), &cfg),
            None
        );
        assert_eq!(
            walked_base(from, to, 0, 1.0, EYE, corner(true), &cfg),
            Some(2.0)
        );
    }

    /// The walk starts on ground under the held feet, in their own
    /// column: not from the air over a low wall, through a door the wall
    /// seals (review 86: a 20-voxel wall crossed).
    #[test]
    fn a_walk_starts_on_the_ground_under_the_held_feet() {
        let cfg = GravityConfig::default();
        let world = |v: VoxelPos| {
            let door = v.z == 10 && (1..=2).contains(&v.y);
            let inside = match v.x {
                12..=16 => 4 * (v.x - 11),
                _ => 0,
            };
            Some(
                v.y <= 0
                    || (v.x == 9 && v.y <= 2)
                    || (v.x == 10 && v.y <= 20 && !door)
                    || (v.x >= 11 && v.y <= inside),
            )
        };
        let to = feet(16.2, 21.0, 10.2);
        let over_the_low_wall = feet(9.2, 4.9, 10.2);
        assert_eq!(
            walked_base(over_the_low_wall, to, 20, 1.0, EYE, world, &cfg),
            None
        );
        // On the low wall's top: the high wall over the door is in the way.
        let on_it = feet(9.2, 3.0, 10.2);
        assert_eq!(walked_base(on_it, to, 20, 3.0, EYE, world, &cfg), None);
        // In front of the door (the low wall gone): through it and up.
        let open = |v: VoxelPos| Some(v.x != 9 && world(v) == Some(true) || v.y <= 0);
        let before = feet(8.2, 1.0, 10.2);
        assert!(walked_base(before, to, 20, 1.0, EYE, open, &cfg).is_some());
    }

    /// Ways over and under a slab are both followed: the one under it
    /// leads on through a passage (review 86: the highest top alone was
    /// followed onto the slab, and the way refused).
    #[test]
    fn a_walk_follows_the_way_under_a_slab_too() {
        let world = |v: VoxelPos| {
            let slab = (12..=14).contains(&v.x) && v.y == 3;
            let building = (15..=16).contains(&v.x) && (3..=12).contains(&v.y);
            let steps = (18..=24).contains(&v.x) && v.y <= 3 * (v.x - 17);
            Some(v.y <= 0 || slab || building || steps)
        };
        assert_eq!(walk_to(feet(24.2, 22.0, 10.5), 21, world), Some(23.0));
    }

    /// Every voxel a walk reads lies in the chunks [`walk_chunks`] lists:
    /// on speckled terrain (many tops, many blocked rooms) and on flat
    /// ground at either end's height (walks that get through), between
    /// ends near chunk borders, from bases up to the start's feet.
    #[test]
    fn a_walks_chunks_hold_every_voxel_it_reads() {
        let cfg = GravityConfig::default();
        let speckled = |v: VoxelPos| {
            let h = (v.x as u32).wrapping_mul(73_856_093)
                ^ (v.y as u32).wrapping_mul(19_349_663)
                ^ (v.z as u32).wrapping_mul(83_492_791);
            h % 7 < 3
        };
        let ends = [
            [0.4, 1.0, 0.5],
            [1.2, 30.0, 2.3],
            [5.5, 30.2, 9.0],
            [-3.2, 62.4, 31.5],
            [31.0, 33.0, -0.5],
            [20.0, -20.0, 3.0],
            [31.6, 0.5, 31.6],
        ];
        for a in ends {
            for b in ends {
                let (a, b) = (
                    FixedVec3::from_f64(a).unwrap(),
                    FixedVec3::from_f64(b).unwrap(),
                );
                let listed = walk_chunks(a, b, EYE);
                let (ay, by) = (a.y.to_f64(), b.y.to_f64());
                for base in [ay - 8.0, ay - 0.5, ay] {
                    for top in [by.floor() as i32 - 1, (by + 0.5).floor() as i32] {
                        for world in [0, 1, 2] {
                            let read = |v: VoxelPos| {
                                assert!(listed.contains(&v.chunk()), "{v:?} of {a:?} -> {b:?}");
                                Some(match world {
                                    0 => speckled(v),
                                    1 => f64::from(v.y) < ay.floor(),
                                    _ => f64::from(v.y) < by.floor(),
                                })
                            };
                            walked_base(a, b, top, base, EYE, read, &cfg);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn the_chunks_listed_hold_every_voxel_read() {
        for y in [-0.4, 0.0, 1.0, 2.6, 31.2, 32.0, 33.9] {
            for x in [-0.5, 0.0, 30.9, 31.0, 31.5] {
                let feet = FixedVec3::from_f64([x, y, x]).unwrap();
                let listed = chunks(feet);
                ground(feet, |v| {
                    assert!(listed.contains(&v.chunk()), "{v:?} of {feet:?}");
                    Some(false)
                });
            }
        }
    }
}
