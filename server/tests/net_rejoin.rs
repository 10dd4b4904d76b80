//! Logging in again is not free: a player's logins draw on a bucket of its
//! own that outlives its sessions (`[validation.join_rate]`), refused with
//! a reason before the engine hears of them, and a session's first view
//! draws on the player's request bucket like a subscription of it. A
//! client that lost its connection still comes back, several times.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, ClientError};
use strata_protocol::{ErrorCode, Role, Start};
use strata_server::app;
use strata_server::validate::ratelimit::BucketConfig;

/// Reports `feet` until the server says the view around it is loaded.
async fn view_loaded(c: &Client, feet: strata_terrain::FixedVec3) -> bool {
    eventually(Duration::from_secs(20), || {
        let _ = c.send_position(feet);
        c.view_loaded().is_some()
    })
    .await
}

#[tokio::test]
async fn logins_past_the_players_join_bucket_are_refused_before_the_engine() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Three logins, never refilled.
        let mut cfg = test_config(dir.path());
        cfg.validation.join_rate = BucketConfig {
            capacity: 3,
            per_second: 0,
        };
        let server = app::start(cfg).await.expect("server starts");
        let mut live: Option<Client> = None;
        for _ in 0..3 {
            let c = connect(&server, "looper", Role::Player).await;
            if let Some(old) = live.replace(c) {
                match tokio::time::timeout(Duration::from_secs(10), old.closed()).await {
                    Ok(ClientError::Refused {
                        code: ErrorCode::Kicked,
                        ..
                    }) => {}
                    other => panic!("a newer login replaces the older: {other:?}"),
                }
            }
        }
        let t = token(&server, "looper", Role::Player);
        match Client::connect(server.addr, &server.cert_der, &t).await {
            Err(ClientError::Refused {
                code: ErrorCode::TooManyConnections,
                message,
            }) => assert!(message.contains("logs in too often"), "{message}"),
            Err(e) => panic!("expected a refusal for the rate, got {e}"),
            Ok(_) => panic!("a fourth login was let in"),
        }
        // The engine never saw it: the live session was not replaced.
        let live = live.unwrap();
        live.ping(1).await.unwrap();
        assert!(!live.is_closed());
        // Other players still join.
        let calm = connect(&server, "calm", Role::Player).await;
        calm.ping(2).await.unwrap();
        live.close().await;
        calm.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_player_who_loses_its_connection_comes_back_with_its_view() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (feet, _) = spot(70, 40);
        for i in 0..5 {
            let c = connect(&server, "ana", Role::Player).await;
            if i > 0 {
                assert_eq!(c.welcome().start, Start::Resume { feet });
            }
            assert!(view_loaded(&c, feet).await, "reconnect {i}: no view");
            // Gone without a word, as a dropped link would be.
            c.abandon();
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_resumed_sessions_first_view_waits_for_the_players_request_tokens() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        // A radius-2 view is 125 chunks: one fits the bucket, and it
        // refills at one a second.
        let config = format!(
            "{FAST_EDITS}[validation.request_rate]\ncapacity = 150\nper_second = 1\n\
             [interest]\nview_radius = 2\n[metrics]\nlisten = \"{metrics}\"\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let throttled =
            || metric(&scrape(metrics), "strata_requests_throttled_total").unwrap_or(0.0);
        let (feet, _) = spot(70, 40);
        let first = process_client(&data, addr, "ana").await;
        assert!(view_loaded(&first, feet).await);
        assert_eq!(throttled(), 0.0, "the first view fit the bucket");
        first.abandon();
        // Back at once: the same place, but its view costs as much again.
        let again = process_client(&data, addr, "ana").await;
        assert_eq!(again.welcome().start, Start::Resume { feet });
        assert!(
            eventually(Duration::from_secs(20), || {
                let _ = again.send_position(feet);
                throttled() >= 1.0
            })
            .await,
            "the resumed view did not wait for request tokens"
        );
        assert_eq!(again.view_loaded(), None, "streamed before it was paid");
        assert_eq!(again.replica().len(), 0);
        assert!(!again.is_closed(), "slowed down, not refused");
        again.close().await;
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}
