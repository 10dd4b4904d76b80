//! A player's place in the world outlives its sessions and the server: a
//! reconnect, even after a restart, resumes where the player last stood,
//! so a far first report is refused as too fast and edits there are out
//! of reach (no teleport by reconnecting).

mod common;

use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_protocol::{RejectReason, Role};
use strata_terrain::{Edit, FixedVec3, VoxelPos};

fn mine(ground: VoxelPos) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
        radius: r(1.5),
        strength: 255,
    }
}

#[tokio::test]
async fn a_restarted_server_resumes_players_where_they_stood() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (home, home_ground) = spot(70, 40);
        let (far, far_ground) = spot(5070, 40);
        let server = start(dir.path()).await;
        let ana = connect(&server, "ana", Role::Player).await;
        ana.send_position(home).unwrap();
        assert!(
            eventually(Duration::from_secs(10), || ana
                .replica()
                .get(home_ground.chunk())
                .is_some())
            .await
        );
        assert!(matches!(
            ana.edit(mine(home_ground)).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        ana.close().await;
        // Positions are saved every second and at shutdown.
        server.shutdown().await.unwrap();

        let server = start(dir.path()).await;
        let ana = connect(&server, "ana", Role::Player).await;
        // 5000 voxels from where ana stood: refused, so ana is still home.
        ana.send_position(far).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        match ana.edit(mine(far_ground)).await.unwrap() {
            Verdict::Rejected(RejectReason::OutOfReach { .. }) => {}
            other => panic!("a teleport by restart and reconnect: {other:?}"),
        }
        // A player never seen before may start anywhere.
        let bo = connect(&server, "bo", Role::Player).await;
        bo.send_position(far).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            !matches!(
                bo.edit(mine(far_ground)).await.unwrap(),
                Verdict::Rejected(RejectReason::OutOfReach { .. } | RejectReason::NoPosition)
            ),
            "a new player's first position is accepted"
        );
        ana.close().await;
        bo.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
