//! Snapshot streaming under the smallest time and byte budgets: each tick
//! serves at least one session, sessions take turns, and every session
//! still receives its whole view.

mod common;

use std::time::Duration;

use common::*;
use strata_protocol::Role;
use strata_server::app;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkPos, VoxelPos};

/// Chunks within Chebyshev `r` of `c` (the test world's bounds are far).
fn cube(c: ChunkPos, r: i32) -> Vec<ChunkPos> {
    let mut v = Vec::new();
    for z in -r..=r {
        for y in -r..=r {
            for x in -r..=r {
                v.push(ChunkPos::new(c.x + x, c.y + y, c.z + z));
            }
        }
    }
    v
}

#[tokio::test]
async fn tiny_stream_budgets_serve_sessions_in_turn_and_deliver_every_chunk() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        // The smallest batches, and time for one session per tick.
        cfg.engine.stream_us = 1;
        cfg.net.send_budget_bytes_per_tick = strata_server::config::MIN_SEND_BUDGET_BYTES_PER_TICK;
        let radius = i32::from(cfg.interest.view_radius);
        let server = app::start(cfg).await.expect("server starts");
        let g = Generator::fractal(GenParams::default()).unwrap();
        let mut clients = Vec::new();
        let mut views = Vec::new();
        for (i, name) in ["ana", "bo", "cy"].into_iter().enumerate() {
            let c = connect(&server, name, Role::Player).await;
            let x = 70 + 40 * i as i32;
            let y = g.surface_height(x, 40);
            c.send_position(at(x as f64, y + 1.0, 40.0)).unwrap();
            views.push(cube(
                VoxelPos::new(x, y.floor() as i32 + 1, 40).chunk(),
                radius,
            ));
            clients.push(c);
        }
        let want = views[0].len();
        let held = |c: &strata_client_sim::Client| c.replica().len();
        // Taking turns: when the first session has everything, the others
        // are nearly done too (one at a time, they would have nothing).
        assert!(
            eventually(Duration::from_secs(30), || clients
                .iter()
                .any(|c| held(c) >= want))
            .await
        );
        let least = clients.iter().map(held).min().unwrap();
        assert!(
            least >= want / 2,
            "sessions were not served in turn: {:?} of {want}",
            clients.iter().map(held).collect::<Vec<_>>()
        );
        assert!(
            eventually(Duration::from_secs(30), || clients
                .iter()
                .all(|c| held(c) >= want))
            .await
        );
        for (c, view) in clients.iter().zip(&views) {
            let r = c.replica();
            let missing: Vec<_> = view.iter().filter(|p| r.get(**p).is_none()).collect();
            assert!(missing.is_empty(), "never sent: {missing:?}");
            assert_eq!(r.len(), view.len());
        }
        for c in clients {
            c.close().await;
        }
    })
    .await
    .expect("test finished in time");
}
