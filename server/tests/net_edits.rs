//! Edits over real QUIC: validation rejects with a reason and changes
//! nothing; accepted edits are acknowledged after they are durable, and two
//! clients receive the same deltas in the same order as the server's store.

#[macro_use]
mod common;

use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_protocol::{RejectReason, Role};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Edit, FixedVec3, VoxelPos};

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
