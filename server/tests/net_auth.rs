//! The handshake over real QUIC: good tokens get `Welcome`; bad, expired
//! and forged tokens, a wrong protocol version and a wrong ALPN are refused
//! before any world data is sent.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::tls::{client_config_pinned, client_config_pinned_with_alpn};
use strata_client_sim::{Client, ClientError};
use strata_protocol::{ErrorCode, Role, PROTOCOL_VERSION};
use strata_server::auth::{self, Secret};

#[tokio::test]
async fn tokens_versions_and_alpn() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let ok = connect(&server, "ana", Role::Player).await;
        assert_eq!(ok.welcome().player, "ana");
        assert_eq!(ok.welcome().role, Role::Player);

        let refused = |r: Result<Client, ClientError>| match r {
            Err(ClientError::Refused { code, message }) => (code, message),
            Err(e) => panic!("expected a refusal, got {e}"),
            Ok(_) => panic!("expected a refusal, got a session"),
        };
        let forged = auth::issue(
            &Secret::from_bytes([7; 32]),
            "eve",
            Role::Admin,
            Duration::from_secs(60),
            auth::unix_now(),
        )
        .unwrap();
        let (code, _) = refused(Client::connect(server.addr, &server.cert_der, &forged).await);
        assert_eq!(code, ErrorCode::BadToken);
        let (code, message) =
            refused(Client::connect(server.addr, &server.cert_der, "not-a-token").await);
        assert_eq!(code, ErrorCode::BadToken);
        assert!(!message.is_empty());
        let old = auth::issue(
            server.data_dir.secret(),
            "bob",
            Role::Player,
            Duration::from_secs(1),
            1_000,
        )
        .unwrap();
        let (code, _) = refused(Client::connect(server.addr, &server.cert_der, &old).await);
        assert_eq!(code, ErrorCode::ExpiredToken);
        let cfg = client_config_pinned(&server.cert_der).unwrap();
        let (code, _) = refused(
            Client::connect_with(
                server.addr,
                cfg,
                &token(&server, "cy", Role::Player),
                PROTOCOL_VERSION + 1,
            )
            .await,
        );
        assert_eq!(code, ErrorCode::UnsupportedVersion);

        let wrong_alpn = client_config_pinned_with_alpn(&server.cert_der, b"strata/0").unwrap();
        let r = Client::connect_with(
            server.addr,
            wrong_alpn,
            &token(&server, "dee", Role::Player),
            PROTOCOL_VERSION,
        )
        .await;
        assert!(r.is_err(), "a wrong ALPN must fail the handshake");

        // The good session is unaffected by all of that.
        ok.ping(1).await.unwrap();
        assert!(!ok.is_closed());
        ok.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// An admin-role session on the player protocol keeps its admin powers
/// (every edit kind, protected zones) only while its token is good: it
/// ends with `ExpiredToken` when the token expires, as an admin
/// connection does. A player's session outlives its token.
#[tokio::test]
async fn an_admin_session_ends_when_its_token_expires_and_a_players_goes_on() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let short = |player: &str, role: Role| {
            auth::issue(
                server.data_dir.secret(),
                player,
                role,
                Duration::from_secs(2),
                auth::unix_now(),
            )
            .unwrap()
        };
        let admin = Client::connect(server.addr, &server.cert_der, &short("ops", Role::Admin))
            .await
            .unwrap();
        let player = Client::connect(server.addr, &server.cert_der, &short("ana", Role::Player))
            .await
            .unwrap();
        let ended = tokio::time::timeout(Duration::from_secs(6), admin.closed()).await;
        match ended {
            Ok(ClientError::Refused { code, .. }) => assert_eq!(code, ErrorCode::ExpiredToken),
            other => panic!("the admin session went on, or ended otherwise: {other:?}"),
        }
        player.ping(1).await.unwrap();
        assert!(!player.is_closed());
        player.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// `[auth] token_max_ttl` bounds the life of every token the server takes,
/// not only of those `strata-admin` issues next: lowered, it shortens the
/// tokens already out (say, an issuer's that leaked).
#[tokio::test]
async fn a_lowered_token_max_ttl_shortens_tokens_already_issued() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.auth.token_max_ttl = auth::HumanDuration(Duration::from_secs(3600));
        let server = strata_server::app::start(cfg).await.unwrap();
        let day = Duration::from_secs(24 * 3600);
        let issued = |ago: u64| {
            auth::issue(
                server.data_dir.secret(),
                "ann",
                Role::Player,
                day,
                auth::unix_now() - ago,
            )
            .unwrap()
        };
        match Client::connect(server.addr, &server.cert_der, &issued(7200)).await {
            Err(ClientError::Refused { code, .. }) => assert_eq!(code, ErrorCode::ExpiredToken),
            Err(e) => panic!("expected a refusal, got {e}"),
            Ok(_) => panic!("a token two hours old was taken under a one-hour cap"),
        }
        let ann = Client::connect(server.addr, &server.cert_der, &issued(60))
            .await
            .unwrap();
        ann.ping(1).await.unwrap();
        ann.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
