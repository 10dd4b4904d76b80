//! Re-centring a view: a prompt client at view radius 8 that jumps its
//! subscription across the world is told which chunks left in a few
//! frames, not thousands, and stays connected.

mod common;

use std::time::Duration;

use common::*;
use strata_protocol::Role;
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
        // 17³ = 4913 chunks each time; every jump drops all of the last view,
        // far more than the session's writer queue holds frames.
        for (i, x) in [0, 100, 0, -100].into_iter().enumerate() {
            c.subscribe(ChunkPos::new(x, 0, 0), 8).await.unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            c.ping(i as u64).await.unwrap();
            assert!(!c.is_closed(), "disconnected after jump {i}");
        }
        // What the client holds is only the last view's.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let stale = c
            .replica()
            .chunks()
            .filter(|(p, _)| (p.x - -100).abs() > 10)
            .count();
        assert_eq!(stale, 0, "chunks of earlier views were dropped");
        assert!(!c.replica().is_empty(), "the last view is streaming");
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
