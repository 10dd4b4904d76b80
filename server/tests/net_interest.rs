//! Interest: a prompt client at view radius 8 that re-centres its
//! subscription is told which chunks left in a few frames, not thousands,
//! and stays connected; a player cannot subscribe or ask for chunks far
//! from itself (map hack), and each refusal is answered.

mod common;

use std::time::Duration;

use common::*;
use strata_protocol::{Refusal, Role};
use strata_server::app;
use strata_terrain::ChunkPos;

#[tokio::test]
async fn a_far_re_centre_at_view_radius_8_keeps_the_client() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.interest.view_radius = 8;
        let server = app::start(cfg).await.expect("server starts");
        let c = connect(&server, "walker", Role::Player).await;
        // 17³ = 4913 chunks a view; each jump of 10 chunks (the farthest a
        // player may re-centre: radius plus hysteresis) drops 2312 of them,
        // far more than the session's writer queue holds frames.
        for (i, x) in [0, 10, 0, -10].into_iter().enumerate() {
            c.subscribe(ChunkPos::new(x, 0, 0), 8).await.unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            c.ping(i as u64).await.unwrap();
            assert!(!c.is_closed(), "disconnected after jump {i}");
        }
        // What the client holds is only the last view's.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let stale = c.replica().chunks().filter(|(p, _)| p.x > 0).count();
        assert_eq!(stale, 0, "chunks of earlier views were dropped");
        assert!(!c.replica().is_empty(), "the last view is streaming");
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn far_subscriptions_and_snapshot_requests_are_refused() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // View radius 2, hysteresis 2: centres at most 4 chunks away.
        let server = start(dir.path()).await;
        let c = connect(&server, "spy", Role::Player).await;
        c.subscribe(ChunkPos::new(0, 0, 0), 2).await.unwrap();
        let far = ChunkPos::new(175, 0, 0);
        c.subscribe(far, 2).await.unwrap();
        c.full_snapshot(far).await.unwrap();
        c.resync(ChunkPos::new(-60, 0, 3)).await.unwrap();
        // A near one is fine.
        c.subscribe(ChunkPos::new(4, 0, 0), 2).await.unwrap();
        assert!(
            eventually(Duration::from_secs(5), || c.refusals().len() >= 3).await,
            "{:?}",
            c.refusals()
        );
        assert_eq!(
            c.refusals(),
            vec![
                Refusal::SubscribeTooFar {
                    center: far,
                    max: 4
                },
                Refusal::NotInInterest { pos: far },
                Refusal::NotInInterest {
                    pos: ChunkPos::new(-60, 0, 3)
                },
            ]
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
        let outside = c.replica().chunks().filter(|(p, _)| p.x.abs() > 8).count();
        assert_eq!(outside, 0, "no chunk far from the player was sent");
        assert!(!c.replica().is_empty(), "the near view streams");
        // An admin may look anywhere.
        let admin = connect(&server, "ops", Role::Admin).await;
        admin.subscribe(ChunkPos::new(0, 0, 0), 1).await.unwrap();
        admin.subscribe(far, 1).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(admin.refusals().is_empty());
        c.close().await;
        admin.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
