//! Each edit rule rejects with its own reason and changes nothing.

use crate::sequencer_common;

use sequencer_common::*;
use strata_protocol::{RejectReason, Role};
use strata_server::sequencer::{Sequencer, SequencerConfig};
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::{ValidationConfig, WorldBounds, Zone};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{ChunkPos, Edit, EditKind, VoxelPos};

const X: i32 = HOME.0;
const Z: i32 = HOME.1;

/// Submits, expects `reason`, and checks that nothing changed, even after a tick.
fn rejects(
    s: &mut strata_server::sequencer::Sequencer,
    sid: u64,
    edit: Edit,
    reason: RejectReason,
) {
    let before = snapshot(s);
    assert_eq!(s.submit(sid, req(9, edit), 0), Err(reason));
    assert_eq!(snapshot(s), before);
    let out = s.tick(0);
    assert!(out.applied.is_empty() && out.batch.is_empty());
    assert_eq!(snapshot(s), before);
}

#[test]
fn permission_caps_and_core_validation() {
    let mut s = ready(ValidationConfig::default());
    rejects(
        &mut s,
        PLAYER,
        fill((X, 0, Z + 3), (X + 1, 1, Z + 3)),
        RejectReason::NotPermitted {
            kind: EditKind::FillBox,
        },
    );
    rejects(
        &mut s,
        PLAYER,
        mine(X, -1, Z + 3, 9),
        RejectReason::RadiusTooLarge {
            max: Fixed::from_voxels(8),
        },
    );
    rejects(
        &mut s,
        PLAYER,
        Edit::Explode {
            center: FixedVec3::from_voxels(X, -1, Z + 3),
            radius: Fixed::from_voxels(2),
            power: 513,
        },
        RejectReason::PowerTooLarge { max: 512 },
    );
    rejects(
        &mut s,
        PLAYER,
        Edit::Build {
            center: FixedVec3::from_voxels(X, 1, Z + 3),
            radius: Fixed::from_voxels(2),
            material: 200,
            strength: 10,
        },
        RejectReason::Invalid {
            message: "unknown material id 200".into(),
        },
    );
    // The same edits pass for an admin where only the role differed.
    assert!(s
        .submit(ADMIN, req(1, fill((X, 0, Z + 3), (X + 1, 1, Z + 3))), 0)
        .is_ok());
}

#[test]
fn no_position_and_reach() {
    let mut s = ready(ValidationConfig::default());
    s.session_joined(7, "newcomer".into(), Role::Player);
    rejects(&mut s, 7, mine(X, -1, Z + 3, 2), RejectReason::NoPosition);
    // Eye at (X, 1.6, Z); target 12 voxels away, reach 10.
    let far = mine(X, -1, Z + 12, 2);
    let before = snapshot(&s);
    match s.submit(PLAYER, req(1, far), 0) {
        Err(RejectReason::OutOfReach { distance, max }) => {
            assert_eq!(max, Fixed::from_voxels(10));
            assert!((distance.to_f64() - (144.0f64 + 2.6 * 2.6).sqrt()).abs() < 0.01);
        }
        other => panic!("expected OutOfReach, got {other:?}"),
    }
    assert_eq!(snapshot(&s), before);
    assert!(s.submit(PLAYER, req(2, mine(X, -1, Z + 6, 2)), 0).is_ok());
}

#[test]
fn line_of_sight_blocked_by_a_wall_and_clear_without_it() {
    let mut s = ready(ValidationConfig::default());
    let target = mine(X, -1, Z + 6, 2);
    assert!(
        s.submit(PLAYER, req(1, target.clone()), 0).is_ok(),
        "clear view"
    );
    s.tick(0);
    // A one-voxel brick wall between the player and the next target.
    let wall = ((X - 4, 0, Z + 3), (X + 4, 4, Z + 3));
    s.submit(ADMIN, req(2, fill(wall.0, wall.1)), 0).unwrap();
    s.tick(0);
    let next = mine(X + 1, -1, Z + 6, 2);
    rejects(&mut s, PLAYER, next.clone(), RejectReason::NoLineOfSight);
    let clear = Edit::ClearBox {
        min: VoxelPos::new(wall.0 .0, wall.0 .1, wall.0 .2),
        max: VoxelPos::new(wall.1 .0, wall.1 .1, wall.1 .2),
    };
    s.submit(ADMIN, req(3, clear), 0).unwrap();
    s.tick(0);
    assert!(s.submit(PLAYER, req(4, next), 0).is_ok(), "wall gone");
}

#[test]
fn vertical_bounds() {
    let v = ValidationConfig {
        bounds: WorldBounds {
            min_y: -3,
            max_y: 2,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    // A radius-2 sphere's box is open: at y = -3 it reaches y = -4, below
    // the bottom; at y = -2 it reaches -3 (voxels at -4 lie at the radius).
    // At the top row, radius 2 leaves the world, radius 1 changes that row
    // alone.
    rejects(
        &mut s,
        PLAYER,
        mine(X, -3, Z + 3, 2),
        RejectReason::OutOfBounds,
    );
    rejects(
        &mut s,
        PLAYER,
        mine(X + 2, 2, Z + 3, 2),
        RejectReason::OutOfBounds,
    );
    assert!(s.submit(PLAYER, req(1, mine(X, -2, Z + 3, 2)), 0).is_ok());
    assert!(s
        .submit(PLAYER, req(2, mine(X + 2, 2, Z + 3, 1)), 0)
        .is_ok());
}

#[test]
fn spawn_protection_with_admin_exemption_and_zone_management() {
    let mut s = sequencer(SequencerConfig::default(), ValidationConfig::default());
    join_at(&mut s, PLAYER, Role::Player, 10, 10);
    join_at(&mut s, ADMIN, Role::Admin, 8, 10);
    let spawn = RejectReason::ProtectedZone {
        zone: "spawn".into(),
    };
    rejects(&mut s, PLAYER, mine(10, -1, 13, 2), spawn);
    assert!(s.submit(ADMIN, req(1, mine(10, -1, 13, 2)), 0).is_ok());

    // Radius 0 turns spawn protection off: the same edit is a player's to make.
    let open = ValidationConfig {
        spawn_protection_radius: 0,
        ..ValidationConfig::default()
    };
    assert!(Sequencer::default_zones(&open).is_empty());
    let mut s = sequencer(SequencerConfig::default(), open);
    join_at(&mut s, PLAYER, Role::Player, 10, 10);
    assert!(s.submit(PLAYER, req(1, mine(10, -1, 13, 2)), 0).is_ok());

    // Zones are managed at run time and serialize for the store's blob.
    let mut s = ready(ValidationConfig::default());
    let castle = Zone {
        name: "castle".into(),
        min: VoxelPos::new(X - 5, -10, Z + 2),
        max: VoxelPos::new(X + 5, 10, Z + 8),
    };
    s.add_zone(castle.clone()).unwrap();
    assert!(s.add_zone(castle.clone()).is_err(), "duplicate name");
    let blob = serde_json::to_string(s.zones()).unwrap();
    let back: Vec<Zone> = serde_json::from_str(&blob).unwrap();
    assert_eq!(back, s.zones());
    rejects(
        &mut s,
        PLAYER,
        mine(X, -1, Z + 4, 2),
        RejectReason::ProtectedZone {
            zone: "castle".into(),
        },
    );
    assert_eq!(s.remove_zone("castle"), Some(castle));
    assert!(s.submit(PLAYER, req(1, mine(X, -1, Z + 4, 2)), 0).is_ok());
}

#[test]
fn edit_bucket_refills_with_time() {
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 2,
            per_second: 1,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    let e = || mine(X, -1, Z + 4, 1);
    assert!(s.submit(PLAYER, req(1, e()), 1_000).is_ok());
    assert!(s.submit(PLAYER, req(2, e()), 1_000).is_ok());
    let before = snapshot(&s);
    assert_eq!(
        s.submit(PLAYER, req(3, e()), 1_500),
        Err(RejectReason::RateLimited)
    );
    assert_eq!(snapshot(&s), before);
    assert!(
        s.submit(PLAYER, req(4, e()), 2_000).is_ok(),
        "one token after 1 s"
    );
    assert_eq!(
        s.submit(PLAYER, req(5, e()), 2_000),
        Err(RejectReason::RateLimited)
    );
    // The admin has a bucket of their own.
    assert!(s.submit(ADMIN, req(6, e()), 2_000).is_ok());
}

#[test]
fn volume_bucket_refills_with_time() {
    let v = ValidationConfig {
        volume_rate: BucketConfig {
            capacity: 300,
            per_second: 1_000,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    // Radius 3: a 5³ = 125-voxel box (open: voxels 3 away along an axis
    // lie at the radius).
    let e = || mine(X, -1, Z + 4, 3);
    assert!(s.submit(PLAYER, req(1, e()), 0).is_ok());
    assert!(s.submit(PLAYER, req(2, e()), 0).is_ok());
    assert_eq!(
        s.submit(PLAYER, req(3, e()), 0),
        Err(RejectReason::VolumeRateLimited)
    );
    assert_eq!(
        s.submit(PLAYER, req(3, e()), 74),
        Err(RejectReason::VolumeRateLimited)
    );
    assert!(
        s.submit(PLAYER, req(4, e()), 75).is_ok(),
        "50 + 75 = 125 voxels"
    );
    // A box bigger than the burst costs the whole burst, so it can still pass.
    let big = Edit::ClearBox {
        min: VoxelPos::new(X - 10, 0, Z + 2),
        max: VoxelPos::new(X + 10, 6, Z + 12),
    };
    assert!(s.submit(ADMIN, req(5, big), 0).is_ok());
}

#[test]
fn a_smooth_takes_its_weight_from_the_volume_bucket() {
    let v = ValidationConfig {
        volume_rate: BucketConfig {
            capacity: 100,
            per_second: 0,
        },
        ..Default::default()
    };
    assert_eq!(v.volume_weight.smooth, 3);
    let mut s = ready(v);
    // Radius 2 on a voxel centre: a 3³ = 27-voxel box, 81 at weight 3.
    let smooth = || Edit::Smooth {
        center: FixedVec3::from_voxels(X, -1, Z + 4),
        radius: Fixed::from_voxels(2),
        strength: 255,
    };
    assert!(s.submit(PLAYER, req(1, smooth()), 0).is_ok());
    // 19 voxels left: a Mine of the same box (27) does not fit either,
    // though 27 + 27 would have at weight 1.
    let before = snapshot(&s);
    assert_eq!(
        s.submit(PLAYER, req(2, mine(X, -1, Z + 4, 2)), 0),
        Err(RejectReason::VolumeRateLimited)
    );
    assert_eq!(snapshot(&s), before);
    // At weight 1 the two fit.
    let v = ValidationConfig {
        volume_rate: BucketConfig {
            capacity: 100,
            per_second: 0,
        },
        volume_weight: strata_server::validate::VolumeWeights {
            smooth: 1,
            ..Default::default()
        },
        ..Default::default()
    };
    let mut s = ready(v);
    assert!(s.submit(PLAYER, req(1, smooth()), 0).is_ok());
    assert!(s.submit(PLAYER, req(2, mine(X, -1, Z + 4, 2)), 0).is_ok());
}

#[test]
fn full_queue_is_busy_and_keeps_tokens() {
    let cfg = SequencerConfig {
        queue_capacity: 2,
        ..Default::default()
    };
    let mut s = sequencer(cfg, ValidationConfig::default());
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    let e = || mine(X, -1, Z + 4, 1);
    assert!(s.submit(PLAYER, req(1, e()), 0).is_ok());
    assert!(s.submit(PLAYER, req(2, e()), 0).is_ok());
    let before = snapshot(&s);
    assert_eq!(s.submit(PLAYER, req(3, e()), 0), Err(RejectReason::Busy));
    assert_eq!(snapshot(&s), before);
    assert_eq!(s.tick(0).applied.len(), 2);
    // 10-edit burst: 2 spent, the Busy one was not charged, so 8 remain.
    for round in 0..4 {
        for i in 0..2 {
            assert!(s.submit(PLAYER, req(10 * round + i, e()), 0).is_ok());
        }
        s.tick(0);
    }
    assert_eq!(
        s.submit(PLAYER, req(99, e()), 0),
        Err(RejectReason::RateLimited)
    );
}

#[test]
fn unknown_session_is_invalid() {
    let mut s = ready(ValidationConfig::default());
    assert!(matches!(
        s.submit(99, req(1, mine(X, -1, Z + 4, 1)), 0),
        Err(RejectReason::Invalid { .. })
    ));
}

#[test]
fn reconnecting_does_not_refill_the_bucket() {
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 2,
            per_second: 1,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    let e = || mine(X, -1, Z + 4, 1);
    assert!(s.submit(PLAYER, req(1, e()), 1_000).is_ok());
    assert!(s.submit(PLAYER, req(2, e()), 1_000).is_ok());
    s.tick(1_000);
    // Same player, new session: the spent budget follows them.
    s.session_left(PLAYER);
    s.tick(1_100);
    assert_eq!(s.tracked_players(), 2, "the spent player is remembered");
    s.session_joined(PLAYER + 200, format!("p{PLAYER}"), Role::Player);
    s.update_position(PLAYER + 200, at(1, X, 0, Z), 1_200)
        .expect("standing on flat ground");
    assert_eq!(
        s.submit(PLAYER + 200, req(3, e()), 1_200),
        Err(RejectReason::RateLimited)
    );
    // Once the bucket is full again and nobody is connected, it is forgotten.
    s.session_left(PLAYER + 200);
    s.tick(10_000);
    assert_eq!(s.tracked_players(), 1, "only the admin is left");
}

#[test]
fn refused_edits_cost_an_edit_token() {
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 3,
            per_second: 1,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    for i in 0..3 {
        assert!(matches!(
            s.submit(PLAYER, req(i, mine(X, -1, Z + 3, 9)), 0),
            Err(RejectReason::RadiusTooLarge { .. })
        ));
    }
    // The three refusals spent the burst: a good edit must wait.
    assert_eq!(
        s.submit(PLAYER, req(5, mine(X, -1, Z + 4, 1)), 0),
        Err(RejectReason::RateLimited)
    );
    assert!(s
        .submit(PLAYER, req(6, mine(X, -1, Z + 4, 1)), 1000)
        .is_ok());
}

#[test]
fn a_player_out_of_rejection_tokens_is_disconnected_once() {
    let v = ValidationConfig {
        reject_rate: BucketConfig {
            capacity: 5,
            per_second: 1,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    let refuse = |s: &mut strata_server::sequencer::Sequencer, i: u64, now: u64| {
        assert!(s
            .submit(PLAYER, req(i, mine(X, -1, Z + 3, 9)), now)
            .is_err());
    };
    for i in 0..5 {
        refuse(&mut s, i, 0);
    }
    assert!(
        s.take_disconnects().is_empty(),
        "five refusals are within the burst"
    );
    refuse(&mut s, 5, 0);
    refuse(&mut s, 6, 0);
    assert_eq!(s.take_disconnects(), vec![PLAYER]);
    assert!(s.take_disconnects().is_empty());
    // The admin's refusals are its own budget.
    assert!(s.submit(ADMIN, req(7, mine(X, 500, Z, 1)), 0).is_err());
    assert!(s.take_disconnects().is_empty());
    // Time refills the budget.
    refuse(&mut s, 8, 10_000);
    assert!(s.take_disconnects().is_empty());
}

#[test]
fn precheck_refuses_without_loading_anything() {
    let mut s = ready(ValidationConfig::default());
    let resident = s.resident();
    let far = Edit::Explode {
        center: FixedVec3::from_voxels(X + 5000, -1, Z),
        radius: Fixed::from_voxels(8),
        power: 100,
    };
    assert!(matches!(
        s.precheck(PLAYER, &far, 0),
        Err(RejectReason::OutOfReach { .. })
    ));
    assert!(matches!(
        s.precheck(PLAYER, &mine(X, -1, Z + 3, 9), 0),
        Err(RejectReason::RadiusTooLarge { .. })
    ));
    assert_eq!(s.resident(), resident, "no chunk was loaded or generated");
    let pre = s.precheck(PLAYER, &mine(X, -1, Z + 4, 1), 0).unwrap();
    // What admitting it reads: the box with its margin, and the ray's
    // chunks with their neighbours, sorted; still nothing loaded.
    assert!(pre.reads().windows(2).all(|w| w[0] < w[1]));
    assert!(pre.reads().contains(&ChunkPos::new(3, -1, 3)));
    assert_eq!(s.resident(), resident);
}

/// A one-voxel brick wall between the player (eye at HOME) and z + 6.
fn walled() -> Sequencer {
    let mut s = ready(ValidationConfig::default());
    s.submit(ADMIN, req(1, fill((X - 4, 0, Z + 3), (X + 4, 4, Z + 3))), 0)
        .unwrap();
    s.tick(0);
    s
}

#[test]
fn admitted_edits_wait_for_one_sight_check_in_arrival_order() {
    let mut s = walled();
    let before = snapshot(&s);
    // Behind the wall, then in front of it (z + 2), then behind it again.
    s.admit(PLAYER, req(10, mine(X + 1, -1, Z + 6, 2)), 0)
        .unwrap();
    s.admit(PLAYER, req(11, mine(X, -1, Z + 2, 1)), 0).unwrap();
    s.admit(PLAYER, req(12, mine(X - 1, -1, Z + 6, 2)), 0)
        .unwrap();
    assert_eq!((s.queued(), s.sighting()), (0, 3), "nothing queued yet");
    assert_eq!(snapshot(&s), before);
    let refused = s.check_sighted(0);
    let ids: Vec<(u64, RejectReason)> = refused
        .into_iter()
        .map(|r| (r.client_edit_id, r.reason))
        .collect();
    assert_eq!(
        ids,
        vec![
            (10, RejectReason::NoLineOfSight),
            (12, RejectReason::NoLineOfSight)
        ]
    );
    assert_eq!((s.queued(), s.sighting()), (1, 0));
    let out = s.tick(0);
    let applied: Vec<u64> = out.applied.iter().map(|a| a.client_edit_id).collect();
    assert_eq!(applied, vec![11]);
    // The same three through `submit` decide the same.
    let mut t = walled();
    let r: Vec<_> = [
        mine(X + 1, -1, Z + 6, 2),
        mine(X, -1, Z + 2, 1),
        mine(X - 1, -1, Z + 6, 2),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, e)| t.submit(PLAYER, req(10 + i as u64, e), 0))
    .collect();
    assert_eq!(
        r,
        vec![
            Err(RejectReason::NoLineOfSight),
            Ok(()),
            Err(RejectReason::NoLineOfSight)
        ]
    );
}

#[test]
fn admission_takes_the_edit_token_and_a_refused_sight_gives_the_volume_back() {
    // Three edit tokens, and volume for one radius-2 mine (a 3^3 box) at a time.
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 3,
            per_second: 0,
        },
        volume_rate: BucketConfig {
            capacity: 27,
            per_second: 0,
        },
        ..Default::default()
    };
    let mut s = ready(v.clone());
    s.submit(ADMIN, req(1, fill((X - 4, 0, Z + 3), (X + 4, 4, Z + 3))), 0)
        .unwrap();
    s.tick(0);
    s.admit(PLAYER, req(10, mine(X, -1, Z + 6, 2)), 0).unwrap();
    // Its volume is held while it waits: a second one does not fit (and,
    // refused, costs the second edit token).
    assert_eq!(
        s.admit(PLAYER, req(11, mine(X, -1, Z + 2, 2)), 0),
        Err(RejectReason::VolumeRateLimited)
    );
    assert_eq!(s.check_sighted(0).len(), 1, "behind the wall");
    // The volume came back; the one edit token left pays for this one.
    s.admit(PLAYER, req(12, mine(X, -1, Z + 2, 2)), 0).unwrap();
    assert!(s.check_sighted(0).is_empty());
    assert_eq!(
        s.admit(PLAYER, req(13, mine(X + 1, -1, Z + 2, 1)), 0),
        Err(RejectReason::RateLimited),
        "three edit tokens: one per edit, refused or not"
    );
}

/// A player with two edit tokens, both spent: edit 10 queued (its sight
/// checked), edit 11 awaiting its sight check; and that edit.
fn one_queued_one_awaiting_sight() -> (Sequencer, Edit) {
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 2,
            per_second: 0,
        },
        ..Default::default()
    };
    let mut s = ready(v);
    let e = mine(X, -1, Z + 2, 1);
    s.admit(PLAYER, req(10, e.clone()), 0).unwrap();
    assert!(s.check_sighted(0).is_empty());
    s.admit(PLAYER, req(11, e.clone()), 0).unwrap();
    assert_eq!((s.queued(), s.sighting()), (1, 1));
    (s, e)
}

/// Edits taken out for a region whose reload failed (queued, or awaiting
/// their sight check) are refused `Busy`, which costs nothing: their edit
/// and volume tokens come back, and edits elsewhere stay.
#[test]
fn edits_taken_out_of_a_region_get_their_tokens_back() {
    let (mut s, e) = one_queued_one_awaiting_sight();
    let elsewhere = [strata_server::sequencer::regions::RegionId { x: 99, z: 99 }]
        .into_iter()
        .collect();
    assert!(s.unqueue_in(&elsewhere, 0).is_empty());
    assert_eq!((s.queued(), s.sighting()), (1, 1));

    let here = s.edit_regions(&e).unwrap();
    assert_eq!(s.unqueue_in(&here, 0), vec![(PLAYER, 10), (PLAYER, 11)]);
    assert_eq!((s.queued(), s.sighting()), (0, 0));
    // Both edit tokens are back.
    s.admit(PLAYER, req(12, e.clone()), 0).unwrap();
    s.admit(PLAYER, req(13, e), 0).unwrap();
}

/// A cluster node's region reloaded with chunks another node moved: the
/// queued edits whose sight was checked on its old copies, because their
/// box or only their sight ray reaches into it, are taken out and refused
/// `Busy` at no cost; an edit awaiting its sight check stays for it (on the
/// reloaded chunks), and edits seen elsewhere stay. A reload that failed
/// takes out those awaiting their check there too, by box or by ray.
#[test]
fn edits_seen_through_a_reloaded_region_are_taken_out() {
    use strata_server::sequencer::regions::RegionId;
    let v = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 3,
            per_second: 0,
        },
        ..Default::default()
    };
    // Regions of one chunk: x 96..128 is region 3, 128..160 region 4.
    let cfg = SequencerConfig {
        region_chunks: 1,
        ..SequencerConfig::default()
    };
    let mut s = sequencer(cfg, v);
    join_at(&mut s, PLAYER, Role::Player, 126, Z);
    let (here, across) = (mine(124, -1, Z, 1), mine(133, -1, Z, 1));
    let region = |x| RegionId { x, z: Z / 32 };
    assert_eq!(s.edit_regions(&across).unwrap(), [region(4)].into());
    s.admit(PLAYER, req(10, here.clone()), 0).unwrap();
    s.admit(PLAYER, req(11, across.clone()), 0).unwrap();
    assert!(s.check_sighted(0).is_empty());
    s.admit(PLAYER, req(12, here), 0).unwrap();
    assert_eq!((s.queued(), s.sighting()), (2, 1));

    assert!(s.unqueue_seen_in(&[region(5)].into(), 0).is_empty());
    // Region 3 holds edit 10's box and edit 11's eye.
    assert_eq!(
        s.unqueue_seen_in(&[region(3)].into(), 0),
        vec![(PLAYER, 10), (PLAYER, 11)]
    );
    assert_eq!((s.queued(), s.sighting()), (0, 1));
    // A failed reload of region 3 takes out what awaits its sight check
    // there too: edit 12's box, edit 13's ray.
    s.admit(PLAYER, req(13, across.clone()), 0).unwrap();
    assert_eq!(
        s.unqueue_in(&[region(3)].into(), 0),
        vec![(PLAYER, 12), (PLAYER, 13)]
    );
    assert_eq!((s.queued(), s.sighting()), (0, 0));
    // Every edit token is back.
    for id in 14..17 {
        s.admit(PLAYER, req(id, across.clone()), 0).unwrap();
    }
}

/// After a fenced batch, the queued edits (their sight checked, perhaps on
/// what the batch changed) are taken out and refused `Busy` at no cost;
/// those still awaiting their check stay for it.
#[test]
fn a_fenced_batch_takes_the_queued_edits_out_and_leaves_those_awaiting_sight() {
    let (mut s, e) = one_queued_one_awaiting_sight();
    assert_eq!(s.unqueue_sighted(0), vec![(PLAYER, 10)]);
    assert_eq!((s.queued(), s.sighting()), (0, 1));
    // The edit token of the one taken out is back.
    s.admit(PLAYER, req(12, e), 0).unwrap();
}

/// The regions an edit needs are those of the chunks it changes and of the
/// chunks whose collision meshes read what it changes (two voxels past a
/// chunk border): an edit a few voxels from a region border needs its own
/// region alone, so two nodes can both edit up to near their border; one
/// at the border needs both.
#[test]
fn an_edit_needs_the_regions_its_meshes_read_and_no_more() {
    use strata_server::sequencer::regions::RegionId;
    let s = ready(ValidationConfig::default());
    let border = s.region_chunks() as i32 * 32;
    let regions = |x: i32| -> Vec<RegionId> {
        s.edit_regions(&mine(x, -1, Z, 1))
            .unwrap()
            .into_iter()
            .collect()
    };
    let (west, east) = (RegionId { x: 0, z: 0 }, RegionId { x: 1, z: 0 });
    assert_eq!(regions(border - 8), vec![west]);
    assert_eq!(regions(border + 8), vec![east]);
    assert_eq!(regions(border), vec![west, east]);
    assert_eq!(regions(border - 1), vec![west, east]);
    // Mining radius 1 changes its centre's voxel alone (the others lie at
    // the radius or beyond), and a change reaches meshes two voxels on:
    // the edges are exact.
    assert_eq!(regions(border + 1), vec![west, east]);
    assert_eq!(regions(border + 2), vec![east]);
    assert_eq!(regions(border - 2), vec![west, east]);
    assert_eq!(regions(border - 3), vec![west]);
}
