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

/// How far below the feet a ground voxel may lie, in voxels: feet a
/// little above the surface (a bot's stand on the top voxel's top, a
/// client's capsule) still stand.
pub const GROUND_REACH: f64 = 2.5;
/// How far into the ground the feet may have sunk, in voxels.
pub const GROUND_SINK: f64 = 0.5;

/// `[validation.gravity]`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GravityConfig {
    /// Whether players are held to the ground at all (a game whose
    /// players fly turns it off).
    pub enabled: bool,
    /// See [`DEFAULT_JUMP_VOXELS`].
    pub jump_voxels: f64,
}

impl Default for GravityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            jump_voxels: DEFAULT_JUMP_VOXELS,
        }
    }
}

impl GravityConfig {
    fn jump(&self) -> i32 {
        Fixed::from_f64(self.jump_voxels).map_or(0, |f| f.0)
    }
}

/// How high a player's next report may be, after an accepted one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Air {
    /// The highest feet off the ground may be: a jump above where they
    /// last stood, lowered to where a fall began.
    pub apex: Fixed,
    /// The highest feet standing on something may be: a jump above the
    /// last report that stood, else the apex.
    pub step: Fixed,
}

fn add(y: Fixed, d: i32) -> Fixed {
    Fixed(y.0.saturating_add(d))
}

impl Air {
    /// Not held to the ground (an admin, or the rule off).
    pub const FREE: Air = Air {
        apex: Fixed(i32::MAX),
        step: Fixed(i32::MAX),
    };

    /// Standing at `feet`: a jump from there either way.
    pub fn stood(feet: FixedVec3, cfg: &GravityConfig) -> Self {
        let top = add(feet.y, cfg.jump());
        Self {
            apex: top,
            step: top,
        }
    }

    /// A player placed at `feet` without a report (a resume, an arrival,
    /// a first spot in the air): not known to stand, so it may not rise
    /// off the ground; it may stand a jump higher (walking up a slope),
    /// and `climb` voxels more (an arrival's walk since its spot).
    pub fn placed(feet: FixedVec3, climb: f64, cfg: &GravityConfig) -> Self {
        let more = Fixed::from_f64(climb.max(0.0)).map_or(i32::MAX, |f| f.0);
        Self {
            apex: feet.y,
            step: add(add(feet.y, cfg.jump()), more),
        }
    }
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

/// Whether feet at `feet` stand on the ground: some voxel near them (see
/// [`columns`]) is solid with a non-solid one above it, the top of the
/// ground; a wall's face is no ground.
pub fn stands(feet: FixedVec3, solid: impl Fn(VoxelPos) -> bool) -> bool {
    let (ys, cols) = columns(feet);
    cols.iter().any(|&(x, z)| {
        ys.clone()
            .any(|y| solid(VoxelPos::new(x, y, z)) && !solid(VoxelPos::new(x, y + 1, z)))
    })
}

/// The chunks [`stands`] may read for feet at `feet`.
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

/// Checks a report of `feet` against `prev`, the state after the last
/// accepted one at `last` (none for a first position); `standing` is
/// [`stands`] for the new feet. Standing, the feet may be up to the step
/// (a jump above the last report that stood); off the ground, up to the
/// apex, and a fall lowers the apex to where it began.
pub fn check(
    prev: Option<(Air, FixedVec3)>,
    feet: FixedVec3,
    standing: bool,
    cfg: &GravityConfig,
) -> Result<Air, PositionReject> {
    let Some((air, last)) = prev else {
        return Ok(if standing {
            Air::stood(feet, cfg)
        } else {
            // A first position in the air: it may only fall.
            Air::placed(feet, 0.0, cfg)
        });
    };
    let limit = if standing { air.step } else { air.apex };
    if feet.y > limit {
        return Err(PositionReject::TooHigh {
            apex: limit.to_f64(),
        });
    }
    if standing {
        return Ok(Air::stood(feet, cfg));
    }
    let apex = if feet.y < last.y {
        air.apex.min(last.y)
    } else {
        air.apex
    };
    Ok(Air { apex, step: apex })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(y: f64) -> FixedVec3 {
        FixedVec3::from_f64([10.5, y, 10.5]).unwrap()
    }

    /// Ground: solid at and below y = 0 in every column; a wall at x = 12
    /// up to y = 20.
    fn ground(v: VoxelPos) -> bool {
        v.y <= 0 || (v.x == 12 && v.y <= 20)
    }

    #[test]
    fn feet_on_the_ground_stand_and_a_wall_is_no_ground() {
        assert!(stands(at(1.0), ground));
        assert!(stands(at(2.5), ground), "a little above the top");
        assert!(!stands(at(3.0), ground));
        assert!(stands(at(0.5), ground), "sunk half a voxel");
        // Beside the wall (its column within a voxel), above the ground:
        // its face is no ground, its top is.
        let beside = |y| FixedVec3::from_f64([11.5, y, 10.5]).unwrap();
        assert!(!stands(beside(10.0), ground));
        assert!(stands(beside(21.0), ground));
    }

    #[test]
    fn off_the_ground_a_jump_high_and_no_climbing_back_after_a_fall() {
        let cfg = GravityConfig::default();
        let stood = check(None, at(1.0), true, &cfg).unwrap();
        assert_eq!(stood, Air::stood(at(1.0), &cfg));
        // Up to the apex, 4 above the feet; not past it.
        let up = check(Some((stood, at(1.0))), at(5.0), false, &cfg).unwrap();
        assert!(matches!(
            check(Some((up, at(5.0))), at(5.5), false, &cfg),
            Err(PositionReject::TooHigh { apex }) if apex == 5.0
        ));
        // Nor standing on a ledge above it.
        assert!(check(Some((up, at(5.0))), at(5.5), true, &cfg).is_err());
        // A fall lowers the apex to where it began.
        let down = check(Some((up, at(5.0))), at(3.0), false, &cfg).unwrap();
        assert_eq!(down.apex, at(5.0).y);
        let lower = check(Some((down, at(3.0))), at(2.8), false, &cfg).unwrap();
        assert_eq!(lower.apex, at(3.0).y);
        assert!(check(Some((lower, at(2.8))), at(3.5), false, &cfg).is_err());
        // Standing again: a new jump.
        let landed = check(Some((lower, at(2.8))), at(1.0), true, &cfg).unwrap();
        assert_eq!(landed, Air::stood(at(1.0), &cfg));
    }

    /// Standing reports climb a jump at a time: walking up a slope passes,
    /// the top of a wall far above the last report does not.
    #[test]
    fn a_standing_report_is_a_jump_above_the_last_at_most() {
        let cfg = GravityConfig::default();
        let mut air = Air::stood(at(1.0), &cfg);
        let mut last = at(1.0);
        for y in [3.0, 6.5, 10.0, 13.5] {
            air = check(Some((air, last)), at(y), true, &cfg).unwrap();
            last = at(y);
        }
        assert!(matches!(
            check(Some((air, last)), at(25.0), true, &cfg),
            Err(PositionReject::TooHigh { apex }) if apex == 17.5
        ));
    }

    #[test]
    fn a_player_placed_in_the_air_may_fall_or_stand_not_rise() {
        let cfg = GravityConfig::default();
        let placed = Air::placed(at(30.0), 0.0, &cfg);
        let prev = Some((placed, at(30.0)));
        assert!(check(prev, at(30.5), false, &cfg).is_err());
        assert!(check(prev, at(29.0), false, &cfg).is_ok());
        assert!(check(prev, at(33.0), true, &cfg).is_ok(), "up a slope");
        assert!(check(prev, at(34.5), true, &cfg).is_err());
        // An arrival's walk since its spot counts.
        let arrived = Some((Air::placed(at(30.0), 10.0, &cfg), at(30.0)));
        assert!(check(arrived, at(44.0), true, &cfg).is_ok());
        assert!(check(arrived, at(31.0), false, &cfg).is_err());
        assert_eq!(check(None, at(30.0), false, &cfg), Ok(placed));
    }

    #[test]
    fn the_chunks_listed_hold_every_voxel_read() {
        for y in [-0.4, 0.0, 1.0, 2.6, 31.2, 32.0, 33.9] {
            for x in [-0.5, 0.0, 30.9, 31.0, 31.5] {
                let feet = FixedVec3::from_f64([x, y, x]).unwrap();
                let listed = chunks(feet);
                stands(feet, |v| {
                    assert!(listed.contains(&v.chunk()), "{v:?} of {feet:?}");
                    false
                });
            }
        }
    }
}
