//! Bans and token revocations through `strata-admin`, online (the change
//! ends live sessions and is refused at the next Hello) and offline (a
//! stopped server's stored list), and both survive a restart.

use crate::common;

use std::process::Command;
use std::time::Duration;

use common::*;
use strata_client_sim::{Client, ClientError};
use strata_protocol::{ErrorCode, Role};
use strata_server::app;

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
        tokio::time::sleep(Duration::from_millis(1100)).await;
        let fresh = token(&server, "eve", Role::Player);
        let eve = Client::connect(server.addr, &server.cert_der, &fresh)
            .await
            .expect("a token issued after the revocation works");
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
