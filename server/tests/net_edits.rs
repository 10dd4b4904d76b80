//! Edits over real QUIC: validation rejects with a reason and changes
//! nothing; accepted edits are acknowledged after they are durable, and two
//! clients receive the same deltas in the same order as the server's store;
//! `[net] send_interval_ms` spaces a watcher's writes; an edit behind a
//! wall is refused for line of sight.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, Verdict};
use strata_protocol::{RejectReason, Role};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{ChunkPos, Edit, FixedVec3, VoxelPos};

/// A surface point away from spawn, and the feet position standing on it.
fn spot() -> (FixedVec3, VoxelPos) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let (x, z) = (70, 40);
    let y = g.surface_height(x, z);
    (
        at(x as f64, y + 1.0, z as f64),
        VoxelPos::new(x, y.floor() as i32, z),
    )
}

on_both_backends!(
    two_clients_see_one_history,
    two_clients_see_one_history_on_postgres,
    two_clients_see_one_history_on
);

async fn two_clients_see_one_history_on(backend: Backend) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start_on(dir.path(), &backend).await;
        let a = connect(&server, "ana", Role::Player).await;
        let b = connect(&server, "bo", Role::Player).await;
        for c in [&a, &b] {
            c.replica().record_history();
        }
        let (feet, ground) = spot();
        // Without a validated position there is no reach to check against.
        let mine = |dx: i32| Edit::Mine {
            center: FixedVec3::from_voxels(ground.x + dx, ground.y, ground.z),
            radius: r(2.5),
            strength: 255,
        };
        assert_eq!(
            a.edit(mine(0)).await.unwrap(),
            Verdict::Rejected(RejectReason::NoPosition)
        );
        a.send_position(feet).unwrap();
        b.send_position(feet).unwrap();
        let target = ground.chunk();
        assert!(
            eventually(Duration::from_secs(10), || a
                .replica()
                .get(target)
                .is_some()
                && b.replica().get(target).is_some())
            .await
        );
        let far = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x + 40, ground.y, ground.z),
            radius: r(2.0),
            strength: 255,
        };
        assert!(matches!(
            a.edit(far).await.unwrap(),
            Verdict::Rejected(RejectReason::OutOfReach { .. })
        ));
        let huge = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(30.0),
            strength: 255,
        };
        assert!(matches!(
            a.edit(huge).await.unwrap(),
            Verdict::Rejected(RejectReason::RadiusTooLarge { .. })
        ));

        let mut seqs = Vec::new();
        for (i, c) in [&a, &b, &a].iter().enumerate() {
            match c.edit(mine(i as i32 - 1)).await.unwrap() {
                Verdict::Accepted { seq } => seqs.push(seq),
                v => panic!("edit {i} refused: {v:?}"),
            }
        }
        assert!(
            seqs.windows(2).all(|w| w[1] > w[0]),
            "sequence numbers rise: {seqs:?}"
        );
        let last = *seqs.last().unwrap();
        assert!(
            eventually(Duration::from_secs(10), || a.replica().last_seq() >= last
                && b.replica().last_seq() >= last)
            .await
        );
        let (ha, hb) = (
            a.replica().history().unwrap().clone(),
            b.replica().history().unwrap().clone(),
        );
        assert_eq!(
            ha.get(&target),
            hb.get(&target),
            "both clients saw the same versions in the same order"
        );
        assert!(ha[&target].len() >= 2);
        let held: Vec<_> = [&a, &b]
            .iter()
            .map(|c| {
                let r = c.replica();
                let h = r.get(target).unwrap();
                (h.version, chunk_hash(&h.chunk))
            })
            .collect();
        assert_eq!(held[0], held[1]);
        for c in [&a, &b] {
            let stats = c.replica().stats;
            assert_eq!(
                stats.mesh_mismatches,
                0,
                "{:?}",
                c.replica().mesh_mismatches()
            );
            assert_eq!(stats.hash_mismatches, 0);
        }
        a.close().await;
        b.close().await;
        server.shutdown().await.unwrap();
        // The store holds exactly what the clients hold.
        let store = backend.open_store(dir.path());
        let stored = store.load_chunk(target).unwrap().unwrap();
        assert_eq!((stored.version, chunk_hash(&stored.chunk)), held[0]);
        assert_eq!(store.last_seq().unwrap(), last);
    })
    .await
    .expect("test finished in time");
}

on_both_backends!(
    resync_request_sends_a_fresh_snapshot,
    resync_request_sends_a_fresh_snapshot_on_postgres,
    resync_request_sends_a_fresh_snapshot_on
);

async fn resync_request_sends_a_fresh_snapshot_on(backend: Backend) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start_on(dir.path(), &backend).await;
        let a = connect(&server, "ana", Role::Player).await;
        let (feet, ground) = spot();
        a.send_position(feet).unwrap();
        let target = ground.chunk();
        assert!(
            eventually(Duration::from_secs(10), || a
                .replica()
                .get(target)
                .is_some())
            .await
        );
        let edit = Edit::Build {
            center: FixedVec3::from_voxels(ground.x, ground.y + 2, ground.z),
            radius: r(2.0),
            material: 7,
            strength: 255,
        };
        assert!(matches!(
            a.edit(edit).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        assert!(
            eventually(Duration::from_secs(10), || a
                .replica()
                .get(target)
                .is_some_and(|h| h.version == 1))
            .await
        );
        let before = a.replica().stats.snapshots;
        a.resync(target).await.unwrap();
        assert!(
            eventually(Duration::from_secs(10), || a.replica().stats.snapshots
                > before)
            .await
        );
        assert_eq!(a.replica().get(target).unwrap().version, 1);
        a.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Two clients standing on the chunk border x = 96, each holding the
/// chunks on both sides: `ana` (deltas) and `bo` (`CAP_OP_REPLAY`). Returns
/// them, the ground voxel and the two chunks.
async fn at_the_border(
    server: &strata_server::app::Running,
) -> (Client, Client, VoxelPos, [ChunkPos; 2]) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let (x, z) = (96, 40);
    let y = g.surface_height(x, z);
    let ground = VoxelPos::new(x, y.floor() as i32, z);
    let sides = [VoxelPos::new(x - 3, ground.y, z).chunk(), ground.chunk()];
    let a = connect(server, "ana", Role::Player).await;
    let b = connect_caps(server, "bo", strata_protocol::CAP_OP_REPLAY).await;
    for c in [&a, &b] {
        c.send_position(at(x as f64 + 0.5, y + 1.0, z as f64))
            .unwrap();
    }
    let holds = |c: &Client| sides.iter().all(|p| c.replica().get(*p).is_some());
    assert!(eventually(Duration::from_secs(20), || holds(&a) && holds(&b)).await);
    (a, b, ground, sides)
}

/// A Mine or Smooth of radius `radius` centred on `ground`, accepted.
async fn dig(c: &Client, ground: VoxelPos, smooth: bool, radius: f64) -> u64 {
    let (center, radius) = (at(96.0, ground.y as f64, 40.0), r(radius));
    let edit = if smooth {
        Edit::Smooth {
            center,
            radius,
            strength: 255,
        }
    } else {
        Edit::Mine {
            center,
            radius,
            strength: 255,
        }
    };
    match c.edit(edit).await.unwrap() {
        Verdict::Accepted { seq } => seq,
        v => panic!("edit refused: {v:?}"),
    }
}

/// A client with `CAP_OP_REPLAY` takes accepted edits (Mine, Smooth) as
/// ops, replays them with the terrain core, and ends with the server's
/// versions and hashes, and its mesh hashes.
#[tokio::test]
async fn op_replay_clients_replay_accepted_edits() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (a, b, ground, sides) = at_the_border(&server).await;
        dig(&a, ground, false, 3.0).await;
        let seq = dig(&a, ground, true, 4.0).await;
        assert!(eventually(Duration::from_secs(10), || b.replica().last_seq() >= seq).await);
        let s = b.replica().stats;
        assert!(s.ops >= 2 && s.op_chunks >= 2, "{s:?}");
        assert_eq!((s.deltas, s.op_gaps, s.op_mismatches), (0, 0, 0), "{s:?}");
        assert!(s.meshes_checked >= 1, "{s:?}");
        assert_eq!(s.mesh_mismatches, 0, "{:?}", b.replica().mesh_mismatches());
        for pos in sides {
            let (version, hash) = server_chunk(&server, pos).await;
            assert!(version >= 1, "{pos:?} changed");
            let held = b.replica().get(pos).cloned().unwrap();
            assert_eq!((held.version, held.hash), (version, hash), "{pos:?}");
        }
        for c in [a, b] {
            c.close().await;
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// An op whose base the client lacks (it dropped the chunk) or whose
/// replay gives another hash (its copy was wrong) is not applied: the
/// client asks for those chunks again and converges on the server's.
#[tokio::test]
async fn op_replay_falls_back_to_resync_and_converges() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (a, b, ground, [dropped, wrong]) = at_the_border(&server).await;
        {
            let mut r = b.replica();
            r.apply(strata_protocol::WorldUpdate::Unsubscribed { pos: dropped });
            // A copy that hashes right for itself but is not the server's.
            let fake = strata_terrain::Chunk::uniform(strata_terrain::Voxel::solid(3));
            let version = r.get(wrong).unwrap().version;
            r.apply(strata_protocol::WorldUpdate::Snapshot {
                pos: wrong,
                version,
                hash: chunk_hash(&fake),
                mesh_hash: 0,
                data: strata_terrain::chunk_codec::encode_chunk(&fake),
            });
        }
        let before = b.replica().stats;
        let seq = dig(&a, ground, false, 3.0).await;
        assert!(eventually(Duration::from_secs(10), || b.replica().last_seq() >= seq).await);
        let s = b.replica().stats;
        assert!(s.op_gaps > before.op_gaps, "{s:?}");
        assert!(s.op_mismatches > before.op_mismatches, "{s:?}");
        for pos in [dropped, wrong] {
            let (version, hash) = server_chunk(&server, pos).await;
            assert!(
                eventually(Duration::from_secs(10), || b
                    .replica()
                    .get(pos)
                    .is_some_and(|h| (h.version, h.hash) == (version, hash)))
                .await,
                "{pos:?} converged"
            );
        }
        assert!(b.replica().stats.snapshots >= before.snapshots + 2);
        for c in [a, b] {
            c.close().await;
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// `[net] send_interval_ms` through the real config: a watcher's updates
/// are written at most once per interval, so the delta of an edit made
/// just after the previous one was written reaches it an interval later.
#[tokio::test]
async fn the_send_interval_spaces_a_watchers_writes() {
    const INTERVAL_MS: u64 = 1000;
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.net.send_interval_ms = INTERVAL_MS;
        let server = strata_server::app::start(cfg).await.unwrap();
        let (feet, ground) = spot();
        let editor = connect(&server, "ed", Role::Player).await;
        let watcher = connect(&server, "wat", Role::Player).await;
        editor.send_position(feet).unwrap();
        watcher.send_position(feet).unwrap();
        assert!(
            eventually(Duration::from_secs(10), || watcher
                .replica()
                .get(ground.chunk())
                .is_some())
            .await
        );
        // Let the view's last write and its interval pass.
        tokio::time::sleep(Duration::from_millis(INTERVAL_MS + 200)).await;
        let build = |dy: i32| Edit::Build {
            center: FixedVec3::from_voxels(ground.x, ground.y + dy, ground.z),
            radius: r(1.5),
            material: 7,
            strength: 40,
        };
        let Verdict::Accepted { seq: first } = editor.edit(build(2)).await.unwrap() else {
            panic!("first edit refused");
        };
        // When the watcher has `seq`, polled every 2 ms.
        let seen = |seq: u64| {
            let watcher = &watcher;
            async move {
                loop {
                    if watcher.replica().last_seq() >= seq {
                        return std::time::Instant::now();
                    }
                    tokio::time::sleep(Duration::from_millis(2)).await;
                }
            }
        };
        let t1 = seen(first).await;
        let Verdict::Accepted { seq: second } = editor.edit(build(3)).await.unwrap() else {
            panic!("second edit refused");
        };
        let t2 = seen(second).await;
        let gap = t2 - t1;
        // At least the interval after the first write; the first may have
        // been noticed late, so allow for that.
        assert!(
            gap >= Duration::from_millis(INTERVAL_MS / 2),
            "the second delta came {gap:?} after the first"
        );
        editor.close().await;
        watcher.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A player ("ana") and an admin ("root") standing at [`spot`], and a
/// brick wall three voxels ahead of them the admin built, from below the
/// ground to `top` voxels above it. Returns their feet and the ground.
async fn by_a_wall(
    server: &strata_server::app::Running,
    top: i32,
) -> (Client, Client, FixedVec3, VoxelPos) {
    let ana = connect(server, "ana", Role::Player).await;
    let root = connect(server, "root", Role::Admin).await;
    let (feet, ground) = spot();
    ana.send_position(feet).unwrap();
    root.send_position(feet).unwrap();
    let (x, y, z) = (ground.x, ground.y, ground.z);
    assert!(
        eventually(Duration::from_secs(10), || ana
            .replica()
            .get(ground.chunk())
            .is_some())
        .await
    );
    let wall = Edit::FillBox {
        min: VoxelPos::new(x - 6, y - 3, z + 3),
        max: VoxelPos::new(x + 6, y + top, z + 3),
        material: strata_terrain::material::ids::BRICK,
    };
    assert!(matches!(
        root.edit(wall).await.unwrap(),
        Verdict::Accepted { .. }
    ));
    (ana, root, feet, ground)
}

/// The first `PositionRefused` the client hears (within 10 s): why, and
/// where the server holds the player.
async fn first_refusal(client: &Client) -> (strata_protocol::PositionRefusal, Option<FixedVec3>) {
    let mut told = None;
    assert!(
        eventually(Duration::from_secs(10), || {
            told = told.or_else(|| {
                std::iter::from_fn(|| client.pop_notice()).find_map(|n| match n {
                    strata_client_sim::Notice::PositionRefused { reason, at, .. } => {
                        Some((reason, at))
                    }
                    _ => None,
                })
            });
            told.is_some()
        })
        .await,
        "no position refused"
    );
    told.unwrap()
}

/// Line of sight over QUIC: checked on the workers for the edits the
/// engine admitted, against the terrain as it stands then.
#[tokio::test]
async fn an_edit_behind_a_wall_is_refused_for_line_of_sight() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (ana, root, _, ground) = by_a_wall(&server, 9).await;
        let (x, y, z) = (ground.x, ground.y, ground.z);
        let g = Generator::fractal(GenParams::default()).unwrap();
        let behind = |dx: i32| {
            let (tx, tz) = (x + dx, z + 8);
            Edit::Mine {
                center: FixedVec3::from_voxels(tx, g.surface_height(tx, tz).floor() as i32, tz),
                radius: r(2.0),
                strength: 255,
            }
        };
        for dx in [0, 1] {
            assert_eq!(
                ana.edit(behind(dx)).await.unwrap(),
                Verdict::Rejected(RejectReason::NoLineOfSight)
            );
        }
        // In front of the wall the view is clear.
        let near = Edit::Mine {
            center: FixedVec3::from_voxels(x, y, z + 1),
            radius: r(1.0),
            strength: 255,
        };
        assert!(matches!(
            ana.edit(near).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        ana.close().await;
        root.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A position beyond a wall, within a move's reach: refused for its path,
/// and the answer says where the server holds the player, from where its
/// next report is checked. Flying over it instead (a spot high above the
/// ground) is refused by gravity, the answer naming the apex a jump
/// reaches.
#[tokio::test]
async fn a_walk_through_or_a_flight_over_a_wall_is_refused_with_where_the_player_stands() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        // Higher than a hop over either end.
        let (ana, root, feet, ground) = by_a_wall(&server, 16).await;
        let (x, z) = (ground.x, ground.z);
        // Standing on the ground six voxels on, past the wall.
        let g = Generator::fractal(GenParams::default()).unwrap();
        let past =
            FixedVec3::from_f64([x as f64, g.surface_height(x, z + 6) + 1.0, (z + 6) as f64])
                .unwrap();
        // Long enough since the last report for the distance.
        tokio::time::sleep(Duration::from_millis(600)).await;
        ana.send_position(past).unwrap();
        let (reason, at) = first_refusal(&ana).await;
        assert!(
            matches!(reason, strata_protocol::PositionRefusal::PathBlocked { voxel }
                if voxel.z == z + 3),
            "{reason:?}"
        );
        assert_eq!(at, Some(feet), "held where it stood");
        // Straight up, higher than the wall: past the refusals' interval.
        let [fx, fy, fz] = feet.to_f64();
        tokio::time::sleep(Duration::from_millis(600)).await;
        ana.send_position(FixedVec3::from_f64([fx, fy + 8.0, fz]).unwrap())
            .unwrap();
        let (reason, at) = first_refusal(&ana).await;
        // A jump above the ground's surface under the feet (at most the
        // feet, at least the ground's reach below them).
        assert!(
            matches!(reason, strata_protocol::PositionRefusal::TooHigh { apex }
                if (fy + 1.5..=fy + 4.0).contains(&apex.to_f64())),
            "a jump above the ground it stood on: {reason:?}"
        );
        assert_eq!(at, Some(feet), "held where it stood");
        ana.close().await;
        root.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A sphere too small to hold a voxel centre (radius under half a voxel,
/// centred between centres) is refused as invalid, and the server goes on
/// editing: it once made an empty box that the tick's apply panicked on.
#[tokio::test]
async fn a_sphere_holding_no_voxel_is_refused_and_the_server_goes_on() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = strata_server::app::start(test_config(dir.path()))
            .await
            .unwrap();
        let a = connect(&server, "ana", Role::Player).await;
        let (feet, ground) = spot();
        a.send_position(feet).unwrap();
        assert!(
            eventually(Duration::from_secs(10), || a
                .replica()
                .get(ground.chunk())
                .is_some())
            .await
        );
        let between = FixedVec3::from_f64([
            ground.x as f64 + 0.5,
            ground.y as f64 + 0.5,
            ground.z as f64 + 0.5,
        ])
        .unwrap();
        let tiny = Edit::Mine {
            center: between,
            radius: strata_terrain::Fixed(64),
            strength: 1,
        };
        match a.edit(tiny).await.unwrap() {
            Verdict::Rejected(RejectReason::Invalid { message }) => {
                assert!(message.contains("no voxel"), "{message}")
            }
            v => panic!("{v:?}"),
        }
        let mine = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(2.5),
            strength: 255,
        };
        assert!(matches!(
            a.edit(mine).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        a.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
