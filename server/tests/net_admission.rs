//! Admission: connections that never say Hello hold only handshake slots
//! (few, a few per address, until a deadline), the session cap counts
//! authenticated sessions, and admins have room of their own.

mod common;

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

#[tokio::test]
async fn a_new_login_replaces_the_old_session_unless_more_are_allowed() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let shared = token(&server, "ana", Role::Player);
        let first = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        let second = Client::connect(server.addr, &server.cert_der, &shared)
            .await
            .unwrap();
        match tokio::time::timeout(Duration::from_secs(5), first.closed()).await {
            Ok(ClientError::Refused { code, message }) => {
                assert_eq!(code, ErrorCode::Kicked);
                assert!(message.contains("newer login"), "{message}");
            }
            other => panic!("expected the first session to end, got {other:?}"),
        }
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
