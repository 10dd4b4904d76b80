//! `/healthz` and a store that fails fast: the engine goes on ticking
//! (edits refused, nothing committed), so only the store's own failures
//! can say the server is not fit to take players.

use crate::common;
use crate::store_common;

use std::time::{Duration, Instant};

use common::*;
use store_common::sql_url;
use strata_client_sim::Verdict;
use strata_protocol::Role;
use strata_server::health::STORE_FAILING;
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
        let admin_url = db.cluster().url("postgres");
        let name = db.name().to_string();
        let close = format!(
            "ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS false; \
             SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = '{name}'"
        );
        let url = admin_url.clone();
        tokio::task::spawn_blocking(move || sql_url(&url, &close))
            .await
            .unwrap();
        let c = connect(&server, "ana", Role::Player).await;
        c.send_position(feet).unwrap();
        // Each edit at the stored chunk reads it, and the read fails.
        let started = Instant::now();
        let mut refused = 0;
        while health.check().is_ok() {
            assert!(
                started.elapsed() < STORE_FAILING * 3,
                "still ready after {:?} of failed reads",
                started.elapsed()
            );
            if !matches!(c.edit(dig(1)).await.unwrap(), Verdict::Accepted { .. }) {
                refused += 1;
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        assert!(started.elapsed() >= STORE_FAILING, "unready at once");
        assert!(refused > 0);
        let why = health.check().unwrap_err();
        assert!(why.contains("store"), "{why}");
        let open = format!("ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS true");
        tokio::task::spawn_blocking(move || sql_url(&admin_url, &open))
            .await
            .unwrap();
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
        assert_eq!(health.check(), Ok(()));
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
