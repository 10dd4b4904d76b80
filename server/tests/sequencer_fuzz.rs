//! Any edit a client can encode, from a player or an admin, near home or
//! at the edges of the coordinate range, with any radius, strength,
//! material, structure and rotation: the sequencer refuses it with a
//! reason and changes nothing, or applies it in a tick, and never panics
//! (a panic on the engine thread stops the server for everyone).

use crate::sequencer_common;

use proptest::prelude::*;
use proptest::test_runner::Config as ProptestConfig;
use sequencer_common::*;
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{Edit, VoxelPos};

/// A coordinate in voxels: mostly near home, sometimes anywhere.
fn coord(home: i32) -> impl Strategy<Value = i32> {
    prop_oneof![
        8 => (home - 6)..(home + 6),
        2 => (home - 20)..(home + 20),
        1 => any::<i32>(),
        1 => prop::sample::select(vec![i32::MIN, -(1 << 22), (1 << 22) - 1, i32::MAX]),
    ]
}

/// A fixed-point coordinate (1/256 voxel): mostly within reach of `home`
/// on quarter voxels (where tiny spheres fall between voxel centres),
/// sometimes anywhere.
fn fixed(home: i32) -> impl Strategy<Value = Fixed> {
    prop_oneof![
        12 => ((home - 6) * 4..(home + 6) * 4).prop_map(|q| Fixed(q * 64)),
        2 => ((home - 20) * 256..(home + 20) * 256).prop_map(Fixed),
        1 => any::<i32>().prop_map(Fixed),
    ]
}

fn center() -> impl Strategy<Value = FixedVec3> {
    (fixed(HOME.0), fixed(2), fixed(HOME.1)).prop_map(|(x, y, z)| FixedVec3::new(x, y, z))
}

fn voxel() -> impl Strategy<Value = VoxelPos> {
    (coord(HOME.0), coord(2), coord(HOME.1)).prop_map(|(x, y, z)| VoxelPos::new(x, y, z))
}

/// Radii from below the smallest allowed to past the largest, in raw
/// fixed point, with the tiny ones that hold no voxel centre.
fn radius() -> impl Strategy<Value = Fixed> {
    prop_oneof![
        3 => (0i32..2304).prop_map(Fixed),
        1 => (32i32..160).prop_map(Fixed),
        1 => any::<i32>().prop_map(Fixed),
    ]
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        (center(), radius(), strength()).prop_map(|(center, radius, strength)| Edit::Mine {
            center,
            radius,
            strength
        }),
        (
            center(),
            radius(),
            prop_oneof![4 => 1u16..=512, 1 => any::<u16>()]
        )
            .prop_map(|(center, radius, power)| Edit::Explode {
                center,
                radius,
                power
            }),
        (center(), radius(), material(), strength()).prop_map(
            |(center, radius, material, strength)| Edit::Build {
                center,
                radius,
                material,
                strength
            }
        ),
        (voxel(), voxel(), material()).prop_map(|(min, max, material)| Edit::FillBox {
            min,
            max,
            material
        }),
        (voxel(), voxel()).prop_map(|(min, max)| Edit::ClearBox { min, max }),
        (
            any::<u32>(),
            voxel(),
            prop_oneof![4 => 0u8..4, 1 => any::<u8>()]
        )
            .prop_map(|(structure, origin, rotation)| {
                Edit::PlaceStructure {
                    structure,
                    origin,
                    rotation,
                }
            }),
        (center(), radius(), strength()).prop_map(|(center, radius, strength)| Edit::Smooth {
            center,
            radius,
            strength
        }),
    ]
}

fn material() -> impl Strategy<Value = u8> {
    prop_oneof![4 => 1u8..=7, 1 => any::<u8>()]
}

fn strength() -> impl Strategy<Value = u8> {
    prop_oneof![4 => 1u8..=255, 1 => Just(0u8)]
}

#[test]
fn any_edit_is_refused_unchanged_or_applied() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases: 512,
        ..ProptestConfig::default()
    });
    let applied = std::cell::Cell::new(0usize);
    let cases = prop::collection::vec((edit(), any::<bool>()), 1..4);
    runner
        .run(&cases, |edits| {
            let mut s = ready(ValidationConfig::default());
            for (i, (e, by_admin)) in edits.into_iter().enumerate() {
                let session = if by_admin { ADMIN } else { PLAYER };
                let before = snapshot(&s);
                let seq = s.next_seq();
                match s.submit(session, req(i as u64, e.clone()), 0) {
                    Err(_) => prop_assert_eq!(snapshot(&s), before, "{:?}", e),
                    Ok(()) => {
                        let out = s.tick(0);
                        prop_assert!(out.applied.len() <= 1, "{:?}", e);
                        for a in &out.applied {
                            prop_assert_eq!(a.seq, seq);
                        }
                        applied.set(applied.get() + out.applied.len());
                    }
                }
            }
            Ok(())
        })
        .unwrap();
    // The strategies must reach the apply, not only the refusals.
    assert!(applied.get() >= 48, "only {} edits applied", applied.get());
}

/// Any position report, from a placed player or one with no position yet:
/// refused with a reason or taken, never a panic, and a refused one
/// leaves the position as it was.
#[test]
fn any_position_report_is_refused_or_taken() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
        cases: 512,
        ..ProptestConfig::default()
    });
    let report = (any::<u32>(), center(), 0u64..100_000);
    runner
        .run(&prop::collection::vec(report, 1..6), |reports| {
            let mut s = ready(ValidationConfig::default());
            s.session_joined(7, "new".into(), strata_protocol::Role::Player);
            for (seq, pos, now) in reports {
                for session in [PLAYER, 7] {
                    let update = strata_protocol::PositionUpdate { seq, pos };
                    // Where and since when: what a refusal must leave (the
                    // time credited to the next move may grow).
                    let place =
                        |p: Option<strata_server::validate::position::ValidatedPosition>| {
                            p.map(|p| {
                                (
                                    p.feet,
                                    p.at_ms,
                                    p.seq,
                                    p.slack_milli,
                                    p.placement,
                                    p.known_ms,
                                )
                            })
                        };
                    let before = s.position(session);
                    let taken = s
                        .precheck_position(session, &update, now)
                        .and_then(|()| s.charge_placement(session, now))
                        .and_then(|()| s.update_position(session, update, now));
                    if taken.is_err() {
                        prop_assert_eq!(place(s.position(session)), place(before));
                    }
                    if let Some(p) = s.position(session) {
                        // Never more than the time since the position.
                        prop_assert!(p.credit_ms <= p.heard_ms.saturating_sub(p.at_ms));
                    }
                }
            }
            Ok(())
        })
        .unwrap();
}
