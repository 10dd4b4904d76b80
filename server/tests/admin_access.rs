//! Bans and token revocations through `strata-admin`, online (the change
//! ends live sessions and is refused at the next Hello) and offline (a
//! stopped server's stored list), and both survive a restart. Admin
//! sessions check their token again, and a ban during a join holds.

use crate::common;

use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use common::*;
use strata_client_sim::{Client, ClientError};
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_protocol::io::FramedReader;
use strata_protocol::{
    encode_frame, ClientMessage, Direction, ErrorCode, FrameBuffer, Hello, Role, ServerMessage,
    PROTOCOL_VERSION,
};
use strata_server::admin::remote::AdminClient;
use strata_server::app;
use strata_server::auth::{self, MAX_CLOCK_SKEW_SECS};
use strata_server::net::admin_session::ADMIN_RECHECK_PERIOD;

fn admin(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_strata-admin"))
        .args(args)
        .output()
        .expect("strata-admin runs");
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// `strata-admin ARGS --server ... --cert ... --token ...`.
fn online(server: &app::Running, args: &[&str]) -> String {
    let token = token(server, "root", Role::Admin);
    let cert = server.data_dir.cert_path();
    let addr = server.addr.to_string();
    let mut all = args.to_vec();
    all.extend([
        "--server",
        &addr,
        "--cert",
        cert.to_str().unwrap(),
        "--token",
        &token,
    ]);
    admin(&all)
}

async fn refused(server: &app::Running, token: &str) -> String {
    match Client::connect(server.addr, &server.cert_der, token).await {
        Err(ClientError::Refused { code, message }) => {
            assert_eq!(code, ErrorCode::Forbidden, "{message}");
            message
        }
        other => panic!("expected a refusal, got {:?}", other.map(|_| ())),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn online_bans_and_revocations_end_sessions_and_refuse_hellos() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let eve = connect(&server, "eve", Role::Player).await;
        let ana = connect(&server, "ana", Role::Player).await;
        let out = online(&server, &["ban", "eve", "--until", "1h"]);
        assert!(out.contains("banned eve until unix time"), "{out}");
        assert!(out.contains("ended 1 live session"), "{out}");
        assert!(matches!(
            tokio::time::timeout(Duration::from_secs(5), eve.closed()).await,
            Ok(ClientError::Refused { .. })
        ));
        let eve_token = token(&server, "eve", Role::Player);
        assert!(refused(&server, &eve_token).await.contains("banned"));
        assert!(online(&server, &["bans"]).contains("banned eve"));
        online(&server, &["unban", "eve"]);
        let eve = Client::connect(server.addr, &server.cert_der, &eve_token)
            .await
            .expect("unbanned");
        // A revocation ends the session and refuses every older token.
        let out = online(&server, &["token", "revoke", "eve"]);
        assert!(out.contains("revoked eve's tokens"), "{out}");
        assert!(out.contains("ended 1 live session"), "{out}");
        assert!(matches!(
            tokio::time::timeout(Duration::from_secs(5), eve.closed()).await,
            Ok(ClientError::Refused { .. })
        ));
        assert!(refused(&server, &eve_token).await.contains("revoked"));
        // A token minted now on a clock up to MAX_CLOCK_SKEW_SECS fast would
        // verify: the revocation covers that long, so a new one waits too.
        let fresh = token(&server, "eve", Role::Player);
        assert!(refused(&server, &fresh).await.contains("revoked"));
        tokio::time::sleep(Duration::from_millis(1100)).await;
        let later = auth::issue(
            server.data_dir.secret(),
            "eve",
            Role::Player,
            Duration::from_secs(3600),
            auth::unix_now() + MAX_CLOCK_SKEW_SECS,
        )
        .unwrap();
        let eve = Client::connect(server.addr, &server.cert_der, &later)
            .await
            .expect("a token issued after the revocation's time works");
        // Nobody else was touched.
        ana.ping(1).await.unwrap();
        eve.close().await;
        ana.close().await;
        server.shutdown().await.unwrap();
        // The list was persisted: it holds after a restart.
        let server = start(dir.path()).await;
        assert!(refused(&server, &eve_token).await.contains("revoked"));
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn an_offline_ban_holds_when_the_server_starts() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        start(dir.path()).await.shutdown().await.unwrap();
        let data = dir.path().to_str().unwrap();
        let out = admin(&["ban", "mal", "--data-dir", data]);
        assert!(out.contains("banned mal until unbanned"), "{out}");
        let server = start(dir.path()).await;
        let mal = token(&server, "mal", Role::Player);
        assert!(refused(&server, &mal).await.contains("banned"));
        server.shutdown().await.unwrap();
        admin(&["unban", "mal", "--data-dir", data]);
        assert!(admin(&["bans", "--data-dir", data]).contains("no bans"));
        let server = start(dir.path()).await;
        let c = Client::connect(server.addr, &server.cert_der, &mal)
            .await
            .expect("unbanned offline");
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// 40,000 bans and 20,000 revocations are about 2.6 MB of answer, over a
/// server frame (1 MiB): the server sends them in parts, and the admin
/// client joins them, for a listing and for a change's answer alike.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_access_list_over_a_frame_comes_whole_in_parts() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        start(dir.path()).await.shutdown().await.unwrap();
        let mut list = strata_server::auth::AccessList::default();
        for i in 0..40_000 {
            list.bans.insert(format!("banned_{i:0>25}"), None);
        }
        for i in 0..20_000 {
            list.revoked_before.insert(format!("revoked_{i:0>24}"), 1);
        }
        let store = strata_server::admin::remote::open_offline_store(dir.path()).unwrap();
        store
            .put_blob(strata_server::auth::ACCESS_BLOB, &list.to_blob())
            .unwrap();
        drop(store);
        let server = start(dir.path()).await;
        let out = online(&server, &["bans"]);
        assert_eq!(
            out.lines().filter(|l| l.starts_with("banned ")).count(),
            40_000
        );
        assert_eq!(
            out.lines().filter(|l| l.starts_with("revoked ")).count(),
            20_000
        );
        assert!(out.contains("banned banned_0000000000000000000000000 until unbanned"));
        assert!(out.contains("revoked revoked_000000000000000000019999's tokens"));
        let eve = connect(&server, "eve", Role::Player).await;
        let out = online(&server, &["ban", "eve"]);
        assert_eq!(
            out.lines().filter(|l| l.starts_with("banned ")).count(),
            40_001
        );
        assert!(
            out.contains("banned eve until unbanned"),
            "{}",
            &out[out.len() - 200..]
        );
        assert!(
            out.ends_with("ended 1 live session(s)\n"),
            "{}",
            &out[out.len() - 200..]
        );
        drop(eve);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

async fn admin_client(server: &app::Running, token: &str) -> AdminClient {
    AdminClient::connect(server.addr, &server.cert_der, token)
        .await
        .expect("admin connects")
}

/// The error that ends `c`'s session when it sends `req`: the request's
/// own, or the `Error` the server sent before it (a periodic check may
/// close the session first, and then the send fails with no code).
async fn ended(c: &mut AdminClient, req: &AdminRequest) -> String {
    let e = c.request(req).await.expect_err("refused").to_string();
    if e.contains("server refused (") {
        return e;
    }
    c.next().await.expect_err("the server's Error").to_string()
}

/// A leaked admin token revoked, or its admin banned, while its session is
/// open: the next request is refused and the connection closes, and an
/// idle session is closed within ADMIN_RECHECK_PERIOD. Others go on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_or_banned_admin_loses_its_open_session() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let mut mal = admin_client(&server, &token(&server, "mal", Role::Admin)).await;
        let mut eve = admin_client(&server, &token(&server, "eve", Role::Admin)).await;
        let mut root = admin_client(&server, &token(&server, "root", Role::Admin)).await;
        assert!(matches!(
            mal.request(&AdminRequest::Players).await.unwrap(),
            AdminResponse::Players(_)
        ));
        let revoke = AdminRequest::RevokeTokens {
            player: "mal".into(),
        };
        assert!(matches!(
            root.request(&revoke).await.unwrap(),
            AdminResponse::Access(_)
        ));
        let e = ended(&mut mal, &AdminRequest::Players).await;
        assert!(e.contains("(Forbidden)") && e.contains("revoked"), "{e}");
        assert!(
            mal.request(&AdminRequest::Stats).await.is_err(),
            "the connection is closed"
        );

        // Eve sends nothing: the periodic check ends her session.
        let ban = AdminRequest::Ban {
            player: "eve".into(),
            until: None,
        };
        assert!(matches!(
            root.request(&ban).await.unwrap(),
            AdminResponse::Access(_)
        ));
        let limit = ADMIN_RECHECK_PERIOD + Duration::from_secs(5);
        let e = tokio::time::timeout(limit, eve.next())
            .await
            .expect("closed within the recheck period")
            .expect_err("refused")
            .to_string();
        assert!(e.contains("(Forbidden)") && e.contains("banned"), "{e}");

        // Root's session outlived several checks.
        match root.request(&AdminRequest::Access).await.unwrap() {
            AdminResponse::Access(a) => {
                assert!(a.bans.iter().any(|(p, _)| p == "eve"));
                assert!(a.revoked_before.iter().any(|(p, _)| p == "mal"));
            }
            other => panic!("unexpected {other:?}"),
        }
        root.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// An admin token's lifetime ends its open session: the first request
/// after it expires fails with `ExpiredToken`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_admin_session_ends_when_its_token_expires() {
    const TTL: Duration = Duration::from_secs(3);
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let issued_at = auth::unix_now();
        let short =
            auth::issue(server.data_dir.secret(), "tmp", Role::Admin, TTL, issued_at).unwrap();
        let mut tmp = admin_client(&server, &short).await;
        assert!(matches!(
            tmp.request(&AdminRequest::Players).await.unwrap(),
            AdminResponse::Players(_)
        ));
        while auth::unix_now() < issued_at + TTL.as_secs() {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let e = ended(&mut tmp, &AdminRequest::Players).await;
        assert!(e.contains("(ExpiredToken)"), "{e}");
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A snapshot does not outlive its admin's token: the session checks the
/// token while the snapshot streams, and ends with `ExpiredToken` even
/// when the client reads nothing (the stream's write is held meanwhile).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_admin_snapshot_ends_with_its_token() {
    use strata_server::admin::snapshot_cmd::{self, RestoreArgs};
    const TTL: Duration = Duration::from_secs(3);
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let data = dir.path().join("data");
        // About 5 MiB: more than the stream takes while nobody reads it.
        let file = dir.path().join("noise.snap");
        crate::snapshot_common::write_noise_snapshot(&file, &crate::snapshot_common::header(1), 80);
        let restored = snapshot_cmd::restore(&RestoreArgs {
            drop_access: false,
            file,
            data_dir: data.clone(),
            force: false,
            config: None,
        })
        .unwrap();
        assert_eq!(restored, 80);
        let server = start(&data).await;
        let issued_at = auth::unix_now();
        let short =
            auth::issue(server.data_dir.secret(), "tmp", Role::Admin, TTL, issued_at).unwrap();
        let mut tmp = admin_client(&server, &short).await;
        tmp.send(&AdminRequest::Snapshot {
            max_pending_chunks: 0,
        })
        .await
        .unwrap();
        assert!(matches!(
            tmp.next().await.unwrap(),
            AdminResponse::SnapshotBegin(_)
        ));
        // Nothing read until the token has run out and been seen to.
        let seen = TTL + ADMIN_RECHECK_PERIOD + Duration::from_secs(2);
        tokio::time::sleep(seen).await;
        let e = loop {
            match tmp.next().await {
                Ok(AdminResponse::SnapshotChunk { .. }) => continue,
                Ok(other) => panic!("the snapshot went on: {other:?}"),
                Err(e) => break e.to_string(),
            }
        };
        assert!(e.contains("(ExpiredToken)"), "{e}");
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// How long the join test waits after its Hello for the server to check
/// it and block on the updates stream (a local Hello takes milliseconds).
const HELLO_CHECKED: Duration = Duration::from_millis(500);

/// A ban between the Hello's check and the engine's Join finds no session
/// to end; the session checks again after the Join and is refused. The
/// client holds the join there by granting no stream credit for the
/// updates stream until the ban is in.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ban_during_a_join_refuses_the_player() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        // Room for the ban within the handshake.
        cfg.server.handshake_timeout_ms = 30_000;
        let server = app::start(cfg).await.expect("server starts");
        let mut tls = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
        let mut transport = quinn::TransportConfig::default();
        transport.max_concurrent_uni_streams(0u32.into());
        tls.transport_config(Arc::new(transport));
        let mut endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
        endpoint.set_default_client_config(tls);
        let conn = endpoint
            .connect(server.addr, "localhost")
            .unwrap()
            .await
            .unwrap();
        let (mut send, recv) = conn.open_bi().await.unwrap();
        let hello = ClientMessage::Hello(Hello {
            protocol_version: PROTOCOL_VERSION,
            token: token(&server, "eve", Role::Player),
            capabilities: 0,
        });
        let frame = encode_frame(&hello, Direction::ClientToServer).unwrap();
        send.write_all(&frame).await.unwrap();
        tokio::time::sleep(HELLO_CHECKED).await;
        let out = online(&server, &["ban", "eve"]);
        assert!(out.contains("banned eve"), "{out}");
        assert!(!out.contains("ended"), "eve had not joined yet: {out}");
        conn.set_max_concurrent_uni_streams(1u32.into());
        let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient));
        let refusal = loop {
            match reader.next::<ServerMessage>().await {
                Ok(Some(ServerMessage::Error { code, message })) => break (code, message),
                Ok(Some(ServerMessage::Welcome(_))) => panic!("a banned player got Welcome"),
                Ok(Some(_)) => continue,
                other => panic!("expected Error, got {other:?}"),
            }
        };
        assert_eq!(refusal.0, ErrorCode::Forbidden, "{}", refusal.1);
        assert!(refusal.1.contains("banned"), "{}", refusal.1);
        // The engine let the session go.
        let mut sessions = live_sessions(&server).await;
        for _ in 0..100 {
            if sessions == 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
            sessions = live_sessions(&server).await;
        }
        assert_eq!(sessions, 0);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
