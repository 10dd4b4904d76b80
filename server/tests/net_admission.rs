//! Admission: connections that never say Hello hold only handshake slots
//! (few, a few per address, until a deadline), spoofed sources hold none
//! once a Retry is asked for, the session cap counts authenticated
//! sessions, and admins have room of their own.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, ClientError};
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_protocol::{ErrorCode, Role};
use strata_server::admin::remote::AdminClient;
use strata_server::app;

/// A QUIC connection from 127.0.0.2 that completes TLS and says nothing;
/// `None` if the server refused it.
async fn silent(
    addr: std::net::SocketAddr,
    cert: Vec<u8>,
) -> Option<(quinn::Endpoint, quinn::Connection)> {
    let cfg = strata_client_sim::tls::client_config_pinned(&cert).unwrap();
    let mut endpoint = quinn::Endpoint::client("127.0.0.2:0".parse().unwrap()).unwrap();
    endpoint.set_default_client_config(cfg);
    let conn = endpoint.connect(addr, "localhost").ok()?.await.ok()?;
    Some((endpoint, conn))
}

#[tokio::test]
async fn silent_connections_from_one_address_lock_out_no_player() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.server.max_connections = 4;
        cfg.server.max_handshakes_per_address = 3;
        cfg.server.handshake_timeout_ms = 800;
        let server = app::start(cfg).await.expect("server starts");
        let mut tries = tokio::task::JoinSet::new();
        for _ in 0..30 {
            tries.spawn(silent(server.addr, server.cert_der.clone()));
        }
        let mut held = Vec::new();
        while let Some(r) = tries.join_next().await {
            held.extend(r.unwrap());
        }
        assert!(
            (1..=3).contains(&held.len()),
            "{} silent connections got in at once",
            held.len()
        );
        // More than the session cap tried, yet players get in.
        let a = connect(&server, "ana", Role::Player).await;
        a.ping(1).await.unwrap();
        // The silent ones are closed at the handshake deadline.
        for (_, conn) in &held {
            let why = tokio::time::timeout(Duration::from_secs(5), conn.closed())
                .await
                .expect("closed by the server");
            assert!(
                matches!(why, quinn::ConnectionError::ApplicationClosed(_)),
                "{why}"
            );
        }
        assert!(!a.is_closed());
        a.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn the_cap_counts_sessions_and_admins_have_their_own_room() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.server.max_connections = 2;
        let server = app::start(cfg).await.expect("server starts");
        // A silent connection takes no session slot.
        let _quiet = silent(server.addr, server.cert_der.clone())
            .await
            .expect("a handshake slot");
        let a = connect(&server, "ana", Role::Player).await;
        let b = connect(&server, "bo", Role::Player).await;
        let cy = token(&server, "cy", Role::Player);
        match Client::connect(server.addr, &server.cert_der, &cy).await {
            Err(ClientError::Refused { code, message }) => {
                assert_eq!(code, ErrorCode::TooManyConnections);
                assert!(message.contains("full"), "{message}");
            }
            other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
        }
        // The operator still gets in.
        let admin_token = token(&server, "root", Role::Admin);
        let mut admin = AdminClient::connect(server.addr, &server.cert_der, &admin_token)
            .await
            .unwrap();
        match admin.request(&AdminRequest::Stats).await.unwrap() {
            AdminResponse::Stats(s) => assert_eq!(s.sessions, 2),
            other => panic!("{other:?}"),
        }
        admin.close().await;
        // A slot frees when a session ends.
        a.close().await;
        let mut c = None;
        for _ in 0..50 {
            if let Ok(client) = Client::connect(server.addr, &server.cert_der, &cy).await {
                c = Some(client);
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let c = c.expect("a freed slot is taken again");
        c.close().await;
        b.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Waits for `c`'s session to end for its player's newer login.
async fn ended_by_a_newer_login(c: Client) {
    match tokio::time::timeout(Duration::from_secs(5), c.closed()).await {
        Ok(ClientError::Refused { code, message }) => {
            assert_eq!(code, ErrorCode::Kicked);
            assert!(message.contains("newer login"), "{message}");
        }
        other => panic!("expected the session to end, got {other:?}"),
    }
}

/// A full server lets a player back in on the slot of its own session
/// that its client left behind (not yet timed out), which the login ends;
/// another player's slot is never taken.
#[tokio::test]
async fn a_full_server_lets_a_player_in_on_its_own_stale_session() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.server.max_connections = 2;
        cfg.validation.join_rate.capacity = 8;
        let server = app::start(cfg).await.expect("server starts");
        let ana = token(&server, "ana", Role::Player);
        let left_behind = Client::connect(server.addr, &server.cert_der, &ana)
            .await
            .unwrap();
        let bo = connect(&server, "bo", Role::Player).await;
        let cy = token(&server, "cy", Role::Player);
        match Client::connect(server.addr, &server.cert_der, &cy).await {
            Err(ClientError::Refused { code, .. }) => {
                assert_eq!(code, ErrorCode::TooManyConnections)
            }
            other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
        }
        let back = Client::connect(server.addr, &server.cert_der, &ana)
            .await
            .expect("ana's own slot");
        ended_by_a_newer_login(left_behind).await;
        back.ping(1).await.unwrap();
        bo.ping(1).await.unwrap();
        assert_eq!(live_sessions(&server).await, 2);
        // Still full for anyone else.
        assert!(Client::connect(server.addr, &server.cert_der, &cy)
            .await
            .is_err());
        back.close().await;
        bo.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_new_login_replaces_the_old_session_unless_more_are_allowed() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Logins past the player's join rate are refused (`net_rejoin.rs`);
        // room here for every one.
        let mut cfg = test_config(dir.path());
        cfg.validation.join_rate.capacity = 64;
        let server = app::start(cfg).await.unwrap();
        let shared = token(&server, "ana", Role::Player);
        let first = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        let second = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        ended_by_a_newer_login(first).await;
        second.ping(1).await.unwrap();
        // 30 logins with one token leave exactly one session.
        let mut last = None;
        for _ in 0..30 {
            last = Some(
                Client::connect(server.addr, &server.cert_der, &shared)
                    .await
                    .unwrap(),
            );
        }
        let mut sessions = 0;
        for _ in 0..50 {
            sessions = live_sessions(&server).await;
            if sessions == 1 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert_eq!(sessions, 1);
        last.unwrap().ping(2).await.unwrap();
        server.shutdown().await.unwrap();

        // Allowed more, both stay.
        let mut cfg = test_config(dir.path());
        cfg.engine.sessions_per_player = 2;
        let server = app::start(cfg).await.unwrap();
        let a = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        let b = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
        a.ping(1).await.unwrap();
        b.ping(1).await.unwrap();
        assert!(!a.is_closed() && !b.is_closed());
        a.close().await;
        b.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Sends one QUIC Initial packet to `server` from each of `sources`
/// loopback addresses and never reads an answer: what a sender of spoofed
/// source addresses does.
fn spoofed_initials(server: std::net::SocketAddr, cert: &[u8], sources: u8) {
    let cfg = strata_client_sim::tls::client_config_pinned(cert).unwrap();
    let mut ep = quinn_proto::Endpoint::new(Default::default(), None, false, None);
    for i in 1..=sources {
        let now = std::time::Instant::now();
        let (_, mut conn) = ep.connect(now, cfg.clone(), server, "localhost").unwrap();
        let mut buf = Vec::new();
        let t = conn.poll_transmit(now, 1, &mut buf).expect("an Initial");
        let from = std::net::UdpSocket::bind((std::net::Ipv4Addr::new(127, 0, 1, i), 0)).unwrap();
        from.send_to(&buf[..t.size], server).unwrap();
    }
}

#[tokio::test]
async fn spoofed_initials_take_no_handshake_slot_once_retry_is_asked() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        // Without a Retry, 40 Initials from 40 addresses take all 8 slots
        // (a player still gets in, taking the oldest one's slot: see
        // `net_robustness.rs`); with it (from 4 in progress), at most 4, and
        // the player takes a free one.
        for retry_above in [9, 4] {
            let dir = tempfile::tempdir().unwrap();
            let mut cfg = test_config(dir.path());
            cfg.server.max_handshakes = 8;
            cfg.server.retry_above_handshakes = retry_above;
            cfg.server.handshake_timeout_ms = 2_000;
            let server = app::start(cfg).await.expect("server starts");
            spoofed_initials(server.addr, &server.cert_der, 40);
            // The server has taken them in before the player comes, long
            // enough ago that their slots may be taken.
            // (half `handshake_timeout_ms`, with room for a slow start).
            tokio::time::sleep(Duration::from_millis(1_400)).await;
            let tls = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
            let mut endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
            endpoint.set_default_client_config(tls);
            let player = endpoint.connect(server.addr, "localhost").unwrap().await;
            // Without a Retry by eviction; with one, the player answers
            // it, so it gets a slot.
            let conn = player.expect("a real client gets in");
            conn.close(0u32.into(), b"");
            let a = connect(&server, "ana", Role::Player).await;
            a.ping(1).await.unwrap();
            a.close().await;
            server.shutdown().await.unwrap();
        }
    })
    .await
    .expect("test finished in time");
}
