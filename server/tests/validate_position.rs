//! Position rules: first position in the spawn area, resume, speed with slack, not inside solid, bounds, staleness, arrival tickets.

use crate::sequencer_common;

use sequencer_common::*;
use strata_protocol::{PositionUpdate, Role, Start, TicketRefusal};
use strata_server::sequencer::{
    Sequencer, SequencerConfig, StoredPosition, STORED_TICKET_SLACK_MS,
};
use strata_server::validate::{PositionReject, SpawnArea, ValidationConfig};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{Edit, VoxelPos};

fn fresh() -> strata_server::sequencer::Sequencer {
    fresh_with(ValidationConfig::default())
}

fn fresh_with(v: ValidationConfig) -> strata_server::sequencer::Sequencer {
    let mut s = sequencer(SequencerConfig::default(), v);
    s.session_joined(PLAYER, "p".into(), Role::Player);
    s
}

/// The default rules without gravity: for tests of the other rules whose
/// players stand in the air or go over walls.
fn flying() -> ValidationConfig {
    let mut v = ValidationConfig::default();
    v.gravity.enabled = false;
    v
}

/// A player the server does not know appears under the open sky: a
/// room sealed under a roof (or a cave under the ground) refuses a first
/// report, at the roof's lowest voxel above the eye; a resumed player, or
/// one already placed, walks in as any other.
#[test]
fn a_first_position_is_open_to_the_sky() {
    let mut s = ready(flying());
    let (x, z) = (HOME.0 + 3, HOME.1);
    // A roof of stone 6 voxels up, over the spot.
    s.submit(ADMIN, req(1, fill((x - 2, 6, z - 2), (x + 2, 7, z + 2))), 0)
        .unwrap();
    s.tick(0);
    s.session_joined(7, "new".into(), Role::Player);
    let under = at(1, x, 0, z);
    assert_eq!(
        s.update_position(7, under, 0),
        Err(PositionReject::PathBlocked {
            voxel: VoxelPos::new(x, 6, z)
        })
    );
    assert_eq!(s.position(7), None);
    // Beside the roof, the sky is open.
    s.update_position(7, at(2, x + 4, 0, z), 0).unwrap();
    // Placed, the player walks under it.
    s.update_position(7, at(3, x, 0, z), 1_000).unwrap();
    // So does one the server resumes there.
    s.session_joined(8, "back".into(), Role::Player);
    let stored = strata_server::store::StoredPosition {
        feet: FixedVec3::from_voxels(x, 0, z),
        known_ms: 0,
    };
    s.resume_position(8, 0, Some(stored));
    s.update_position(8, at(1, x, 0, z + 1), 500).unwrap();
    // A world whose spawn lies under a roof turns the rule off.
    let mut v = flying();
    v.spawn.open_sky = false;
    let mut s = ready(v);
    s.submit(ADMIN, req(1, fill((x - 2, 6, z - 2), (x + 2, 7, z + 2))), 0)
        .unwrap();
    s.tick(0);
    s.session_joined(7, "new".into(), Role::Player);
    s.update_position(7, at(1, x, 0, z), 0).unwrap();
}

/// A tall world's first report reads no more than `MAX_SKY_CHUNKS` rows
/// above the eye's; with the rule off, none.
#[test]
fn the_sky_a_first_report_reads_is_bounded() {
    use strata_server::validate::position::sky_chunks;
    use strata_server::validate::spawn::MAX_SKY_CHUNKS;
    let mut v = ValidationConfig::default();
    v.bounds.max_y = 1 << 20;
    let feet = FixedVec3::from_voxels(3, 40, 5);
    let rows: Vec<i32> = sky_chunks(feet, &v).map(|c| c.y).collect();
    assert_eq!(rows, (1..=1 + MAX_SKY_CHUNKS).collect::<Vec<_>>());
    v.spawn.open_sky = false;
    assert_eq!(sky_chunks(feet, &v).count(), 0);
}

#[test]
fn first_position_in_the_spawn_area_not_solid() {
    let mut s = fresh();
    assert_eq!(s.position(PLAYER), None);
    assert_eq!(
        s.resume_position(PLAYER, 0, None),
        SpawnArea::default().start()
    );
    // Far outside the default spawn square (2048 voxels around 0, 0).
    assert_eq!(
        s.update_position(PLAYER, at(1, 5000, 40, -7000), 0),
        Err(PositionReject::OutsideSpawn {
            x: 0,
            z: 0,
            radius: 2048
        })
    );
    assert_eq!(
        s.update_position(PLAYER, at(2, 2049, 40, 0), 0),
        Err(PositionReject::OutsideSpawn {
            x: 0,
            z: 0,
            radius: 2048
        }),
        "the square's edge is exact"
    );
    // Feet deep in rock: the voxel above the feet is solid.
    assert_eq!(
        s.update_position(PLAYER, at(3, 2000, -10, -2000), 0),
        Err(PositionReject::InsideSolid {
            voxel: VoxelPos::new(2000, -9, -2000)
        })
    );
    assert_eq!(s.position(PLAYER), None, "rejected reports change nothing");
    // At the spawn square's corner, in the air: fine as a first position.
    s.update_position(PLAYER, at(4, 2048, 40, -2048), 0)
        .unwrap();
    assert_eq!(
        s.position(PLAYER).unwrap().feet,
        FixedVec3::from_voxels(2048, 40, -2048)
    );
}

#[test]
fn the_spawn_area_is_configurable_and_reconnects_resume() {
    let cfg = ValidationConfig {
        spawn: SpawnArea {
            x: 5000,
            z: -7000,
            radius: 0,
            ..SpawnArea::default()
        },
        ..ValidationConfig::default()
    };
    let mut s = sequencer(SequencerConfig::default(), cfg);
    s.session_joined(PLAYER, "p".into(), Role::Player);
    assert!(matches!(
        s.update_position(PLAYER, at(1, 5001, 40, -7000), 0),
        Err(PositionReject::OutsideSpawn { radius: 0, .. })
    ));
    s.update_position(PLAYER, at(2, 5000, 40, -7000), 0)
        .unwrap();
    // The player leaves and comes back: it resumes where it stood, and a
    // second live session of it starts from the first one's position.
    s.session_left(PLAYER);
    s.session_joined(PLAYER + 1, "p".into(), Role::Player);
    let feet = FixedVec3::from_voxels(5000, 40, -7000);
    assert_eq!(
        s.resume_position(PLAYER + 1, 10, None),
        Start::Resume { feet }
    );
    s.update_position(PLAYER + 1, at(1, 5010, 40, -7000), 1_000)
        .unwrap();
    s.session_joined(PLAYER + 2, "p".into(), Role::Player);
    assert_eq!(
        s.resume_position(PLAYER + 2, 1_000, None),
        Start::Resume {
            feet: FixedVec3::from_voxels(5010, 40, -7000)
        }
    );
}

#[test]
fn sessions_are_indexed_by_player_and_resume_from_their_own() {
    let mut s = sequencer(SequencerConfig::default(), ValidationConfig::default());
    s.session_joined(1, "p".into(), Role::Player);
    s.session_joined(2, "q".into(), Role::Player);
    s.session_joined(3, "p".into(), Role::Player);
    assert_eq!(s.sessions_of("p"), [1, 3]);
    assert_eq!(s.sessions_of("q"), [2]);
    // An id joined again under another player moves to it.
    s.session_joined(3, "q".into(), Role::Player);
    assert_eq!(
        (s.sessions_of("p"), s.sessions_of("q")),
        (&[1][..], &[2, 3][..])
    );
    s.session_left(1);
    assert!(s.sessions_of("p").is_empty());
    // Another player's position is no one else's to resume from.
    s.update_position(2, at(1, 100, 0, 100), 0).unwrap();
    s.session_joined(4, "p".into(), Role::Player);
    assert_eq!(s.resume_position(4, 10, None), SpawnArea::default().start());
    s.update_position(4, at(1, 50, 0, 50), 0).unwrap();
    s.session_joined(5, "p".into(), Role::Player);
    let feet = FixedVec3::from_voxels(50, 0, 50);
    assert_eq!(s.resume_position(5, 10, None), Start::Resume { feet });
    for id in 2..=5 {
        s.session_left(id);
    }
    assert!(s.sessions_of("p").is_empty() && s.sessions_of("q").is_empty());
}

#[test]
fn speed_limit_with_slack() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 0, 0, 0), 0).unwrap();
    // Default: 20 voxels/s, +25 %, +2 voxels: 27 voxels allowed after 1 s.
    s.update_position(PLAYER, at(2, 26, 0, 0), 1_000).unwrap();
    // That move spent 1 of the 2 slack voxels; 100 ms refill 0.8 of it:
    // 2.5 voxels of speed and 1.8 of slack.
    match s.update_position(PLAYER, at(3, 36, 0, 0), 1_100) {
        Err(PositionReject::TooFast { distance, allowed }) => {
            assert!((distance - 10.0).abs() < 1e-9);
            assert!((allowed - 4.3).abs() < 1e-9, "{allowed}");
        }
        other => panic!("expected TooFast, got {other:?}"),
    }
    assert_eq!(
        s.position(PLAYER).unwrap().feet,
        FixedVec3::from_voxels(26, 0, 0)
    );
    // Measured from the last validated position and its time.
    s.update_position(PLAYER, at(4, 36, 0, 0), 1_500).unwrap();
}

#[test]
fn a_silence_buys_no_more_than_max_move_ms_of_walking() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 0, 0, 0), 0).unwrap();
    // A minute quiet: 20 voxels/s, +25 %, +2 voxels over 2 s (the cap),
    // not over 60 s.
    match s.update_position(PLAYER, at(2, 1_000, 0, 0), 60_000) {
        Err(PositionReject::TooFast { distance, allowed }) => {
            assert!((distance - 1_000.0).abs() < 1e-9);
            assert!((allowed - 52.0).abs() < 1e-9, "{allowed}");
        }
        other => panic!("expected TooFast, got {other:?}"),
    }
    s.update_position(PLAYER, at(3, 52, 0, 0), 60_000).unwrap();
    // Configurable.
    let cfg = ValidationConfig {
        max_move_ms: 10_000,
        ..ValidationConfig::default()
    };
    let mut s = sequencer(SequencerConfig::default(), cfg);
    s.session_joined(PLAYER, "p".into(), Role::Player);
    s.update_position(PLAYER, at(1, 0, 0, 0), 0).unwrap();
    s.update_position(PLAYER, at(2, 252, 0, 0), 60_000).unwrap();
}

#[test]
fn reports_close_together_share_one_slack() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 0, 0, 0), 0).unwrap();
    // A hundred reports in one millisecond, each a voxel on: each used to
    // get the whole 2-voxel slack (a 100-voxel jump); now they share it.
    let mut x = 0;
    for seq in 2..102 {
        if s.update_position(PLAYER, at(seq, x + 1, 0, 0), 1).is_ok() {
            x += 1;
        }
    }
    assert_eq!(x, 2, "the slack's two voxels, once");
    // It refills in SLACK_REFILL_MS: a quarter second on, 6.25 voxels of
    // speed and the whole slack again, but no more.
    assert!(matches!(
        s.update_position(PLAYER, at(200, x + 9, 0, 0), 251),
        Err(PositionReject::TooFast { .. })
    ));
    s.update_position(PLAYER, at(201, x + 8, 0, 0), 251)
        .unwrap();
}

#[test]
fn stale_reports_are_ignored() {
    let mut s = fresh();
    s.update_position(PLAYER, at(5, 0, 0, 0), 0).unwrap();
    assert_eq!(
        s.update_position(PLAYER, at(5, 1, 0, 0), 100),
        Err(PositionReject::Stale { seq: 5, last: 5 })
    );
    assert_eq!(
        s.update_position(PLAYER, at(4, 1, 0, 0), 100),
        Err(PositionReject::Stale { seq: 4, last: 5 })
    );
    assert_eq!(s.position(PLAYER).unwrap().seq, 5);
}

#[test]
fn bounds_and_unknown_sessions() {
    let mut s = fresh();
    assert_eq!(
        s.update_position(PLAYER, at(1, 0, 100_000, 0), 0),
        Err(PositionReject::OutOfBounds)
    );
    let wild = PositionUpdate {
        seq: 2,
        pos: FixedVec3::new(Fixed(i32::MAX), Fixed(0), Fixed(0)),
    };
    assert_eq!(
        s.update_position(PLAYER, wild, 0),
        Err(PositionReject::OutOfBounds)
    );
    assert_eq!(
        s.update_position(42, at(1, 0, 0, 0), 0),
        Err(PositionReject::UnknownSession)
    );
}

#[test]
fn eye_inside_a_wall_is_solid() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    // A brick slab at eye height only (y = 2), above the player's next spot.
    s.submit(ADMIN, req(1, fill((x + 3, 2, z), (x + 3, 2, z))), 0)
        .unwrap();
    s.tick(0);
    assert_eq!(
        s.update_position(PLAYER, at(2, x + 3, 0, z), 1_000),
        Err(PositionReject::InsideSolid {
            voxel: VoxelPos::new(x + 3, 2, z)
        })
    );
    s.update_position(PLAYER, at(3, x + 2, 0, z), 1_000)
        .unwrap();
}

#[test]
fn the_precheck_refuses_far_jumps_without_touching_terrain() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 100, 40, 100), 0).unwrap();
    let resident = s.resident();
    // 5000 voxels in 50 ms, then a stale report, then below the world.
    assert!(matches!(
        s.precheck_position(PLAYER, &at(2, 5100, 40, 100), 50),
        Err(PositionReject::TooFast { .. })
    ));
    assert!(matches!(
        s.precheck_position(PLAYER, &at(1, 101, 40, 100), 50),
        Err(PositionReject::Stale { .. })
    ));
    assert_eq!(
        s.precheck_position(PLAYER, &at(3, 100, -100_000, 100), 50),
        Err(PositionReject::OutOfBounds)
    );
    assert_eq!(s.resident(), resident, "nothing was loaded or generated");
    assert_eq!(
        s.precheck_position(PLAYER, &at(4, 101, 40, 100), 50),
        Ok(())
    );
    assert_eq!(
        s.precheck_position(99, &at(1, 0, 40, 0), 0),
        Err(PositionReject::UnknownSession)
    );
}

#[test]
fn a_reconnect_resumes_where_the_player_left() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 100, 40, 100), 0).unwrap();
    s.session_left(PLAYER);
    // A new session of the same player, 10 s later: it starts where the
    // player was, and its first report is a move from there.
    let again = 7;
    s.session_joined(again, "p".into(), Role::Player);
    s.resume_position(again, 10_000, None);
    assert_eq!(
        s.position(again).unwrap().feet,
        FixedVec3::from_voxels(100, 40, 100)
    );
    assert!(matches!(
        s.update_position(again, at(1, 5100, 40, 100), 10_050),
        Err(PositionReject::TooFast { .. })
    ));
    s.update_position(again, at(2, 101, 40, 100), 10_050)
        .unwrap();
    // A player never seen may start anywhere.
    s.session_joined(8, "new".into(), Role::Player);
    s.resume_position(8, 10_000, None);
    assert_eq!(s.position(8), None);
}

/// An arrival counts the ticket's age at arrival on top of the cap (the
/// player walked on meanwhile, on the node that issued it), for the first
/// move only; a silence after it buys no more than the cap.
#[test]
fn an_arrival_allows_the_tickets_age_and_no_silence_after_it() {
    let spot = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    let run = |s: &mut Sequencer, id: u64, taken: u64, report: u64, dx: i32| {
        s.session_joined(id, "p".into(), Role::Player);
        assert_eq!(
            s.resume_position(id, taken, None),
            SpawnArea::default().start()
        );
        assert!(s.arrive(id, spot, 1_000, taken).is_ok());
        s.update_position(id, at(1, HOME.0 + dx, 0, HOME.1), report)
    };
    // Taken 10 s after its issue, reported at once: the 10 s since the
    // issue count (20 voxels/s, +25 %) with the 2 voxels of slack, 252
    // voxels, though above the 2 s cap.
    let mut s = fresh();
    s.session_left(PLAYER);
    let r = run(&mut s, 7, 11_000, 11_000, 252);
    assert!(r.is_ok(), "{r:?}");
    let mut s = fresh();
    s.session_left(PLAYER);
    assert!(matches!(
        run(&mut s, 7, 11_000, 11_000, 253),
        Err(PositionReject::TooFast { .. })
    ));
    // Taken at once, then a minute quiet: 2 s, not 61 s.
    let mut s = fresh();
    s.session_left(PLAYER);
    assert!(matches!(
        run(&mut s, 7, 1_000, 61_000, 100),
        Err(PositionReject::TooFast { .. })
    ));
    // A ticket 29 s old (they live 30 s): 12 s of its age at most, with
    // the 2 s cap, 352 voxels, but no move is longer than a path is swept
    // (256 voxels).
    let mut s = fresh();
    s.session_left(PLAYER);
    assert!(run(&mut s, 7, 30_000, 30_000, 256).is_ok());
    let mut s = fresh();
    s.session_left(PLAYER);
    assert!(matches!(
        run(&mut s, 7, 30_000, 30_000, 257),
        Err(PositionReject::TooFast { allowed, .. }) if allowed == 256.0
    ));
}

/// An arrival starts where its player was seen last, the ticket's spot or
/// a newer saved one (its issuing node saves it every second), and its
/// grace covers no more than the hand-off since: a player silent since
/// its ticket gets 3 s, not the ticket's age.
#[test]
fn an_arrival_starts_where_its_player_was_seen_last() {
    let spot = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    let walked_to = FixedVec3::from_voxels(HOME.0 + 190, 0, HOME.1);
    let arrive_seen = |feet: FixedVec3, seen_ms: u64| {
        let mut s = fresh();
        s.session_left(PLAYER);
        s.session_joined(7, "p".into(), Role::Player);
        let stored = StoredPosition {
            feet,
            known_ms: seen_ms,
        };
        s.resume_position(7, 13_000, Some(stored));
        let start = s.arrive(7, spot, 1_000, 13_000).unwrap();
        let moved = s.update_position(7, at(1, HOME.0 + 200, 0, HOME.1), 13_000);
        (start, moved)
    };
    // Saved 190 voxels on at 11 s: placed there, 10 voxels to go.
    let (start, moved) = arrive_seen(walked_to, 11_000);
    assert_eq!(start, Start::Resume { feet: walked_to });
    assert!(moved.is_ok(), "{moved:?}");
    // Saved at the ticket's own time: placed at the ticket's spot, and the
    // 12 s since allow 3 s of walking (127 voxels), not 200.
    let (start, moved) = arrive_seen(spot, 1_000);
    assert_eq!(start, Start::Resume { feet: spot });
    assert!(matches!(
        moved,
        Err(PositionReject::TooFast { allowed, .. }) if allowed < 128.0
    ));
}

/// A join that arrives with an older ticket (retried after a failed one)
/// finds the player farther than the ticket's capped age allows: refused,
/// and refused however long it reports on from there (refusals earn no
/// time past the cap), until it moves back near the ticket's spot (where
/// `PositionRefused::at` tells a client it stands).
#[test]
fn an_arrival_with_an_older_ticket_moves_back_to_it() {
    let mut s = fresh();
    s.session_left(PLAYER);
    s.session_joined(7, "p".into(), Role::Player);
    s.resume_position(7, 21_000, None);
    let spot = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    // Issued 20 s before it is taken: 12 s of it and the 2 s cap count,
    // 352 voxels; the player walked 400 at 20 voxels/s.
    s.arrive(7, spot, 1_000, 21_000).unwrap();
    let handle = |s: &mut Sequencer, report: PositionUpdate, now: u64| {
        s.precheck_position(7, &report, now)
            .and_then(|()| s.update_position(7, report, now))
    };
    for i in 0..200u32 {
        let report = at(1 + i, HOME.0 + 400 + 2 * i as i32, 0, HOME.1);
        assert!(
            matches!(
                handle(&mut s, report, 21_000 + 100 * u64::from(i)),
                Err(PositionReject::TooFast { .. })
            ),
            "report {i}"
        );
    }
    assert_eq!(s.position(7).unwrap().feet, spot, "held where it arrived");
    // The ticket's age went with the first report: 200 voxels on is more
    // than the 2 s cap allows.
    assert!(matches!(
        handle(&mut s, at(201, HOME.0 + 200, 0, HOME.1), 41_000),
        Err(PositionReject::TooFast { .. })
    ));
    // Back at the spot, then on from there.
    handle(&mut s, at(202, HOME.0 + 1, 0, HOME.1), 41_000).unwrap();
    handle(&mut s, at(203, HOME.0 + 3, 0, HOME.1), 41_100).unwrap();
}

/// A player whose reports went unhandled for a while (a stall of the
/// server, a burst of lost datagrams) is refused and keeps its position.
/// Within `max_move_ms` it catches up as it reports on: each refused
/// report is credited the time since the one before. Past it, refusals
/// earn nothing more, and the player moves back to where it is held.
#[test]
fn a_player_refused_after_a_stall_catches_up_within_the_cap() {
    // Reports 40 voxels up, without falling.
    let mut s = fresh_with(flying());
    // As the engine handles a report: the rules that read no terrain first.
    let handle = |s: &mut Sequencer, report: PositionUpdate, now: u64| {
        s.precheck_position(PLAYER, &report, now)
            .and_then(|()| s.update_position(PLAYER, report, now))
    };
    handle(&mut s, at(1, 0, 40, 0), 0).unwrap();
    // 1.01 s: 27.25 voxels allowed (20 a second, a quarter more, 2 of
    // slack) for 30.
    assert!(matches!(
        handle(&mut s, at(2, 30, 40, 0), 1_010),
        Err(PositionReject::TooFast { .. })
    ));
    // On at full speed, a report every 100 ms: 2.5 voxels more allowed
    // each time for 2 walked, so 2.75 voxels behind take 6 reports.
    let caught_up = (1..=20).find(|&i| {
        let report = at(2 + i, 30 + 2 * i as i32, 40, 0);
        handle(&mut s, report, 1_010 + 100 * u64::from(i)).is_ok()
    });
    assert_eq!(caught_up, Some(6));

    // 3 s unheard: 60 voxels, 52 allowed (the 2 s cap), and never more
    // however long it reports on.
    let held = s.position(PLAYER).unwrap();
    let t0 = held.at_ms;
    let x0 = held.feet.x.floor_voxel();
    for i in 0..50u32 {
        let report = at(100 + i, x0 + 60 + 2 * i as i32, 40, 0);
        let r = handle(&mut s, report, t0 + 3_000 + 100 * u64::from(i));
        assert!(
            matches!(r, Err(PositionReject::TooFast { allowed, .. }) if allowed <= 52.0),
            "report {i}: {r:?}"
        );
    }
    assert_eq!(s.position(PLAYER).unwrap().feet, held.feet);
    handle(&mut s, at(200, x0 + 2, 40, 0), t0 + 8_000).unwrap();
}

/// Refusals earn no more than `max_move_ms`: a minute of refused reports
/// does not buy a move of a minute's walk (through any wall).
#[test]
fn a_minute_of_refused_reports_buys_no_far_move() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, 0, 40, 0), 0).unwrap();
    for i in 0..600u32 {
        let now = 100 * u64::from(i + 1);
        // Far off, each refused.
        let far = at(2 + i, 5_000, 40, 0);
        assert!(s.precheck_position(PLAYER, &far, now).is_err());
    }
    let r = s.precheck_position(PLAYER, &at(700, 100, 40, 0), 60_100);
    assert!(
        matches!(r, Err(PositionReject::TooFast { allowed, .. }) if allowed <= 52.0),
        "{r:?}"
    );
}

/// A wall between the held position and a report within speed's reach:
/// refused whichever way the body could have gone, and the position stays.
#[test]
fn a_report_beyond_a_wall_is_refused_for_its_path() {
    for thickness in [1, 5] {
        // Gravity off: this is the path rule's test (over the top too).
        let mut s = ready(flying());
        let (x, z) = HOME;
        s.submit(
            ADMIN,
            req(1, fill((x + 3, 0, z - 8), (x + 2 + thickness, 6, z + 8))),
            0,
        )
        .unwrap();
        s.tick(0);
        let beyond = at(2, x + 4 + thickness, 0, z);
        let r = s.update_position(PLAYER, beyond, 1_000);
        assert!(
            matches!(r, Err(PositionReject::PathBlocked { voxel })
                if voxel.x == x + 3 && voxel.z == z),
            "{thickness} thick: {r:?}"
        );
        assert_eq!(
            s.position(PLAYER).unwrap().feet,
            FixedVec3::from_voxels(x, 0, z)
        );
        assert_eq!(
            r.unwrap_err().refusal(),
            Some(strata_protocol::PositionRefusal::PathBlocked {
                voxel: VoxelPos::new(x + 3, 1, z)
            })
        );
        // Over the top of it (7 voxels up): the way up is clear, so is the
        // way across above the wall.
        s.update_position(PLAYER, at(3, x + 4 + thickness, 7, z), 1_000)
            .unwrap();
        // And down again, by the way across first.
        s.update_position(PLAYER, at(4, x + 5 + thickness, 0, z), 1_500)
            .unwrap();
    }
}

/// Over a mound lower than [`HOP_VOXELS`] between two reports: the way up,
/// across and down again; a higher one blocks.
#[test]
fn a_mound_is_stepped_over_between_two_reports() {
    use strata_server::validate::sweep::HOP_VOXELS;
    for (height, passes) in [(HOP_VOXELS as i32, true), (HOP_VOXELS as i32 + 2, false)] {
        let mut s = ready(ValidationConfig::default());
        let (x, z) = HOME;
        // Solid from y = 0 to `height - 1`: the body (one voxel above the
        // feet, the eye) clears it `HOP_VOXELS` above the ground.
        s.submit(
            ADMIN,
            req(1, fill((x + 2, 0, z - 4), (x + 2, height - 1, z + 4))),
            0,
        )
        .unwrap();
        s.tick(0);
        let r = s.update_position(PLAYER, at(2, x + 4, 0, z), 1_000);
        assert_eq!(r.is_ok(), passes, "{height} high: {r:?}");
    }
}

/// A cluster node sweeps a move only through the regions it names (its
/// own and free ones): its copies of another node's may be behind (the
/// wall mined there).
#[test]
fn a_cluster_node_sweeps_only_the_regions_it_names() {
    use strata_server::sequencer::regions::RegionId;
    let (x, z) = HOME;
    let wall = |s: &mut Sequencer| {
        s.submit(ADMIN, req(1, fill((x + 3, 0, z - 8), (x + 5, 6, z + 8))), 0)
            .unwrap();
        s.tick(0);
    };
    let side = SequencerConfig::default().region_chunks;
    let home = RegionId::of(VoxelPos::new(x + 4, 0, z).chunk(), side);
    let mut s = ready(ValidationConfig::default());
    wall(&mut s);
    s.set_swept_regions(Some([home].into_iter().collect()));
    assert!(matches!(
        s.update_position(PLAYER, at(2, x + 8, 0, z), 1_000),
        Err(PositionReject::PathBlocked { .. })
    ));
    let mut s = ready(ValidationConfig::default());
    wall(&mut s);
    let elsewhere = RegionId::of(VoxelPos::new(x + 4, 0, z + 1000).chunk(), side);
    s.set_swept_regions(Some([elsewhere].into_iter().collect()));
    s.update_position(PLAYER, at(2, x + 8, 0, z), 1_000)
        .unwrap();
}

/// A spot in a region another node holds (air to this one) is taken, but
/// what leaves the node, in tickets and stored positions, is the last
/// spot it judged: the other node sweeps the way on from there.
#[test]
fn only_spots_a_cluster_node_judged_leave_it() {
    use strata_server::sequencer::regions::RegionId;
    let (x, z) = HOME;
    let side = SequencerConfig::default().region_chunks;
    let region = |x: i32| RegionId::of(VoxelPos::new(x, 0, z).chunk(), side);
    let mut s = ready(ValidationConfig::default());
    s.set_swept_regions(Some([region(x)].into_iter().collect()));
    s.update_position(PLAYER, at(2, x + 2, 0, z), 1_000)
        .unwrap();
    let judged = FixedVec3::from_voxels(x + 2, 0, z);
    assert_eq!(s.judged_position(PLAYER).unwrap().feet, judged);
    // The region is another node's now (or one whose holder this node
    // has not read): not swept.
    let elsewhere = region(x + 1000);
    s.set_swept_regions(Some([elsewhere].into_iter().collect()));
    s.update_position(PLAYER, at(3, x + 4, 0, z), 1_500)
        .unwrap();
    let taken = FixedVec3::from_voxels(x + 4, 0, z);
    assert_eq!(s.position(PLAYER).unwrap().feet, taken);
    assert_eq!(s.judged_position(PLAYER).unwrap().feet, judged);
    let stored: Vec<FixedVec3> = s
        .take_moved()
        .into_iter()
        .filter(|(player, _)| player == &format!("p{PLAYER}"))
        .map(|(_, p)| p.feet)
        .collect();
    assert_eq!(stored, [judged]);
    // A second session of the player on this node starts there too.
    s.session_joined(9, format!("p{PLAYER}"), Role::Player);
    assert_eq!(
        s.resume_position(9, 1_600, None),
        Start::Resume { feet: judged }
    );
    // Alone on its store, a node judges every spot.
    s.set_swept_regions(None);
    s.update_position(PLAYER, at(4, x + 5, 0, z), 2_000)
        .unwrap();
    let here = FixedVec3::from_voxels(x + 5, 0, z);
    assert_eq!(s.judged_position(PLAYER).unwrap().feet, here);
}

/// An arrival's first move is swept like any other, from where it was
/// placed: a ticket carries no way through a wall.
#[test]
fn an_arrivals_first_move_is_swept() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    s.submit(ADMIN, req(1, fill((x + 3, 0, z - 8), (x + 5, 6, z + 8))), 0)
        .unwrap();
    s.tick(0);
    s.session_joined(7, "q".into(), Role::Player);
    s.resume_position(7, 1_000, None);
    s.arrive(7, FixedVec3::from_voxels(x, 0, z), 500, 1_000)
        .unwrap();
    assert!(matches!(
        s.update_position(7, at(1, x + 8, 0, z), 1_000),
        Err(PositionReject::PathBlocked { .. })
    ));
    // On its side of the wall it walks on.
    s.update_position(7, at(2, x - 2, 0, z), 1_100).unwrap();
}

/// A step onto a ledge and off it between two reports: the straight way
/// cuts the ledge's corner, a bent one (up, then across; across, then
/// down) does not.
#[test]
fn a_ledge_is_climbed_and_left_between_two_reports() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    // A block 4 high (a jump) from x + 1 on: its top is at y = 4.
    s.submit(ADMIN, req(1, fill((x + 1, 0, z - 4), (x + 8, 3, z + 4))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(2, x + 2, 4, z), 500).unwrap();
    s.update_position(PLAYER, at(3, x, 0, z), 1_000).unwrap();
    // Across the whole block: not through it, but a hop over its top (a
    // jump high, within the apex).
    s.update_position(PLAYER, at(4, x + 9, 0, z), 2_000)
        .unwrap();
}

/// Round a corner between two reports: the straight way cuts it, the way
/// along x first, then z, does not.
#[test]
fn a_corner_is_run_round_between_two_reports() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    // Solid over x - 10 ..= x, z - 10 ..= z, 7 high: its corner at (x, z).
    s.submit(ADMIN, req(1, fill((x - 10, 0, z - 10), (x, 6, z))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(2, x - 1, 0, z + 1), 500)
        .unwrap();
    s.update_position(PLAYER, at(3, x + 1, 0, z - 1), 1_000)
        .unwrap();
}

/// A tall body (`eye_height` 4) does not slip through a slot a voxel high
/// at its eye: every voxel between one above the feet and the eye is swept.
#[test]
fn a_tall_body_is_swept_whole() {
    let cfg = ValidationConfig {
        eye_height: 4.0,
        ..ValidationConfig::default()
    };
    let mut s = ready(cfg);
    let (x, z) = HOME;
    // Solid at y 2..=3 and 5..=12, open at 0, 1 and 4.
    s.submit(ADMIN, req(1, fill((x + 3, 2, z - 8), (x + 3, 3, z + 8))), 0)
        .unwrap();
    s.submit(
        ADMIN,
        req(2, fill((x + 3, 5, z - 8), (x + 3, 12, z + 8))),
        0,
    )
    .unwrap();
    s.tick(0);
    assert_eq!(
        s.update_position(PLAYER, at(2, x + 6, 0, z), 1_000),
        Err(PositionReject::PathBlocked {
            voxel: VoxelPos::new(x + 3, 2, z)
        })
    );
    // Built around at its middle (feet + 2): it walks out.
    s.submit(ADMIN, req(3, fill((x, 2, z), (x, 2, z))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(3, x - 1, 0, z), 1_500)
        .unwrap();
}

/// Over a bump in a low tunnel: the lowest hop that clears the bump stays
/// under the ceiling.
#[test]
fn a_bump_under_a_low_ceiling_is_stepped_over() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    // Ceiling from y = 5 up, a bump 2 high at x + 2.
    s.submit(ADMIN, req(1, fill((x - 4, 5, z - 4), (x + 8, 8, z + 4))), 0)
        .unwrap();
    s.submit(ADMIN, req(2, fill((x + 2, 0, z - 4), (x + 2, 1, z + 4))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(2, x + 4, 0, z), 1_000)
        .unwrap();
}

/// No hop leaves the world: a wall up to `max_y` is not passed over its
/// top through voxels above the world.
#[test]
fn a_wall_up_to_the_top_of_the_world_is_not_hopped() {
    let top = 10;
    let cfg = ValidationConfig {
        bounds: strata_server::validate::WorldBounds {
            min_y: -128,
            max_y: top,
        },
        ..flying()
    };
    let mut s = ready(cfg);
    let (x, z) = HOME;
    s.submit(
        ADMIN,
        req(1, fill((x + 3, 0, z - 4), (x + 3, top, z + 4))),
        0,
    )
    .unwrap();
    s.tick(0);
    // Feet 3 below the top: one voxel above them and the eye in the world.
    s.update_position(PLAYER, at(2, x, top - 3, z), 1_000)
        .unwrap();
    assert!(matches!(
        s.update_position(PLAYER, at(3, x + 6, top - 3, z), 2_000),
        Err(PositionReject::PathBlocked { .. })
    ));
}

/// A player something was built around may walk out of it: the body's
/// own voxels at the held position do not block its way.
#[test]
fn a_player_built_around_walks_out() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    s.submit(ADMIN, req(1, fill((x, 1, z), (x, 2, z))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(2, x + 1, 0, z), 500).unwrap();
}

#[test]
fn remembering_more_players_than_the_cap_forgets_those_known_longest_ago() {
    let cfg = ValidationConfig {
        remembered_players: 3,
        ..ValidationConfig::default()
    };
    let mut s = sequencer(SequencerConfig::default(), cfg);
    // Four players leave, known at 4, 1, 3 and 2 s: the one known at 1 s
    // is forgotten when the fourth is remembered, whatever the map's order.
    for (id, (name, t)) in [("a", 4_000), ("b", 1_000), ("c", 3_000), ("d", 2_000)]
        .into_iter()
        .enumerate()
    {
        let id = 100 + id as u64;
        s.session_joined(id, name.into(), Role::Player);
        s.update_position(id, at(1, 10 * id as i32, 40, 0), t)
            .unwrap();
        s.session_left(id);
    }
    for (id, name) in ["a", "b", "c", "d"].into_iter().enumerate() {
        let again = 200 + id as u64;
        s.session_joined(again, name.into(), Role::Player);
        s.resume_position(again, 5_000, None);
        assert_eq!(s.position(again).is_some(), name != "b", "{name}");
    }
}

#[test]
fn refusals_name_the_rule_and_stale_reports_get_none() {
    use strata_protocol::PositionRefusal;
    let mut s = fresh();
    let far = s
        .update_position(PLAYER, at(1, 5000, 40, 0), 0)
        .unwrap_err();
    assert_eq!(
        far.refusal(),
        Some(PositionRefusal::OutsideSpawn {
            x: 0,
            z: 0,
            radius: 2048
        })
    );
    let high = s
        .update_position(PLAYER, at(2, 0, 100_000, 0), 0)
        .unwrap_err();
    assert_eq!(high.refusal(), Some(PositionRefusal::OutOfBounds));
    s.update_position(PLAYER, at(5, 0, 40, 0), 0).unwrap();
    let fast = s
        .update_position(PLAYER, at(6, 100, 40, 0), 1000)
        .unwrap_err();
    assert_eq!(
        fast.refusal(),
        Some(PositionRefusal::TooFast {
            distance: Fixed(100 * 256),
            allowed: Fixed::from_f64(20.0 * 1.25 + 2.0).unwrap(),
        })
    );
    let stale = s
        .update_position(PLAYER, at(5, 0, 40, 0), 2000)
        .unwrap_err();
    assert_eq!(stale.refusal(), None, "stale reports get no answer");
    assert_eq!(PositionReject::UnknownSession.refusal(), None);
}

/// Walks session `id` east from `from` 20 voxels a second (within the
/// default 25 a second) for `seconds`, reporting once a second from `t0`
/// with seqs from 2.
fn walk_east(s: &mut Sequencer, id: u64, from: (i32, i32), t0: u64, seconds: u32) {
    for i in 1..=seconds {
        let x = from.0 + 20 * i as i32;
        s.update_position(id, at(1 + i, x, 0, from.1), t0 + u64::from(i) * 1000)
            .expect("a legal walk");
    }
}

#[test]
fn an_older_ticket_never_rewinds_a_resumed_player() {
    let mut s = fresh();
    // At A at t = 0 (when a ticket for A was issued), then 500 voxels east
    // to B by t = 25 s.
    let a = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    s.update_position(PLAYER, at(1, HOME.0, 0, HOME.1), 0)
        .unwrap();
    walk_east(&mut s, PLAYER, HOME, 0, 25);
    let b = FixedVec3::from_voxels(HOME.0 + 500, 0, HOME.1);
    s.session_left(PLAYER);
    let again = 7;
    s.session_joined(again, "p".into(), Role::Player);
    assert_eq!(
        s.resume_position(again, 26_000, None),
        Start::Resume { feet: b }
    );
    // The ticket for A would time the player from t = 0 and let it jump
    // ~600 voxels past A: refused, and the resume stands.
    assert_eq!(s.arrive(again, a, 0, 0), Err(TicketRefusal::AlreadyPlaced));
    assert_eq!(s.position(again).unwrap().feet, b);
    assert!(matches!(
        s.update_position(again, at(1, HOME.0 - 600, 0, HOME.1), 26_000),
        Err(PositionReject::TooFast { .. })
    ));
    // Still refused after another reconnect without a report: the resume
    // keeps when the player was last seen.
    s.session_left(again);
    s.session_joined(8, "p".into(), Role::Player);
    s.resume_position(8, 27_000, None);
    assert_eq!(s.arrive(8, a, 0, 0), Err(TicketRefusal::AlreadyPlaced));
    // A ticket newer than the last report (another node saw the player
    // since) is taken, once.
    let c = FixedVec3::from_voxels(HOME.0 + 520, 0, HOME.1);
    assert_eq!(
        s.arrive(8, c, 26_000, 26_000),
        Ok(Start::Resume { feet: c })
    );
    assert_eq!(s.position(8).unwrap().feet, c);
    assert_eq!(
        s.arrive(8, c, 26_500, 26_500),
        Err(TicketRefusal::AlreadyPlaced)
    );
    s.update_position(8, at(1, HOME.0 + 530, 0, HOME.1), 27_000)
        .unwrap();
}

#[test]
fn a_stored_position_newer_than_this_nodes_bounds_tickets_and_resumes_there() {
    // Another node had the player since: it stored B at t = 25 s. This
    // node never saw the player.
    let mut s = fresh();
    let a = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    let b = FixedVec3::from_voxels(HOME.0 + 500, 0, HOME.1);
    let stored = StoredPosition {
        feet: b,
        known_ms: 25_000,
    };
    s.session_joined(7, "p".into(), Role::Player);
    assert_eq!(
        s.resume_position(7, 26_000, Some(stored)),
        Start::Resume { feet: b }
    );
    // A ticket for A issued at t = 0 would rewind the player: refused.
    assert_eq!(s.arrive(7, a, 0, 0), Err(TicketRefusal::AlreadyPlaced));
    assert_eq!(s.position(7).unwrap().feet, b);
    // One issued shortly before the other node saved (the player walked
    // on a little after its latest ticket) is taken.
    s.session_joined(9, "q".into(), Role::Player);
    s.resume_position(9, 26_000, Some(stored));
    let issued = 25_000 - STORED_TICKET_SLACK_MS + 1;
    assert_eq!(
        s.arrive(9, b, issued, issued),
        Ok(Start::Resume { feet: b })
    );
    // A time from another node's clock running ahead counts as now.
    let ahead = StoredPosition {
        feet: b,
        known_ms: 90_000,
    };
    s.session_joined(10, "r".into(), Role::Player);
    s.resume_position(10, 26_000, Some(ahead));
    assert_eq!(s.arrive(10, b, 0, 0), Err(TicketRefusal::AlreadyPlaced));
    let issued = 26_000 - STORED_TICKET_SLACK_MS + 1;
    assert_eq!(
        s.arrive(10, b, issued, issued),
        Ok(Start::Resume { feet: b })
    );
    // An older stored position loses to what this node remembers.
    let mut s = fresh();
    s.update_position(PLAYER, at(1, HOME.0, 0, HOME.1), 30_000)
        .unwrap();
    s.session_left(PLAYER);
    s.session_joined(8, "p".into(), Role::Player);
    assert_eq!(
        s.resume_position(8, 31_000, Some(stored)),
        Start::Resume { feet: a }
    );
}

#[test]
fn a_ticket_never_moves_a_player_that_reported() {
    let mut s = fresh();
    let far = FixedVec3::from_voxels(HOME.0 + 1000, 0, HOME.1);
    // A first report with seq 0 is accepted as any first report...
    s.update_position(PLAYER, at(0, HOME.0, 0, HOME.1), 1_000)
        .unwrap();
    // ...and still places the player: a ticket, even a newer one, is refused.
    assert_eq!(
        s.arrive(PLAYER, far, 2_000, 2_000),
        Err(TicketRefusal::AlreadyPlaced)
    );
    // Another seq 0 after it is stale.
    assert_eq!(
        s.update_position(PLAYER, at(0, HOME.0 + 1, 0, HOME.1), 1_500),
        Err(PositionReject::Stale { seq: 0, last: 0 })
    );
    // The same after a report on a resumed session.
    s.session_left(PLAYER);
    s.session_joined(9, "p".into(), Role::Player);
    s.resume_position(9, 3_000, None);
    s.update_position(9, at(1, HOME.0 + 2, 0, HOME.1), 3_100)
        .unwrap();
    assert_eq!(
        s.arrive(9, far, 3_200, 3_200),
        Err(TicketRefusal::AlreadyPlaced)
    );
    assert_eq!(
        s.position(9).unwrap().feet,
        FixedVec3::from_voxels(HOME.0 + 2, 0, HOME.1)
    );
}

#[test]
fn a_ticket_older_than_another_sessions_report_is_refused() {
    let mut s = fresh();
    s.update_position(PLAYER, at(1, HOME.0, 0, HOME.1), 0)
        .unwrap();
    // A second session of the player (`sessions_per_player` > 1) resumes
    // there, and the first walks on for 5 s.
    s.session_joined(5, "p".into(), Role::Player);
    s.resume_position(5, 1_000, None);
    walk_east(&mut s, PLAYER, HOME, 0, 5);
    let a = FixedVec3::from_voxels(HOME.0, 0, HOME.1);
    assert_eq!(
        s.arrive(5, a, 1_000, 1_000),
        Err(TicketRefusal::AlreadyPlaced)
    );
    assert_eq!(
        s.arrive(5, a, 4_999, 4_999),
        Err(TicketRefusal::AlreadyPlaced)
    );
    let b = FixedVec3::from_voxels(HOME.0 + 100, 0, HOME.1);
    assert_eq!(s.arrive(5, b, 5_000, 5_000), Ok(Start::Resume { feet: b }));
}

/// A session with no position yet may claim any spot in the spawn square
/// at any height, and each claim loads (or generates) the chunks around
/// the body before it can be refused: the player's placements are
/// bounded by `[validation.placement_rate]`, shared by its sessions. A
/// placed session is not charged.
#[test]
fn placements_of_a_player_with_no_position_are_bounded() {
    let mut s = fresh();
    let burst = ValidationConfig::default().placement_rate.capacity;
    let per_second = ValidationConfig::default().placement_rate.per_second;
    for _ in 0..burst {
        s.charge_placement(PLAYER, 0).unwrap();
    }
    assert_eq!(
        s.charge_placement(PLAYER, 0),
        Err(PositionReject::PlacementLimited)
    );
    // Another session of the player draws on the same bucket.
    s.session_joined(2, "p".into(), Role::Player);
    assert_eq!(
        s.charge_placement(2, 0),
        Err(PositionReject::PlacementLimited)
    );
    // It refills; once placed, reports are not charged.
    let refill_ms = 1000 / per_second;
    s.charge_placement(PLAYER, refill_ms).unwrap();
    s.update_position(PLAYER, at(1, HOME.0, 0, HOME.1), refill_ms)
        .unwrap();
    for _ in 0..3 * burst {
        s.charge_placement(PLAYER, refill_ms).unwrap();
    }
    assert_eq!(PositionReject::PlacementLimited.refusal(), None);
}

/// A wall 12 voxels high (solid from the ground to y = 11) at x + 3.
fn tall_wall(s: &mut Sequencer) {
    let (x, z) = HOME;
    s.submit(
        ADMIN,
        req(1, fill((x + 3, 0, z - 8), (x + 3, 11, z + 8))),
        0,
    )
    .unwrap();
    s.tick(0);
}

/// Gravity: a player may rise a jump above the ground, no higher, so a
/// wall taller than that is no way across; an admin flies.
#[test]
fn a_player_rises_a_jump_and_no_more_an_admin_flies() {
    use strata_server::validate::gravity::DEFAULT_JUMP_VOXELS;
    let mut s = ready(ValidationConfig::default());
    tall_wall(&mut s);
    let (x, z) = HOME;
    let jump = DEFAULT_JUMP_VOXELS as i32;
    s.update_position(PLAYER, at(2, x, jump, z), 500).unwrap();
    assert_eq!(
        s.update_position(PLAYER, at(3, x, 13, z), 1_000),
        Err(PositionReject::TooHigh {
            apex: f64::from(jump)
        })
    );
    assert_eq!(
        s.position(PLAYER).map(|p| p.feet),
        Some(at(2, x, jump, z).pos)
    );
    // The admin goes up and over, and down the far side.
    let ax = x - 2;
    s.update_position(ADMIN, at(2, ax, 13, z), 1_000).unwrap();
    s.update_position(ADMIN, at(3, x + 6, 13, z), 1_500)
        .unwrap();
    s.update_position(ADMIN, at(4, x + 6, 0, z), 3_000).unwrap();
}

/// Standing on the top of a wall higher than a jump above the last report
/// is refused too (it stood there in one move); a standing report a jump
/// up passes. And no hop of the path goes above the apex.
#[test]
fn a_wall_top_beyond_a_jump_is_no_footing() {
    let mut s = ready(ValidationConfig::default());
    tall_wall(&mut s);
    let (x, z) = HOME;
    // The wall's top (solid to y = 11): feet at 12, standing.
    assert_eq!(
        s.update_position(PLAYER, at(2, x + 3, 12, z), 1_000),
        Err(PositionReject::TooHigh { apex: 4.0 })
    );
    // A wall solid to y = 6 and a report past it at the apex: a hop over
    // the wall would need the feet at 7 or more, above the apex 4.
    let mut s = ready(ValidationConfig::default());
    s.submit(ADMIN, req(1, fill((x + 3, 0, z - 8), (x + 3, 6, z + 8))), 0)
        .unwrap();
    s.tick(0);
    assert!(matches!(
        s.update_position(PLAYER, at(2, x + 6, 4, z), 1_000),
        Err(PositionReject::PathBlocked { .. })
    ));
    // Standing on it, a jump up from the ground (feet 7, top 6): passes.
    let mut s = ready(ValidationConfig::default());
    s.submit(ADMIN, req(1, fill((x + 3, 0, z - 8), (x + 3, 2, z + 8))), 0)
        .unwrap();
    s.tick(0);
    s.update_position(PLAYER, at(2, x + 3, 3, z), 1_000)
        .unwrap();
}

/// Reports lost on the way up: a standing report above the step passes
/// when ground a jump at a time leads there from the last one (stairs 3
/// high), not where no jump reaches the next step (7 high).
#[test]
fn a_climb_whose_reports_were_lost_is_caught_up_along_the_ground() {
    let (x, z) = HOME;
    let stairs = |rise: i32| {
        let mut s = ready(ValidationConfig::default());
        for k in 1..=4 {
            let (x0, top) = (x + 2 * k - 1, rise * k - 1);
            let steps = fill((x0, 0, z - 4), (x0 + 1, top, z + 4));
            s.submit(ADMIN, req(k as u64, steps), 0).unwrap();
        }
        s.tick(0);
        s
    };
    // The fourth step's top at 11: feet 12 up in one report.
    let mut s = stairs(3);
    s.update_position(PLAYER, at(2, x + 8, 12, z), 1_500)
        .unwrap();
    // And a jump from there (a new step).
    s.update_position(PLAYER, at(3, x + 8, 16, z), 1_700)
        .unwrap();
    let mut s = stairs(7);
    assert_eq!(
        s.update_position(PLAYER, at(2, x + 8, 28, z), 1_500),
        Err(PositionReject::TooHigh { apex: 4.0 })
    );
    // A tower without stairs (floors every 4 voxels, a roof, a wall on
    // its far side): its roof is reached by no walk, though each floor
    // is a jump above the last (the body cannot pass a floor), nor is
    // the wall's top.
    let mut s = ready(ValidationConfig::default());
    let (z0, z1) = (z - 3, z + 3);
    let parts = [
        fill((x + 10, 0, z0), (x + 10, 19, z1)),
        fill((x + 3, 3, z0), (x + 9, 3, z1)),
        fill((x + 3, 7, z0), (x + 9, 7, z1)),
        fill((x + 3, 11, z0), (x + 9, 11, z1)),
        fill((x + 3, 15, z0), (x + 9, 15, z1)),
        fill((x + 3, 19, z0), (x + 9, 19, z1)),
    ];
    // The admin flies up beside it to reach every part.
    s.update_position(ADMIN, at(2, x + 1, 10, z - 4), 1_000)
        .unwrap();
    for (k, part) in parts.into_iter().enumerate() {
        s.submit(ADMIN, req(k as u64 + 1, part), 1_000).unwrap();
    }
    s.tick(1_000);
    for (seq, (dx, dz)) in [(5, 2), (10, 2)].into_iter().enumerate() {
        assert_eq!(
            s.update_position(PLAYER, at(seq as u32 + 2, x + dx, 20, z + dz), 2_000),
            Err(PositionReject::TooHigh { apex: 4.0 })
        );
    }
}

/// A catch-up walk starts on the ground under the held feet: a player
/// held in the air over a low wall is not walked from inside it through
/// a door the wall seals, into a walled yard and up its steps; one on the
/// ground before the door is.
#[test]
fn a_catch_up_walk_starts_on_the_ground_under_the_held_feet() {
    let (x, z) = HOME;
    let yard = |low_wall: bool| {
        let mut s = ready(ValidationConfig::default());
        let (z0, z1) = (z - 3, z + 3);
        let mut parts = vec![
            fill((x + 3, 0, z0), (x + 3, 19, z1)),
            Edit::ClearBox {
                min: VoxelPos::new(x + 3, 0, z),
                max: VoxelPos::new(x + 3, 1, z),
            },
        ];
        for k in 1..=5 {
            parts.push(fill((x + 4 + k, 0, z0), (x + 4 + k, 4 * k - 1, z1)));
        }
        if low_wall {
            parts.push(fill((x + 2, 0, z0), (x + 2, 1, z1)));
        }
        s.update_position(ADMIN, at(2, x + 1, 6, z - 4), 1_000)
            .unwrap();
        for (k, part) in parts.into_iter().enumerate() {
            s.submit(ADMIN, req(k as u64 + 1, part), 1_000).unwrap();
        }
        s.tick(1_000);
        s
    };
    let mut s = yard(true);
    s.update_position(PLAYER, at(2, x + 2, 4, z), 1_200)
        .unwrap();
    assert_eq!(
        s.update_position(PLAYER, at(3, x + 9, 20, z), 2_700),
        Err(PositionReject::TooHigh { apex: 4.0 })
    );
    let mut s = yard(false);
    s.update_position(PLAYER, at(2, x + 2, 0, z), 1_200)
        .unwrap();
    s.update_position(PLAYER, at(3, x + 9, 20, z), 2_700)
        .unwrap();
}

/// `[validation.gravity] enabled = false`: players fly.
#[test]
fn with_gravity_off_players_fly() {
    let mut v = ValidationConfig::default();
    v.gravity.enabled = false;
    let mut s = ready(v);
    tall_wall(&mut s);
    let (x, z) = HOME;
    s.update_position(PLAYER, at(2, x, 13, z), 1_000).unwrap();
    s.update_position(PLAYER, at(3, x + 6, 13, z), 1_500)
        .unwrap();
    s.update_position(PLAYER, at(4, x + 6, 13, z + 1), 9_000)
        .unwrap();
}

/// A resumed player may fall or stand, not rise, until it stands: a
/// reconnect is no fresh jump.
#[test]
fn a_resumed_player_in_the_air_may_not_rise() {
    let mut s = fresh();
    let (x, z) = HOME;
    let feet = FixedVec3::from_voxels(x, 6, z);
    s.resume_position(PLAYER, 0, Some(StoredPosition { feet, known_ms: 0 }));
    assert!(matches!(
        s.update_position(PLAYER, at(1, x, 7, z), 500),
        Err(PositionReject::TooHigh { .. })
    ));
    s.update_position(PLAYER, at(2, x, 0, z), 1_000).unwrap();
    s.update_position(PLAYER, at(3, x, 4, z), 1_200).unwrap();
}

/// A jump counts from the ground's surface: feet reported up to the
/// ground's reach above it (they still stand) gain no height.
#[test]
fn feet_reported_above_the_ground_gain_no_jump() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    let up = |seq, y: f64| PositionUpdate {
        seq,
        pos: FixedVec3::from_f64([f64::from(x), y, f64::from(z)]).unwrap(),
    };
    // 1.5 above the surface (y = 0; the top voxel is at -1): standing,
    // but the jump counts from 1 above the surface, to 5.
    s.update_position(PLAYER, up(2, 1.5), 500).unwrap();
    assert_eq!(
        s.update_position(PLAYER, up(3, 5.5), 1_000),
        Err(PositionReject::TooHigh { apex: 5.0 })
    );
}

/// A reconnect while in the air is no fresh jump: the resumed spot is
/// settled from the ground under it (none), so the player may not rise
/// above it, hop over a wall on its way, nor stand higher.
#[test]
fn a_reconnect_in_the_air_gives_no_second_jump() {
    let mut s = fresh();
    let (x, z) = HOME;
    let apex = FixedVec3::from_voxels(x, 4, z);
    s.resume_position(
        PLAYER,
        0,
        Some(StoredPosition {
            feet: apex,
            known_ms: 0,
        }),
    );
    assert_eq!(
        s.update_position(PLAYER, at(1, x + 1, 6, z), 500),
        Err(PositionReject::TooHigh { apex: 4.0 })
    );
    // Nor a hop over a wall on the way (the way's hops are held to the
    // settled state: no higher than the resumed feet), nor a step up onto
    // a ledge a jump higher.
    let mut s = fresh();
    join_at(&mut s, ADMIN, Role::Admin, x - 2, z);
    s.resume_position(
        PLAYER,
        0,
        Some(StoredPosition {
            feet: apex,
            known_ms: 0,
        }),
    );
    s.submit(ADMIN, req(1, fill((x + 2, 0, z - 4), (x + 2, 6, z + 4))), 0)
        .unwrap();
    s.submit(ADMIN, req(2, fill((x - 1, 0, z - 4), (x - 1, 7, z + 4))), 0)
        .unwrap();
    s.tick(0);
    let r = s.update_position(PLAYER, at(1, x + 4, 4, z), 500);
    assert!(
        matches!(r, Err(PositionReject::PathBlocked { .. })),
        "{r:?}"
    );
    assert!(matches!(
        s.update_position(PLAYER, at(2, x - 1, 8, z), 1_000),
        Err(PositionReject::TooHigh { .. })
    ));
    // Resumed standing on the ground, a jump up is fine.
    let mut s = fresh();
    let ground = FixedVec3::from_voxels(x, 0, z);
    s.resume_position(
        PLAYER,
        0,
        Some(StoredPosition {
            feet: ground,
            known_ms: 0,
        }),
    );
    s.update_position(PLAYER, at(1, x, 4, z), 500).unwrap();
}

/// A body needs more than a one-voxel gap: feet sunk under a wall's lowest
/// voxel (at most half a voxel into solid counts as standing) do not let
/// a one-voxel-high window, or a gate raised one voxel, through.
#[test]
fn a_one_voxel_gap_is_no_way_through() {
    let (x, z) = HOME;
    let feet = |seq, x: i32, y: f64| PositionUpdate {
        seq,
        pos: FixedVec3::from_f64([f64::from(x), y, f64::from(z)]).unwrap(),
    };
    // The ground's top voxel is at y = -1. A window: solid at 0 and from
    // 2 up, air at 1. A gate: air at 0, solid from 1 up.
    for (name, gap, sunk) in [("window", 1, -0.25), ("gate", 0, -1.25)] {
        let mut s = ready(ValidationConfig::default());
        if gap > 0 {
            s.submit(
                ADMIN,
                req(1, fill((x + 3, 0, z - 8), (x + 3, gap - 1, z + 8))),
                0,
            )
            .unwrap();
        }
        s.submit(
            ADMIN,
            req(2, fill((x + 3, gap + 1, z - 8), (x + 3, 20, z + 8))),
            0,
        )
        .unwrap();
        s.tick(0);
        // Through the window: the wall's lowest voxel is in the way. Under
        // the gate: feet that low are in the ground, there or anywhere.
        let r = s.update_position(PLAYER, feet(2, x + 6, sunk), 1_000);
        let refused = match r {
            Err(PositionReject::PathBlocked { voxel }) => voxel.x == x + 3,
            Err(PositionReject::InsideSolid { voxel }) => gap == 0 && voxel.y == -1,
            _ => false,
        };
        assert!(refused, "{name}: {r:?}");
        let here = s.update_position(PLAYER, feet(3, x, sunk), 1_000);
        assert_eq!(here.is_ok(), gap > 0, "{name}: {here:?}");
    }
}

/// No one stays up: off the ground from the first report there, a player
/// keeps its apex for `hang_ms`, then its limits sink as a fall would.
/// Running on air at the apex is refused once the hang is over; coming
/// down is not.
#[test]
fn a_player_off_the_ground_comes_down_after_the_hang() {
    let mut s = ready(ValidationConfig::default());
    let (x, z) = HOME;
    let hang = ValidationConfig::default().gravity.hang_ms;
    let t0 = 1_000;
    // A jump: 4 above the feet (the ground's top voxel is at y = -1).
    s.update_position(PLAYER, at(2, x, 4, z), t0).unwrap();
    let mut refused = None;
    for i in 1..40u32 {
        let t = t0 + 100 * u64::from(i);
        match s.update_position(PLAYER, at(2 + i, x + i as i32, 4, z), t) {
            Ok(()) => assert!(t <= t0 + hang, "still up at {t}"),
            Err(e) => {
                assert!(matches!(e, PositionReject::TooHigh { .. }), "{e:?}");
                refused = Some(t);
                break;
            }
        }
    }
    let refused = refused.expect("refused at last");
    assert!(
        refused > t0 + hang && refused <= t0 + hang + 200,
        "{refused}"
    );
    // Coming down (below the sunk limit) is fine, then standing again.
    let held = s.position(PLAYER).unwrap().feet;
    let down = PositionUpdate {
        seq: 100,
        pos: FixedVec3::from_f64([held.x.to_f64(), 0.0, held.z.to_f64()]).unwrap(),
    };
    s.update_position(PLAYER, down, refused + 100).unwrap();
}
