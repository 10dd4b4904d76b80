//! A server alone on PostgreSQL rides out an outage: a commit that wrote
//! nothing is tried again for `[store.postgres] commit_retry_ms`, nothing
//! is acknowledged meanwhile, and once PostgreSQL is back the edit is
//! acknowledged and stored. Past the window the server stops without
//! acknowledging.

use crate::common;
use crate::store_common;

use std::time::Duration;

use common::*;
use store_common::{close_db, on_postgres, sql_url};
use strata_client_sim::{Client, Verdict};
use strata_protocol::Role;
use strata_terrain::{Edit, FixedVec3};

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

/// The seqs in the edit log.
async fn logged(db: &strata_tests::postgres::PgDb) -> Vec<String> {
    let url = db.url();
    tokio::task::spawn_blocking(move || sql_url(&url, "SELECT seq FROM edit_log ORDER BY seq"))
        .await
        .unwrap()
}

#[tokio::test]
async fn an_edit_made_while_postgres_is_gone_is_acknowledged_once_it_is_back() {
    let test = "an_edit_made_while_postgres_is_gone_is_acknowledged_once_it_is_back";
    let Some((db, _dir, cfg)) = on_postgres(test, 200) else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (server, c, dig, first) = edited_once(cfg).await;
        let open = close_db(&db).await;
        let sent = c.submit(dig(50)).await.unwrap();
        let acked = {
            let verdict = c.verdict(sent);
            tokio::pin!(verdict);
            assert!(
                tokio::time::timeout(Duration::from_secs(2), &mut verdict)
                    .await
                    .is_err(),
                "no verdict while PostgreSQL is gone"
            );
            tokio::task::spawn_blocking(open).await.unwrap();
            verdict.await.expect("acknowledged once it is back")
        };
        let Verdict::Accepted { seq, .. } = acked.0 else {
            panic!("expected the edit accepted, got {:?}", acked.0);
        };
        assert_eq!(logged(&db).await, [first.to_string(), seq.to_string()]);
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
    .expect("test finished in time");
}

#[tokio::test]
async fn a_server_whose_postgres_stays_gone_past_the_window_stops_unacknowledged() {
    let test = "a_server_whose_postgres_stays_gone_past_the_window_stops_unacknowledged";
    let Some((db, _dir, mut cfg)) = on_postgres(test, 200) else {
        return;
    };
    cfg.store.postgres.commit_retry_ms = 500;
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (server, c, dig, first) = edited_once(cfg).await;
        let open = close_db(&db).await;
        let verdict = c.edit(dig(50)).await;
        assert!(
            !matches!(verdict, Ok(Verdict::Accepted { .. })),
            "{verdict:?}"
        );
        tokio::task::spawn_blocking(open).await.unwrap();
        assert_eq!(
            logged(&db).await,
            [first.to_string()],
            "nothing more was stored"
        );
        assert!(
            eventually(Duration::from_secs(10), || c.is_closed()).await,
            "the server stopped"
        );
        let _ = server.shutdown().await;
    })
    .await
    .expect("test finished in time");
}
