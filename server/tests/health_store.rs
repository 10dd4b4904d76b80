//! `/healthz` and a store that fails fast: the engine goes on ticking
//! (edits refused, nothing committed), so only the store's own failures
//! can say the server is not fit to take players.

use crate::common;
use crate::store_common;

use std::time::{Duration, Instant};

use common::*;
use store_common::{close_db, on_postgres};
use strata_client_sim::Verdict;
use strata_protocol::Role;
use strata_server::config::ServerConfig;
use strata_server::health::STORE_FAILING;
use strata_server::store::ChunkStore;
use strata_terrain::{Edit, FixedVec3};

/// PostgreSQL stops taking the server's connections (its database closed
/// to them, theirs ended) while no edit commits: every read of a stored
/// chunk fails at once. The server turns unready after `STORE_FAILING`
/// of that, and ready again at the first read that succeeds.
#[tokio::test]
async fn a_store_whose_reads_keep_failing_is_not_ready() {
    let Some(backend) = Backend::postgres("a_store_whose_reads_keep_failing_is_not_ready") else {
        return;
    };
    let Backend::Postgres(db) = &backend else {
        unreachable!("asked for PostgreSQL")
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (feet, ground) = spot(70, 40);
        let dig = |strength: u8| Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(2.0),
            strength,
        };
        // A world with a stored chunk, and a server that has not read it.
        {
            let server = start_on(dir.path(), &backend).await;
            let c = connect(&server, "ana", Role::Player).await;
            c.send_position(feet).unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            assert!(matches!(
                c.edit(dig(100)).await.unwrap(),
                Verdict::Accepted { .. }
            ));
            c.close().await;
            server.shutdown().await.unwrap();
        }
        let server = start_on(dir.path(), &backend).await;
        let health = server.health();
        assert_eq!(health.check(), Ok(()));
        let closed = Instant::now();
        let open = close_db(db).await;
        // Connected after: the stored chunk is not read yet.
        let c = connect(&server, "ana", Role::Player).await;
        c.send_position(feet).unwrap();
        // Each edit at the stored chunk reads it, and the read fails.
        let mut refused = 0;
        while !health
            .check()
            .is_err_and(|why| why.contains("engine's reads"))
        {
            assert!(
                closed.elapsed() < STORE_FAILING * 3,
                "no failed reads reported after {:?}: {:?}",
                closed.elapsed(),
                health.check()
            );
            if !matches!(c.edit(dig(1)).await.unwrap(), Verdict::Accepted { .. }) {
                refused += 1;
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        assert!(closed.elapsed() >= STORE_FAILING, "unready at once");
        assert!(refused > 0);
        tokio::task::spawn_blocking(open).await.unwrap();
        // The next read succeeds: ready again, and the edit goes through.
        let started = Instant::now();
        loop {
            let verdict = c.edit(dig(1)).await.unwrap();
            if matches!(verdict, Verdict::Accepted { .. }) {
                break;
            }
            assert!(
                started.elapsed() < Duration::from_secs(20),
                "the store never came back: {verdict:?}"
            );
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        // The engine's reads are no longer failing; the reloads of the
        // access list and zones succeed at their next pass, and a failed
        // position save counts no longer than `STORE_FAILING`.
        assert!(!health
            .check()
            .is_err_and(|why| why.contains("engine's reads")));
        until(&health, None, Instant::now(), STORE_FAILING * 4).await;
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Waits until `health` answers ready (`None`) or unready for a reason
/// that names `Some(what)`, at most `limit` after `from`; how long after
/// `from` it came.
async fn until(
    health: &strata_server::health::Health,
    want: Option<&str>,
    from: Instant,
    limit: Duration,
) -> Duration {
    loop {
        let now = health.check();
        let matched = match (now, want) {
            (Ok(()), None) => true,
            (Err(why), Some(what)) => why.contains(what),
            _ => false,
        };
        if matched {
            return from.elapsed();
        }
        assert!(
            from.elapsed() < limit,
            "readiness {now:?}, not {want:?}, after {:?}",
            from.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// [`on_postgres`] for cluster node `node-a`, no checkpoint thread.
fn on_cluster_node(
    test: &str,
    lease_ms: u64,
    renew_ms: u64,
) -> Option<(
    strata_tests::postgres::PgDb,
    tempfile::TempDir,
    ServerConfig,
)> {
    let (db, dir, mut cfg) = on_postgres(test, 0)?;
    cfg.cluster = Some(strata_server::cluster::ClusterConfig {
        node_id: "node-a".into(),
        lease_ms,
        renew_ms,
        ..Default::default()
    });
    Some((db, dir, cfg))
}

/// Starts a server on `cfg` (PostgreSQL `db`) that nobody connects to,
/// closes `db` to it: unready for the failures of the work `what` names
/// once they have gone on for `STORE_FAILING`, not before; ready again
/// once `db` is back.
async fn unready_while_closed(db: &strata_tests::postgres::PgDb, cfg: ServerConfig, what: &str) {
    let server = strata_server::app::start(cfg).await.unwrap();
    let health = server.health();
    assert_eq!(health.check(), Ok(()));
    let closed = Instant::now();
    let open = close_db(db).await;
    // Work every 5 s (the reloads) may read once more before the close
    // takes hold, then fail at +5 and +10 s, each read as slow as a loaded
    // machine makes it.
    let took = until(&health, Some(what), closed, STORE_FAILING * 5).await;
    assert!(took >= STORE_FAILING, "unready at once: {took:?}");
    tokio::task::spawn_blocking(open).await.unwrap();
    until(&health, None, Instant::now(), STORE_FAILING * 4).await;
    server.shutdown().await.unwrap();
}

/// Nobody connected, nothing edited: the engine never touches the store,
/// but the checkpoint thread does, every pass. Its failures turn the
/// server unready once they have gone on for `STORE_FAILING`; once they
/// stop (the store back), ready again after `STORE_FAILING`.
#[tokio::test]
async fn an_idle_server_whose_store_fails_is_not_ready() {
    let Some((db, _dir, cfg)) = on_postgres("an_idle_server_whose_store_fails_is_not_ready", 200)
    else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, unready_while_closed(&db, cfg, "checkpoints"))
        .await
        .expect("test finished in time");
}

/// Nobody connected, no checkpoint thread, one node: the access list's
/// reload (every `ACCESS_RELOAD_PERIOD`) still reads the store.
#[tokio::test]
async fn a_server_whose_access_list_reads_fail_is_not_ready() {
    let Some((db, _dir, cfg)) =
        on_postgres("a_server_whose_access_list_reads_fail_is_not_ready", 0)
    else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, unready_while_closed(&db, cfg, "access list"))
        .await
        .expect("test finished in time");
}

/// A cluster node with no checkpoint thread and nobody connected: only
/// its lease renewals reach the store. Their failures turn it unready.
#[tokio::test]
async fn a_cluster_node_whose_renewals_fail_is_not_ready() {
    let Some((db, _dir, cfg)) = on_cluster_node(
        "a_cluster_node_whose_renewals_fail_is_not_ready",
        2_000,
        200,
    ) else {
        return;
    };
    tokio::time::timeout(
        TEST_TIMEOUT,
        unready_while_closed(&db, cfg, "renewing region leases"),
    )
    .await
    .expect("test finished in time");
}

/// A player walks on the spot and nobody edits, with no checkpoint
/// thread: only the saves of its positions (every `POSITION_SAVE_EVERY`,
/// on the commit thread) reach the store. Their failures turn the server
/// unready.
#[tokio::test]
async fn a_server_whose_position_saves_fail_is_not_ready() {
    let Some((db, _dir, cfg)) = on_postgres("a_server_whose_position_saves_fail_is_not_ready", 0)
    else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let server = strata_server::app::start(cfg).await.unwrap();
        let health = server.health();
        let (feet, _) = spot(70, 40);
        let c = connect(&server, "ana", Role::Player).await;
        c.send_position(feet).unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let closed = Instant::now();
        let open = close_db(&db).await;
        let mut step = 0u32;
        // Walking on the spot (each report a move), until `want`.
        let mut walk_until = async |want: Option<&str>, from: Instant| loop {
            match (health.check(), want) {
                (Ok(()), None) => return from.elapsed(),
                (Err(why), Some(what)) if why.contains(what) => return from.elapsed(),
                (now, _) => assert!(
                    from.elapsed() < STORE_FAILING * 4,
                    "readiness {now:?}, not {want:?}, after {:?}",
                    from.elapsed()
                ),
            }
            step += 1;
            let dx = if step % 2 == 0 { 0.0 } else { 0.25 };
            let [x, y, z] = feet.to_f64();
            c.send_position(FixedVec3::from_f64([x + dx, y, z]).unwrap())
                .unwrap();
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        let took = walk_until(Some("saving positions"), closed).await;
        assert!(took >= STORE_FAILING, "unready at once: {took:?}");
        tokio::task::spawn_blocking(open).await.unwrap();
        // Ready once a save succeeds (and the reloads read again).
        walk_until(None, Instant::now()).await;
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A cluster node reads a joining player's stored position before the
/// login goes on; players keep trying to join while the store is down
/// (leases renewed too seldom to fail first, no checkpoint thread).
#[tokio::test]
async fn a_cluster_node_whose_position_reads_fail_is_not_ready() {
    let Some((db, _dir, cfg)) = on_cluster_node(
        "a_cluster_node_whose_position_reads_fail_is_not_ready",
        60_000,
        20_000,
    ) else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let server = strata_server::app::start(cfg).await.unwrap();
        let health = server.health();
        let closed = Instant::now();
        let open = close_db(&db).await;
        let mut tries = 0u32;
        let took = loop {
            if let Err(why) = health.check() {
                if why.contains("players' positions") {
                    break closed.elapsed();
                }
            }
            assert!(
                closed.elapsed() < STORE_FAILING * 3,
                "readiness {:?} after {tries} logins",
                health.check()
            );
            tries += 1;
            let token = token(&server, &format!("p{tries}"), Role::Player);
            let joined =
                strata_client_sim::Client::connect(server.addr, &server.cert_der, &token).await;
            assert!(joined.is_err(), "a login with no stored position read");
            tokio::time::sleep(Duration::from_millis(250)).await;
        };
        assert!(took >= STORE_FAILING, "unready at once: {took:?}");
        tokio::task::spawn_blocking(open).await.unwrap();
        let c = connect(&server, "ana", Role::Player).await;
        until(&health, None, Instant::now(), STORE_FAILING * 4).await;
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A player moves and leaves while the store is down: the saves of its
/// position fail, and once the store is back its last spot is saved (the
/// players a failed save left are saved again), not the one before.
#[tokio::test]
async fn a_position_whose_save_failed_is_saved_once_the_store_is_back() {
    let Some((db, _dir, cfg)) = on_postgres(
        "a_position_whose_save_failed_is_saved_once_the_store_is_back",
        0,
    ) else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let server = strata_server::app::start(cfg).await.unwrap();
        let store = store_common::pg_store(&db);
        let (feet, _) = spot(70, 40);
        let [x, y, z] = feet.to_f64();
        let later = FixedVec3::from_f64([x + 0.5, y, z]).unwrap();
        let stored = || store.player_position("ana").ok().flatten().map(|p| p.feet);
        let c = connect(&server, "ana", Role::Player).await;
        c.send_position(feet).unwrap();
        assert!(eventually(Duration::from_secs(10), || stored() == Some(feet)).await);
        let open = close_db(&db).await;
        c.send_position(later).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        c.close().await;
        // A save or two fails (one a second while a player moved).
        tokio::time::sleep(Duration::from_millis(2_500)).await;
        tokio::task::spawn_blocking(open).await.unwrap();
        let saved = eventually(Duration::from_secs(10), || stored() == Some(later)).await;
        assert!(saved, "stored {:?}", store.player_position("ana"));
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
