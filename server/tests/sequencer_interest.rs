//! Interest sets: nearest-first ordering, hysteresis, caps, vertical
//! bounds, and how far a player's own subscription may reach.

use strata_server::interest::{Anchor, Interest, InterestConfig};
use strata_server::validate::WorldBounds;
use strata_terrain::edit::FixedVec3;
use strata_terrain::ChunkPos;

fn d2(a: ChunkPos, b: ChunkPos) -> i64 {
    let d = |p: i32, q: i32| (p as i64 - q as i64).pow(2);
    d(a.x, b.x) + d(a.y, b.y) + d(a.z, b.z)
}

fn interest(radius: u8, hysteresis: u8) -> Interest {
    Interest::new(
        InterestConfig {
            view_radius: radius,
            hysteresis,
        },
        WorldBounds::default(),
    )
}

#[test]
fn nearest_first_with_fixed_tiebreak() {
    let mut i = interest(2, 1);
    let c = i.follow_position(FixedVec3::from_voxels(40, 5, -1));
    let center = ChunkPos::new(1, 0, -1);
    assert_eq!(i.center(), Some(center));
    assert_eq!(c.subscribe.len(), 125);
    assert!(c.unsubscribe.is_empty());
    assert_eq!(c.subscribe[0], center);
    for w in c.subscribe.windows(2) {
        let (a, b) = (w[0], w[1]);
        let ka = (d2(a, center), a.y, a.z, a.x);
        let kb = (d2(b, center), b.y, b.z, b.x);
        assert!(ka < kb, "{a:?} before {b:?}");
    }
    // The same input gives the same order.
    let mut j = interest(2, 1);
    assert_eq!(j.follow_position(FixedVec3::from_voxels(40, 5, -1)), c);
    assert!(i.covers(ChunkPos::new(3, 2, 1)));
    assert!(!i.covers(ChunkPos::new(4, 0, -1)));
    // `may_cover` (no lookup) holds wherever `covers` does, and rules out
    // everything beyond the keep distance (2 + 1 from the center).
    for x in -6..=8 {
        for z in -8..=6 {
            let p = ChunkPos::new(x, 0, z);
            assert!(!i.covers(p) || i.may_cover(p), "{p:?}");
            assert_eq!(
                i.may_cover(p),
                (x - 1).abs().max((z + 1).abs()) <= 3,
                "{p:?}"
            );
        }
    }
    assert!(!interest(2, 1).may_cover(center), "no center yet: nothing");
}

#[test]
fn hysteresis_keeps_chunks_until_far_enough() {
    let mut i = interest(2, 1);
    i.follow_position(FixedVec3::from_voxels(0, 0, 0));
    // One chunk east (far enough past the border to re-centre): the west
    // column (x = -2) is 3 away, within 2 + 1.
    let c = i.follow_position(FixedVec3::from_voxels(40, 0, 0));
    assert!(c.unsubscribe.is_empty());
    assert_eq!(c.subscribe.len(), 25, "only the new east face");
    assert!(c.subscribe.iter().all(|p| p.x == 3));
    assert!(i.covers(ChunkPos::new(-2, 0, 0)));
    // Walking back resends nothing.
    assert!(i
        .follow_position(FixedVec3::from_voxels(0, 0, 0))
        .subscribe
        .is_empty());
    // Two chunks east of the start: x = -2 is now 4 away and goes.
    let c = i.follow_position(FixedVec3::from_voxels(64, 0, 0));
    assert_eq!(c.unsubscribe.len(), 25);
    assert!(c.unsubscribe.iter().all(|p| p.x == -2));
    assert!(!i.covers(ChunkPos::new(-2, 0, 0)));
    assert!(c.unsubscribe.windows(2).all(|w| w[0] < w[1]));
    // Same chunk, different voxel: nothing changes.
    assert!(i
        .follow_position(FixedVec3::from_voxels(70, 3, 3))
        .is_empty());
}

/// Steps ten times over chunk 0's east border (x 31 and 32) and back: no
/// change, and the view stays centred on chunk 0.
fn flip_over_the_x_border_of_chunk_0(i: &mut Interest) {
    for _ in 0..10 {
        for x in [32, 31] {
            assert!(i
                .follow_position(FixedVec3::from_voxels(x, 0, 0))
                .is_empty());
        }
    }
    assert_eq!(i.center(), Some(ChunkPos::new(0, 0, 0)));
}

#[test]
fn walking_to_and_fro_over_a_border_recentres_only_past_the_margin() {
    use strata_server::interest::RECENTRE_MARGIN;
    let mut i = interest(2, 1);
    i.follow_position(FixedVec3::from_voxels(31, 0, 0));
    flip_over_the_x_border_of_chunk_0(&mut i);
    // Just short of the margin, then at it: the view moves east.
    let short = 31 + RECENTRE_MARGIN - 1;
    assert!(i
        .follow_position(FixedVec3::from_voxels(short, 0, 0))
        .is_empty());
    let c = i.follow_position(FixedVec3::from_voxels(31 + RECENTRE_MARGIN, 0, 0));
    assert_eq!(c.subscribe.len(), 25);
    assert_eq!(i.center(), Some(ChunkPos::new(1, 0, 0)));
    // Back west, and the same margin past chunk 1's west face; or up.
    assert!(i
        .follow_position(FixedVec3::from_voxels(29, 0, 0))
        .is_empty());
    assert_eq!(i.center(), Some(ChunkPos::new(1, 0, 0)));
    i.follow_position(FixedVec3::from_voxels(32 - RECENTRE_MARGIN, 0, 0));
    assert_eq!(i.center(), Some(ChunkPos::new(0, 0, 0)));
    i.follow_position(FixedVec3::from_voxels(0, 31 + RECENTRE_MARGIN, 0));
    assert_eq!(i.center(), Some(ChunkPos::new(0, 1, 0)));
}

#[test]
fn explicit_subscribe_is_capped_and_overrides_position() {
    let mut i = interest(2, 0);
    let c = i.subscribe(ChunkPos::new(10, 0, 10), 200);
    assert_eq!(i.radius(), 2, "capped by the view radius");
    assert_eq!(c.subscribe.len(), 125);
    // A position in the view's own chunk keeps it.
    assert!(i
        .follow_position(FixedVec3::from_voxels(330, 0, 330))
        .is_empty());
    assert_eq!(i.center(), Some(ChunkPos::new(10, 0, 10)));
    let c = i.subscribe(ChunkPos::new(10, 0, 10), 0);
    assert!(c.subscribe.is_empty());
    assert_eq!(c.unsubscribe.len(), 124);
    assert_eq!(
        i.subscribed().collect::<Vec<_>>(),
        vec![ChunkPos::new(10, 0, 10)]
    );
}

#[test]
fn a_subscription_must_keep_its_whole_view_within_reach() {
    // View radius 8, hysteresis 2: a view may reach 10 chunks from the anchor.
    let i = interest(8, 2);
    let anchor = Anchor::Chunk(ChunkPos::new(0, 0, 0));
    let check = |x, r| i.check_centre(ChunkPos::new(x, 0, 0), r, anchor);
    assert_eq!(check(2, 8), Ok(()));
    assert_eq!(check(3, 8), Err(2), "a full view two chunks off at most");
    // A radius past the view radius counts as the view radius.
    assert_eq!(check(3, 200), Err(2));
    assert_eq!(check(10, 0), Ok(()));
    assert_eq!(check(10, 1), Err(9));
    assert_eq!(check(6, 4), Ok(()));
    assert_eq!(check(-7, 4), Err(6));
    // Before any position, from the spawn square's chunk columns (-1..=0).
    let spawn = Anchor::Spawn {
        x: 0,
        z: 0,
        radius: 16,
    };
    assert!(i.check_centre(ChunkPos::new(2, 50, -3), 8, spawn).is_ok());
    assert_eq!(i.check_centre(ChunkPos::new(-4, 0, 0), 8, spawn), Err(2));
}

#[test]
fn walking_away_from_a_subscription_moves_it_to_the_feet_at_its_radius() {
    let mut i = interest(2, 1);
    let feet = |cx: i32| FixedVec3::from_voxels(cx * 32 + 16, 16, 16);
    i.follow_position(feet(0));
    // Radius 1 one chunk ahead: reaches 2 of the 3 allowed.
    let c = i.subscribe(ChunkPos::new(1, 0, 0), 1);
    assert!(c.recentred);
    // Still within reach one chunk back, or one chunk on.
    assert!(i.follow_position(feet(-1)).is_empty());
    assert!(i.follow_position(feet(2)).is_empty());
    assert_eq!((i.center(), i.radius()), (Some(ChunkPos::new(1, 0, 0)), 1));
    // Two chunks back it would reach 4: it moves to the feet, keeping the
    // radius asked for.
    let c = i.follow_position(feet(-2));
    assert!(c.recentred);
    assert_eq!((i.center(), i.radius()), (Some(ChunkPos::new(-2, 0, 0)), 1));
    assert!(c.unsubscribe.contains(&ChunkPos::new(2, 0, 0)));
    assert!(!i.covers(ChunkPos::new(2, 0, 0)), "no deltas from there");
    // Within reach of the new centre it stays; past it, it moves again.
    assert!(i.follow_position(feet(-4)).is_empty());
    let c = i.follow_position(feet(-5));
    assert!(c.recentred);
    assert_eq!((i.center(), i.radius()), (Some(ChunkPos::new(-5, 0, 0)), 1));
}

#[test]
fn with_no_hysteresis_flipping_over_a_border_does_not_move_a_subscription() {
    use strata_server::interest::RECENTRE_MARGIN;
    // A whole view with no hysteresis is in reach of its own chunk only.
    let mut i = interest(2, 0);
    i.follow_position(FixedVec3::from_voxels(31, 0, 0));
    i.subscribe(ChunkPos::new(0, 0, 0), 2);
    flip_over_the_x_border_of_chunk_0(&mut i);
    // The margin past it, the view moves to the feet.
    let c = i.follow_position(FixedVec3::from_voxels(31 + RECENTRE_MARGIN, 0, 0));
    assert!(c.recentred);
    assert_eq!((i.center(), i.radius()), (Some(ChunkPos::new(1, 0, 0)), 2));
}

#[test]
fn an_admins_subscription_stays_wherever_it_goes() {
    let mut i = interest(2, 0);
    i.subscribe_anywhere(ChunkPos::new(100, 0, 0), 2);
    assert!(i
        .follow_position(FixedVec3::from_voxels(0, 0, 0))
        .is_empty());
    assert_eq!(i.center(), Some(ChunkPos::new(100, 0, 0)));
}

#[test]
fn vertical_range_follows_world_bounds() {
    let mut i = Interest::new(
        InterestConfig {
            view_radius: 3,
            hysteresis: 1,
        },
        WorldBounds {
            min_y: -32,
            max_y: 31,
        },
    );
    let c = i.follow_position(FixedVec3::from_voxels(0, 0, 0));
    assert!(c.subscribe.iter().all(|p| (-1..=0).contains(&p.y)));
    assert_eq!(c.subscribe.len(), 7 * 7 * 2);
}
