//! A move's path: the body must not pass through solid terrain on its way
//! from the last accepted position to the new one. Else a player reporting
//! the far side of a wall within one move's reach walks through it.

use std::collections::BTreeSet;

use glam::DVec3;
use strata_terrain::edit::FixedVec3;
use strata_terrain::{ChunkPos, VoxelPos, VoxelRead};

use super::config::ValidationConfig;
use super::position::{nearest_voxel, to_dvec3, PositionReject};

/// Longest step between two points of a path that are checked, in voxels:
/// a point crossing a voxel passes at least one sample inside it unless it
/// only clips a corner, so no wall a voxel thick is stepped over.
pub const SWEEP_STEP: f64 = 0.25;

/// How far above the higher end a move may have gone over something in
/// its way (a mound, a ledge's edge), in voxels. The server checks no
/// gravity: a client could report its way up, across and down in three
/// moves anyway, so this opens no wall; it spares an honest player who
/// stepped up and down again between two reports.
pub const HOP_VOXELS: f64 = 4.0;

/// The ways a move may have gone: straight; up or down first, then
/// across; across first, then up or down; along x first, then z; along z
/// first, then x; 1 to [`HOP_VOXELS`] over the higher end (lowest first,
/// so a bump under a low ceiling is cleared), across, and down; never so
/// high that the eye leaves the world. A player stepping onto a ledge or
/// off one between two reports takes a bent way (the straight one cuts
/// the ledge's corner), one running round a corner too; a wall across the
/// whole move, at every height from the lower end to the hop's, blocks
/// them all.
fn routes(from: DVec3, to: DVec3, cfg: &ValidationConfig) -> Vec<[DVec3; 4]> {
    let vertical_first = DVec3::new(from.x, to.y, from.z);
    let across_first = DVec3::new(to.x, from.y, to.z);
    let x_first = DVec3::new(to.x, from.y, from.z);
    let z_first = DVec3::new(from.x, from.y, to.z);
    let mut out = vec![
        [from, to, to, to],
        [from, vertical_first, to, to],
        [from, across_first, to, to],
        [from, x_first, to, to],
        [from, z_first, to, to],
    ];
    let highest = from.y.max(to.y);
    let ceiling = f64::from(cfg.bounds.max_y) - cfg.eye_height;
    for hop in 1..=HOP_VOXELS as u32 {
        let top = highest + f64::from(hop);
        if top > ceiling {
            break;
        }
        let (up, over) = (DVec3::new(from.x, top, from.z), DVec3::new(to.x, top, to.z));
        out.push([from, up, over, to]);
    }
    out
}

/// The voxels a body with feet at `feet` passes through: nearest to one
/// voxel above the feet, to each whole voxel above that below the eye, and
/// to the eye (the position rule's two points, and what lies between
/// them when `eye_height` is over 2).
fn body_column(feet: DVec3, cfg: &ValidationConfig) -> impl Iterator<Item = VoxelPos> {
    let eye = cfg.eye_height;
    let steps = (2..).take_while(move |&k| f64::from(k) < eye);
    std::iter::once(1.0)
        .chain(steps.map(f64::from))
        .chain(std::iter::once(eye))
        .map(move |dy| nearest_voxel(feet + DVec3::Y * dy))
}

/// The body's voxels at each point of leg `a` → `b`, `a` excluded, at
/// most [`SWEEP_STEP`] apart (none when the leg is empty).
fn leg_voxels(a: DVec3, b: DVec3, cfg: &ValidationConfig) -> impl Iterator<Item = VoxelPos> + '_ {
    let n = (a.distance(b) / SWEEP_STEP).ceil() as u32;
    (1..=n).flat_map(move |i| body_column(a.lerp(b, f64::from(i) / f64::from(n)), cfg))
}

fn route_voxels<'a>(
    route: &'a [DVec3; 4],
    cfg: &'a ValidationConfig,
) -> impl Iterator<Item = VoxelPos> + 'a {
    route
        .windows(2)
        .flat_map(move |leg| leg_voxels(leg[0], leg[1], cfg))
        // Above the world there is only air (the hop may go there).
        .filter(move |v| cfg.bounds.contains_y(v.y))
}

/// Every chunk a sweep of `from` → `to` may read: what must be resident
/// before [`check`].
pub fn chunks(from: FixedVec3, to: FixedVec3, cfg: &ValidationConfig) -> BTreeSet<ChunkPos> {
    let mut out = BTreeSet::new();
    for route in routes(to_dvec3(from), to_dvec3(to), cfg) {
        let mut last = None;
        for c in route_voxels(&route, cfg).map(|v| v.chunk()) {
            // Consecutive voxels mostly share a chunk.
            if last.replace(c) != Some(c) {
                out.insert(c);
            }
        }
    }
    out
}

/// `Ok` when some way from `from` to `to` keeps the body out of solid
/// terrain. The body's voxels at `from` (its whole column) do not count:
/// a player something was built around may walk out of it.
pub fn check(
    from: FixedVec3,
    to: FixedVec3,
    cfg: &ValidationConfig,
    voxels: &impl VoxelRead,
) -> Result<(), PositionReject> {
    let (a, b) = (to_dvec3(from), to_dvec3(to));
    let start: Vec<VoxelPos> = body_column(a, cfg).collect();
    let mut first = None;
    for route in routes(a, b, cfg) {
        let hit =
            route_voxels(&route, cfg).find(|v| !start.contains(v) && voxels.voxel(*v).is_solid());
        match hit {
            None => return Ok(()),
            Some(v) => {
                first.get_or_insert(v);
            }
        }
    }
    let voxel = first.expect("the straight way is always tried");
    Err(PositionReject::PathBlocked { voxel })
}
