//! A player's place in the world outlives its sessions and the server: a
//! reconnect, even after a restart, resumes where the player last stood,
//! so a far first report is refused as too fast and edits there are out
//! of reach (no teleport by reconnecting). A player the server does not
//! remember starts in the configured spawn area.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_protocol::{RejectReason, Role, Start};
use strata_server::validate::SpawnArea;
use strata_terrain::{Edit, FixedVec3, VoxelPos};

fn mine(ground: VoxelPos) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
        radius: r(1.5),
        strength: 255,
    }
}

/// Reports `feet`, waits until the chunk under it arrives, and mines there:
/// accepted only if the server took `feet` as the player's position.
async fn stand_and_mine(
    client: &strata_client_sim::Client,
    feet: FixedVec3,
    ground: VoxelPos,
) -> Verdict {
    client.send_position(feet).unwrap();
    assert!(
        eventually(Duration::from_secs(10), || client
            .replica()
            .get(ground.chunk())
            .is_some())
        .await
    );
    client.edit(mine(ground)).await.unwrap()
}

/// A server on `dir` where ana stood at home and mined (her position
/// accepted), stopped again; returns home.
async fn ana_stood_home(dir: &std::path::Path, backend: &Backend) -> FixedVec3 {
    let (home, home_ground) = spot(70, 40);
    let server = start_on(dir, backend).await;
    let ana = connect(&server, "ana", Role::Player).await;
    assert!(matches!(
        stand_and_mine(&ana, home, home_ground).await,
        Verdict::Accepted { .. }
    ));
    ana.close().await;
    // Positions are saved every second and at shutdown.
    server.shutdown().await.unwrap();
    home
}

on_both_backends!(
    a_restarted_server_resumes_players_where_they_stood,
    a_restarted_server_resumes_players_where_they_stood_on_postgres,
    a_restarted_server_resumes_players_where_they_stood_on
);

async fn a_restarted_server_resumes_players_where_they_stood_on(backend: Backend) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (far, far_ground) = spot(5070, 40);
        let home = ana_stood_home(dir.path(), &backend).await;
        let server = start_on(dir.path(), &backend).await;
        let ana = connect(&server, "ana", Role::Player).await;
        assert_eq!(
            ana.welcome().start,
            Start::Resume { feet: home },
            "Welcome names where ana stood"
        );
        // 5000 voxels from where ana stood: refused, so ana is still home.
        ana.send_position(far).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        match ana.edit(mine(far_ground)).await.unwrap() {
            Verdict::Rejected(RejectReason::OutOfReach { .. }) => {}
            other => panic!("a teleport by restart and reconnect: {other:?}"),
        }
        // A player never seen before starts in the spawn area, not anywhere.
        let bo = connect(&server, "bo", Role::Player).await;
        let spawn = SpawnArea::default();
        assert_eq!(bo.welcome().start, spawn.start());
        bo.send_position(far).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        match bo.edit(mine(far_ground)).await.unwrap() {
            Verdict::Rejected(RejectReason::NoPosition) => {}
            other => panic!("a new player appeared outside the spawn area: {other:?}"),
        }
        let (inside, inside_ground) = spot(spawn.radius as i32 - 10, -(spawn.radius as i32) + 10);
        assert!(
            matches!(
                stand_and_mine(&bo, inside, inside_ground).await,
                Verdict::Accepted { .. }
            ),
            "a new player's first position inside the spawn area is accepted"
        );
        ana.close().await;
        bo.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A cluster node of its own on `db` (tickets are a cluster's).
async fn start_node(
    dir: &std::path::Path,
    db: &strata_tests::postgres::PgDb,
) -> strata_server::app::Running {
    let mut cfg = test_config(dir);
    cfg.store.backend = strata_server::store::StoreBackend::Postgres;
    cfg.store.postgres.url = db.url();
    cfg.cluster = Some(strata_server::cluster::ClusterConfig {
        node_id: "solo".into(),
        ..Default::default()
    });
    strata_server::app::start(cfg).await.expect("node starts")
}

/// When the server last knew a player where it stood is stored with the
/// position: after a restart, a ticket (another node's word) issued before
/// then still cannot move the player back in time, and a newer one can.
#[tokio::test]
async fn a_ticket_older_than_a_stored_position_is_refused_after_a_restart() {
    use strata_protocol::{Refusal, TicketRefusal};
    use strata_server::cluster::ticket;
    use strata_server::engine::now_ms;
    let Some(db) = strata_tests::postgres::database("a_ticket_older_than_a_stored_position") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (home, home_ground) = spot(70, 40);
        let (near, _) = spot(74, 40);
        let issued_before = now_ms();
        tokio::time::sleep(Duration::from_millis(20)).await;
        let server = start_node(dir.path(), &db).await;
        let ana = connect(&server, "ana", Role::Player).await;
        assert!(matches!(
            stand_and_mine(&ana, home, home_ground).await,
            Verdict::Accepted { .. }
        ));
        ana.close().await;
        server.shutdown().await.unwrap();
        let server = start_node(dir.path(), &db).await;
        let key = server
            .tickets
            .clone()
            .expect("a cluster node signs tickets");
        let ana = connect(&server, "ana", Role::Player).await;
        assert_eq!(ana.welcome().start, Start::Resume { feet: home });
        let old = ticket::mint(&key, "ana", near, issued_before);
        let arrived = ana.arrive_within(old, Duration::from_secs(10)).await;
        assert_eq!(arrived.unwrap(), None, "an older ticket moved ana");
        assert_eq!(
            ana.refusals(),
            [Refusal::BadTicket {
                reason: TicketRefusal::AlreadyPlaced
            }]
        );
        let new = ticket::mint(&key, "ana", near, now_ms());
        ana.arrive(new).await.unwrap();
        assert!(eventually(Duration::from_secs(10), || ana.arrived().is_some()).await);
        assert_eq!(ana.arrived(), Some(near));
        assert_eq!(ana.refusals().len(), 1);
        ana.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

on_both_backends!(
    a_server_without_a_cluster_accepts_no_ticket,
    a_server_without_a_cluster_accepts_no_ticket_on_postgres,
    a_server_without_a_cluster_accepts_no_ticket_on
);

/// A server alone on its store mints no tickets, so none it could accept
/// is its own: one signed with its secret (shared with a cluster, say) is
/// refused, and the player stays where the server placed it.
async fn a_server_without_a_cluster_accepts_no_ticket_on(backend: Backend) {
    use strata_protocol::{Refusal, TicketRefusal};
    use strata_server::cluster::ticket::{self, TicketKey};
    use strata_server::engine::now_ms;
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (far, _) = spot(5070, 40);
        let server = start_on(dir.path(), &backend).await;
        assert!(server.tickets.is_none());
        let ana = connect(&server, "ana", Role::Player).await;
        let start = ana.welcome().start;
        // Signed as a cluster on this secret would sign it, for any world.
        let key = TicketKey::new(server.data_dir.secret().clone(), "");
        let t = ticket::mint(&key, "ana", far, now_ms());
        let arrived = ana.arrive_within(t, Duration::from_secs(10)).await;
        assert_eq!(arrived.unwrap(), None, "a ticket moved ana");
        assert_eq!(
            ana.refusals(),
            [Refusal::BadTicket {
                reason: TicketRefusal::NotClustered
            }]
        );
        assert_eq!(ana.welcome().start, start);
        ana.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn new_players_appear_at_the_configured_spawn() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (near, _) = spot(70, 40);
        let (far, far_ground) = spot(5070, 40);
        let mut cfg = test_config(dir.path());
        cfg.validation.spawn = SpawnArea {
            x: 5000,
            z: 0,
            radius: 100,
            ..SpawnArea::default()
        };
        let server = strata_server::app::start(cfg).await.unwrap();
        let cy = connect(&server, "cy", Role::Player).await;
        assert_eq!(
            cy.welcome().start,
            Start::Spawn {
                x: 5000,
                z: 0,
                radius: 100
            }
        );
        // Near the origin is outside this world's spawn: ignored.
        cy.send_position(near).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(matches!(
            stand_and_mine(&cy, far, far_ground).await,
            Verdict::Accepted { .. }
        ));
        cy.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
