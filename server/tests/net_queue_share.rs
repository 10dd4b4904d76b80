//! The engine's player queue is shared: clients flooding it with cheap
//! requests each hold at most their session's share of it (`[engine]
//! session_commands`), so an honest player's edits, position and
//! subscription still get in and it is not disconnected as overloaded.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::bots::raw_session::RawSession;
use strata_client_sim::{Client, Verdict};
use strata_protocol::{ClientMessage, Role};
use strata_server::app;
use strata_terrain::{Edit, FixedVec3};

/// Flooding sessions; at their shares they hold 8 × 4 = 32 of the 64 places.
const FLOODERS: usize = 8;

/// A session that writes empty `Forget`s (the cheapest request a client
/// has) as fast as the server reads them, until aborted.
async fn flood(server: &app::Running, player: &str) -> tokio::task::JoinHandle<()> {
    let endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    let tls = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
    let token = token(server, player, Role::Player);
    let mut s = RawSession::open(&endpoint, server.addr, tls, &token, None, None)
        .await
        .unwrap();
    let burst = vec![ClientMessage::Forget { chunks: Vec::new() }; 256];
    tokio::spawn(async move {
        let _endpoint = endpoint;
        while s.send_all(&burst).await.is_ok() {}
    })
}

/// Sends `feet` until the server has accepted it (its view follows it).
async fn placed(c: &Client, feet: FixedVec3) {
    let placed = async {
        while c.view_loaded().is_none() {
            c.send_position(feet).unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    tokio::time::timeout(Duration::from_secs(20), placed)
        .await
        .expect("the position was accepted");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_request_flood_leaves_room_for_an_honest_players_edits() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.engine.command_queue = 64;
        cfg.engine.session_commands = 4;
        // No request bucket to speak of: the share alone must hold them.
        cfg.validation.request_rate.capacity = 1 << 32;
        cfg.validation.request_rate.per_second = 1 << 32;
        cfg.validation.edit_rate.capacity = 1000;
        cfg.validation.edit_rate.per_second = 1000;
        let server = app::start(cfg).await.expect("server starts");
        let (feet, surface) = spot(70, 40);
        let honest = connect(&server, "honest", Role::Player).await;
        placed(&honest, feet).await;
        let mut flooders = Vec::new();
        for f in 0..FLOODERS {
            flooders.push(flood(&server, &format!("flood{f}")).await);
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        for i in 0..40 {
            let edit = Edit::Build {
                center: FixedVec3::from_voxels(
                    surface.x + (i % 5) - 2,
                    surface.y + 2,
                    surface.z + (i / 5) % 5 - 2,
                ),
                radius: r(1.5),
                material: 7,
                strength: 40,
            };
            match honest.edit(edit).await {
                Ok(Verdict::Accepted { .. }) => {}
                other => panic!("edit {i} during the flood: {other:?}"),
            }
            // Positions get in too (one each, never Busy).
            honest.send_position(feet).unwrap();
        }
        // A request the client relies on waits for room, not past it.
        honest
            .subscribe(surface.chunk(), 1)
            .await
            .expect("subscribe sent");
        honest.ping(1).await.unwrap();
        assert!(
            eventually(Duration::from_secs(10), || honest.view_loaded()
                == Some((surface.chunk(), 1)))
            .await,
            "the subscription was served during the flood"
        );
        assert!(!honest.is_closed(), "{:?}", honest.server_error());
        for f in flooders {
            f.abort();
        }
        honest.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
