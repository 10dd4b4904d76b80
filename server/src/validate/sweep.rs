//! A move's path: the body must not pass through solid terrain on its way
//! from the last accepted position to the new one. Else a player reporting
//! the far side of a wall within one move's reach walks through it.

use std::collections::BTreeSet;

use glam::DVec3;
use strata_terrain::edit::FixedVec3;
use strata_terrain::{ChunkPos, VoxelPos, VoxelRead};

use super::config::ValidationConfig;
use super::position::{low_blocks, nearest_voxel, to_dvec3, PositionReject, BODY_LOW};

/// Longest step between two points of a path that are checked, in voxels:
/// a point crossing a voxel passes at least one sample inside it unless it
/// only clips a corner, so no wall a voxel thick is stepped over.
pub const SWEEP_STEP: f64 = 0.25;

/// How far above the higher end a move may have gone over something in
/// its way (a mound, a ledge's edge), in voxels, and never above the
/// apex of a player held to the ground (`gravity.rs`): no higher than it
/// could report its way up, across and down in three moves, so this opens
/// no wall; it spares an honest player who stepped up and down again
/// between two reports.
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
fn routes(from: DVec3, to: DVec3, cfg: &ValidationConfig, apex: Option<f64>) -> Vec<[DVec3; 4]> {
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
    let ceiling = (f64::from(cfg.bounds.max_y) - cfg.eye_height).min(apex.unwrap_or(f64::MAX));
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

/// One of the voxels a body passes through; `low` is the feet's height
/// when it is the body's lowest, judged by [`low_blocks`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct BodyVoxel {
    at: VoxelPos,
    low: Option<f64>,
}

impl BodyVoxel {
    fn blocks(self, voxels: &impl VoxelRead, cfg: &ValidationConfig) -> bool {
        match self.low {
            Some(feet_y) => low_blocks(voxels, self.at, feet_y, cfg.bounds.max_y),
            None => voxels.voxel(self.at).is_solid(),
        }
    }
}

/// The voxels a body with feet at `feet` passes through: nearest to
/// [`BODY_LOW`] and one voxel above the feet, to each whole voxel above
/// that below the eye, and to the eye (the position rule's points, and
/// what lies between them when `eye_height` is over 2).
fn body_column(feet: DVec3, cfg: &ValidationConfig) -> impl Iterator<Item = BodyVoxel> {
    let eye = cfg.eye_height;
    let steps = (2..).take_while(move |&k| f64::from(k) < eye);
    let low = BodyVoxel {
        at: nearest_voxel(feet + DVec3::Y * BODY_LOW),
        low: Some(feet.y),
    };
    std::iter::once(low).chain(
        std::iter::once(1.0)
            .chain(steps.map(f64::from))
            .chain(std::iter::once(eye))
            .map(move |dy| BodyVoxel {
                at: nearest_voxel(feet + DVec3::Y * dy),
                low: None,
            }),
    )
}

/// The body's voxels at each point of leg `a` → `b`, `a` excluded, at
/// most [`SWEEP_STEP`] apart (none when the leg is empty).
fn leg_voxels(a: DVec3, b: DVec3, cfg: &ValidationConfig) -> impl Iterator<Item = BodyVoxel> + '_ {
    let n = (a.distance(b) / SWEEP_STEP).ceil() as u32;
    (1..=n).flat_map(move |i| body_column(a.lerp(b, f64::from(i) / f64::from(n)), cfg))
}

fn route_voxels<'a>(
    route: &'a [DVec3; 4],
    cfg: &'a ValidationConfig,
) -> impl Iterator<Item = BodyVoxel> + 'a {
    route
        .windows(2)
        .flat_map(move |leg| leg_voxels(leg[0], leg[1], cfg))
        // Above the world there is only air (the hop may go there).
        .filter(move |v| cfg.bounds.contains_y(v.at.y))
}

/// Most chunks [`chunks`] lists from the box around a move's ways; a move
/// whose box holds more (a long one) has its ways walked instead.
pub const BOX_CHUNKS: usize = 8;

/// How far the box reaches past the ways' ends, in voxels: far more than
/// a rounding of coordinates below 2^22 voxels.
const BOX_PAD: f64 = 1e-6;

/// Every chunk a sweep of `from` → `to` may read: what must be resident
/// before [`check`]. Worked out from the box around every way when that is
/// small (an honest report: no voxel walked), else along the ways.
pub fn chunks(from: FixedVec3, to: FixedVec3, cfg: &ValidationConfig) -> BTreeSet<ChunkPos> {
    let (a, b) = (to_dvec3(from), to_dvec3(to));
    match box_chunks(a, b, cfg) {
        Some(set) => set,
        None => walked_chunks(a, b, cfg),
    }
}

/// The chunks of the box that holds every voxel [`check`] may read for
/// `a` → `b`, when there are at most [`BOX_CHUNKS`]: every way stays
/// between the ends across, and between the lower end and the highest hop
/// up and down, and the body reaches from the lower of [`BODY_LOW`] and the
/// eye above its feet to the higher of one voxel and the eye.
fn box_chunks(a: DVec3, b: DVec3, cfg: &ValidationConfig) -> Option<BTreeSet<ChunkPos>> {
    // Up to the voxel over the body's lowest, which `low_blocks` reads.
    let (below, above) = (cfg.eye_height.min(BODY_LOW), cfg.eye_height.max(2.0));
    // Padded: a point a way passes may be a rounding off the ends' range
    // (`lerp` of two equal coordinates), on the other side of a voxel's
    // half.
    let pad = DVec3::splat(BOX_PAD);
    let low = nearest_voxel(a.min(b) + DVec3::Y * below - pad);
    let top = a.y.max(b.y) + HOP_VOXELS + above;
    let high = nearest_voxel(DVec3::new(a.x.max(b.x), top, a.z.max(b.z)) + pad);
    // Above and below the world there is nothing to read.
    let (y0, y1) = (low.y.max(cfg.bounds.min_y), high.y.min(cfg.bounds.max_y));
    if y0 > y1 {
        return Some(BTreeSet::new());
    }
    let (lo, hi) = (
        VoxelPos::new(low.x, y0, low.z).chunk(),
        VoxelPos::new(high.x, y1, high.z).chunk(),
    );
    let span = |l: i32, h: i32| usize::try_from(i64::from(h) - i64::from(l) + 1).unwrap_or(0);
    let count = span(lo.x, hi.x)
        .saturating_mul(span(lo.y, hi.y))
        .saturating_mul(span(lo.z, hi.z));
    if count > BOX_CHUNKS {
        return None;
    }
    let mut out = BTreeSet::new();
    for x in lo.x..=hi.x {
        for y in lo.y..=hi.y {
            for z in lo.z..=hi.z {
                out.insert(ChunkPos::new(x, y, z));
            }
        }
    }
    Some(out)
}

/// The chunks the ways' voxels fall in, walked one by one.
fn walked_chunks(a: DVec3, b: DVec3, cfg: &ValidationConfig) -> BTreeSet<ChunkPos> {
    let mut out = BTreeSet::new();
    for route in routes(a, b, cfg, None) {
        let mut last = None;
        let reads = route_voxels(&route, cfg).flat_map(|v| {
            let over = v
                .low
                .map(|_| VoxelPos::new(v.at.x, v.at.y.saturating_add(1), v.at.z))
                .filter(|o| o.y <= cfg.bounds.max_y);
            std::iter::once(v.at).chain(over)
        });
        for c in reads.map(|v| v.chunk()) {
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
/// a player something was built around may walk out of it. No hop's
/// feet go above `apex` (a player held to the ground: a jump's top).
pub fn check(
    from: FixedVec3,
    to: FixedVec3,
    cfg: &ValidationConfig,
    voxels: &impl VoxelRead,
    apex: Option<f64>,
) -> Result<(), PositionReject> {
    let (a, b) = (to_dvec3(from), to_dvec3(to));
    let start: Vec<VoxelPos> = body_column(a, cfg).map(|v| v.at).collect();
    let mut first = None;
    for route in routes(a, b, cfg, apex) {
        let hit =
            route_voxels(&route, cfg).find(|v| !start.contains(&v.at) && v.blocks(voxels, cfg));
        match hit {
            None => return Ok(()),
            Some(v) => {
                first.get_or_insert(v.at);
            }
        }
    }
    let voxel = first.expect("the straight way is always tried");
    Err(PositionReject::PathBlocked { voxel })
}

#[cfg(test)]
mod tests {
    use std::cell::RefCell;

    use proptest::prelude::*;
    use strata_terrain::Voxel;

    use super::*;

    /// Solid at about one voxel in three, by a hash of its position: ways
    /// get blocked at varied points, so [`check`] tries varied ways.
    struct Speckled(RefCell<BTreeSet<ChunkPos>>);

    impl VoxelRead for Speckled {
        fn voxel(&self, p: VoxelPos) -> Voxel {
            self.0.borrow_mut().insert(p.chunk());
            let h = (p.x as u32).wrapping_mul(0x9E37_79B1)
                ^ (p.y as u32).wrapping_mul(0x85EB_CA77)
                ^ (p.z as u32).wrapping_mul(0xC2B2_AE3D);
            if h.wrapping_mul(0x27D4_EB2F) >> 30 == 0 {
                Voxel::solid(1)
            } else {
                Voxel::AIR
            }
        }
    }

    fn point(base: [f64; 3], d: [f64; 3]) -> FixedVec3 {
        FixedVec3::from_f64([base[0] + d[0], base[1] + d[1], base[2] + d[2]]).unwrap()
    }

    /// Moves near chunk borders (every axis crosses one), short and long,
    /// up and down, near the world's top and bottom.
    fn moves() -> impl Strategy<Value = (FixedVec3, FixedVec3)> {
        let base = prop_oneof![
            Just([30.5, 10.0, -1.25]),
            Just([16.5, 29.0, 31.5]),
            Just([31.5, 31.5, -32.5]),
            Just([-0.75, 62.0, 31.75]),
            Just([64.0, -60.0, 0.0]),
            Just([1.0, 508.0, 1.0]),
            Just([1.0, -512.0, 1.0]),
        ];
        let offset = || prop_oneof![2 => -3.0f64..3.0, 1 => Just(0.0)];
        let step =
            prop_oneof![3 => -3.0f64..3.0, 1 => Just(0.0), 1 => Just(2.0), 1 => -60.0f64..60.0];
        (
            base,
            [offset(), offset(), offset()],
            [step.clone(), step.clone(), step],
        )
            .prop_map(|(b, o, s)| {
                (
                    point(b, o),
                    point(b, [o[0] + s[0], o[1] + s[1], o[2] + s[2]]),
                )
            })
    }

    proptest! {
        /// The box is never less than the ways: every chunk a walk of them
        /// meets is in it.
        #[test]
        fn the_box_holds_every_ways_chunks((from, to) in moves()) {
            let cfg = ValidationConfig::default();
            let (a, b) = (to_dvec3(from), to_dvec3(to));
            if let Some(boxed) = box_chunks(a, b, &cfg) {
                let walked = walked_chunks(a, b, &cfg);
                prop_assert!(walked.is_subset(&boxed), "{walked:?} not in {boxed:?}");
                prop_assert!(boxed.len() <= BOX_CHUNKS);
            }
        }

        /// A sweep reads only chunks [`chunks`] listed, whichever ways it
        /// tries, for eyes shorter and taller than a voxel.
        #[test]
        fn a_sweep_reads_only_the_chunks_listed(
            (from, to) in moves(),
            eye in prop_oneof![Just(1.6), Just(0.5), Just(3.5)],
        ) {
            let cfg = ValidationConfig { eye_height: eye, ..ValidationConfig::default() };
            let listed = chunks(from, to, &cfg);
            let world = Speckled(RefCell::default());
            let _ = check(from, to, &cfg, &world, None);
            let read = world.0.into_inner();
            prop_assert!(read.is_subset(&listed), "{read:?} not in {listed:?}");
        }
    }

    /// A way along a coordinate half a voxel below a chunk border: `lerp`
    /// of the two equal ends may round it just under the half, into the
    /// chunk below, which the box must hold too.
    #[test]
    fn a_way_along_a_half_voxel_below_a_chunk_border_is_in_the_box() {
        let cfg = ValidationConfig::default();
        let (a, b) = (DVec3::new(16.5, 29.0, 31.5), DVec3::new(18.5, 29.0, 31.5));
        let boxed = box_chunks(a, b, &cfg).unwrap();
        let walked = walked_chunks(a, b, &cfg);
        assert!(walked.is_subset(&boxed), "{walked:?} not in {boxed:?}");
    }

    /// A short move is listed from its box; a long one along its ways.
    #[test]
    fn a_long_move_is_walked() {
        let cfg = ValidationConfig::default();
        let from = point([16.0, 10.0, 16.0], [0.0; 3]);
        let near = point([16.0, 10.0, 16.0], [0.4, 0.0, -0.3]);
        let far = point([16.0, 10.0, 16.0], [200.0, 0.0, 200.0]);
        let (a, b) = (to_dvec3(from), to_dvec3(near));
        assert_eq!(box_chunks(a, b, &cfg), Some(walked_chunks(a, b, &cfg)));
        assert_eq!(box_chunks(a, to_dvec3(far), &cfg), None);
        assert_eq!(
            chunks(from, far, &cfg),
            walked_chunks(a, to_dvec3(far), &cfg)
        );
    }
}
