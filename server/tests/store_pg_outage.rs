//! A server alone on PostgreSQL rides out an outage: a commit that wrote
//! nothing is tried again for `[store.postgres] commit_retry_ms`, nothing
//! is acknowledged meanwhile, and once PostgreSQL is back the edit is
//! acknowledged and stored. Past the window the server stops without
//! acknowledging.

use crate::common;
use crate::store_common;

use std::sync::Arc;
use std::time::Duration;

use common::*;
use store_common::sql_url;
use strata_client_sim::{Client, Verdict};
use strata_protocol::Role;
use strata_terrain::{Edit, FixedVec3};
use strata_tests::postgres::PgCluster;

/// A server on `cfg`, a player standing at (70, 40), what digs below it,
/// and the seq of its first dig, accepted.
async fn edited_once(
    cfg: strata_server::config::ServerConfig,
) -> (
    strata_server::app::Running,
    Client,
    impl Fn(u8) -> Edit,
    u64,
) {
    let server = strata_server::app::start(cfg).await.unwrap();
    let (feet, ground) = spot(70, 40);
    let c = connect(&server, "ana", Role::Player).await;
    c.send_position(feet).unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let dig = move |strength: u8| Edit::Mine {
        center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
        radius: r(2.0),
        strength,
    };
    let Verdict::Accepted { seq } = c.edit(dig(100)).await.unwrap() else {
        panic!("the first edit refused");
    };
    (server, c, dig, seq)
}

/// The seqs in the edit log of the database at `url`.
async fn logged(url: String) -> Vec<String> {
    tokio::task::spawn_blocking(move || sql_url(&url, "SELECT seq FROM edit_log ORDER BY seq"))
        .await
        .unwrap()
}

/// A PostgreSQL cluster of `test`'s own (it is stopped and started), a
/// data dir, and a server config on its database `strata`.
fn on_own_cluster(
    test: &str,
) -> Option<(
    Arc<PgCluster>,
    tempfile::TempDir,
    strata_server::config::ServerConfig,
)> {
    let pg = Arc::new(strata_tests::postgres::private_cluster(test)?);
    pg.create_database("strata").unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path());
    cfg.store.backend = strata_server::store::StoreBackend::Postgres;
    cfg.store.postgres.url = pg.url("strata");
    Some((pg, dir, cfg))
}

/// Runs `f` (stop or start) on `pg` off the async threads.
async fn pg_ctl(pg: &Arc<PgCluster>, f: fn(&PgCluster) -> Result<(), String>) {
    let pg = pg.clone();
    tokio::task::spawn_blocking(move || f(&pg))
        .await
        .unwrap()
        .unwrap();
}

/// PostgreSQL restarted under a live server: the edit made while it is
/// down is acknowledged once it is back, and stored.
#[tokio::test]
async fn an_edit_made_while_postgres_restarts_is_acknowledged_once_it_is_back() {
    let test = "an_edit_made_while_postgres_restarts_is_acknowledged_once_it_is_back";
    let Some((pg, _dir, cfg)) = on_own_cluster(test) else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (server, c, dig, first) = edited_once(cfg).await;
        pg_ctl(&pg, PgCluster::stop).await;
        let sent = c.submit(dig(50)).await.unwrap();
        let acked = {
            let verdict = c.verdict(sent);
            tokio::pin!(verdict);
            assert!(
                tokio::time::timeout(Duration::from_secs(2), &mut verdict)
                    .await
                    .is_err(),
                "no verdict while PostgreSQL is down"
            );
            pg_ctl(&pg, PgCluster::start_again).await;
            verdict.await.expect("acknowledged once it is back")
        };
        let Verdict::Accepted { seq, .. } = acked.0 else {
            panic!("expected the edit accepted, got {:?}", acked.0);
        };
        let logged_now = logged(pg.url("strata")).await;
        assert_eq!(logged_now, [first.to_string(), seq.to_string()]);
        // The session and the server went on.
        c.ping(1).await.unwrap();
        assert!(matches!(
            c.edit(dig(10)).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .unwrap_or_else(|_| panic!("test finished in time; PostgreSQL's log:\n{}", pg.log()));
}

/// PostgreSQL down for longer than `commit_retry_ms`: the server stops
/// without acknowledging the edit, and nothing of it was stored.
#[tokio::test]
async fn a_server_whose_postgres_stays_down_past_the_window_stops_unacknowledged() {
    let test = "a_server_whose_postgres_stays_down_past_the_window_stops_unacknowledged";
    let Some((pg, _dir, mut cfg)) = on_own_cluster(test) else {
        return;
    };
    cfg.store.postgres.commit_retry_ms = 500;
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (server, c, dig, first) = edited_once(cfg).await;
        pg_ctl(&pg, PgCluster::stop).await;
        let verdict = c.edit(dig(50)).await;
        assert!(
            !matches!(verdict, Ok(Verdict::Accepted { .. })),
            "{verdict:?}"
        );
        assert!(
            eventually(Duration::from_secs(10), || c.is_closed()).await,
            "the server stopped"
        );
        pg_ctl(&pg, PgCluster::start_again).await;
        let logged_now = logged(pg.url("strata")).await;
        assert_eq!(logged_now, [first.to_string()], "nothing more was stored");
        let _ = server.shutdown().await;
    })
    .await
    .unwrap_or_else(|_| panic!("test finished in time; PostgreSQL's log:\n{}", pg.log()));
}
