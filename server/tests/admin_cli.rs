//! The real `strata-admin` process against a real `strata-server` process:
//! online zones, players, stats (the token also from --token-file),
//! inspect and snapshot create; then verify
//! (a corrupt byte is named by record), restore (refused when corrupt or
//! onto a non-empty dir) and diff, and the offline forms on the stopped dir.

use crate::common;

use std::path::Path;
use std::process::{Command, Output};

use common::*;

fn admin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strata-admin"))
        .args(args)
        .output()
        .expect("strata-admin runs")
}

fn ok(args: &[&str]) -> String {
    let out = admin(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

fn fails(args: &[&str]) -> String {
    let out = admin(args);
    assert!(!out.status.success(), "{args:?} should fail");
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

#[tokio::test]
async fn admin_cli_online_then_offline() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let (mut child, addr) = spawn_server(&data, FAST_EDITS);
    let addr_s = addr.to_string();
    let cert = data.join("cert.der");
    let token = ok(&[
        "token",
        "issue",
        "--data-dir",
        p(&data),
        "--player",
        "root",
        "--role",
        "admin",
    ]);
    let token = token.trim();
    let player_token = ok(&["token", "issue", "--data-dir", p(&data), "--player", "bob"]);
    let online = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
        v.extend(["--server", &addr_s, "--cert", p(&cert), "--token", token].map(String::from));
        v
    };
    let run = |args: Vec<String>| ok(&args.iter().map(String::as_str).collect::<Vec<_>>());

    // A player session to list and kick.
    let bob = process_client(&data, addr, "bob").await;
    let zones = run(online(&[
        "zones", "add", "vault", "--min", "-5", "0", "-5", "--max", "5", "9", "5",
    ]));
    assert!(zones.contains("vault (-5, 0, -5) to (5, 9, 5)"), "{zones}");
    assert!(run(online(&["zones", "list"])).contains("vault"));
    let players = run(online(&["players", "list"]));
    assert!(players.contains("bob player"), "{players}");
    let stats = run(online(&["stats"]));
    assert!(
        stats.contains("sessions: 1") && stats.contains("seq: 0"),
        "{stats}"
    );
    let inspect = run(online(&["inspect", "chunk", "2", "0", "1"]));
    assert!(
        inspect.contains("state: generated") && inspect.contains("version: 0"),
        "{inspect}"
    );
    assert!(run(online(&["kick", "bob"])).contains("kicked 1 session"));
    let end = tokio::time::timeout(TEST_TIMEOUT, bob.closed())
        .await
        .unwrap();
    assert!(end.to_string().contains("Kicked"), "{end}");
    // A player token is refused by the real CLI too.
    let mut refused = online(&["stats"]);
    let last = refused.len() - 1;
    refused[last] = player_token.trim().to_string();
    let msg = fails(&refused.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(msg.contains("Forbidden"), "{msg}");
    // The token from a file, off the command line (whitespace ignored).
    let token_file = tmp.path().join("admin.token");
    std::fs::write(&token_file, format!("  {token}\n")).unwrap();
    let from_file = |extra: &[&'static str]| -> Vec<&str> {
        let mut v = extra.to_vec();
        v.extend([
            "--server",
            &addr_s,
            "--cert",
            p(&cert),
            "--token-file",
            p(&token_file),
        ]);
        v
    };
    assert!(ok(&from_file(&["stats"])).contains("sessions: 0"));
    let empty = tmp.path().join("empty.token");
    std::fs::write(&empty, "\n").unwrap();
    let mut no_token = from_file(&["stats"]);
    let last = no_token.len() - 1;
    no_token[last] = p(&empty);
    let msg = fails(&no_token);
    assert!(msg.contains("is empty"), "{msg}");
    let mut both = from_file(&["stats"]);
    both.extend(["--token", token]);
    assert!(fails(&both).contains("cannot be used with"));

    let snap = tmp.path().join("a.snap");
    let created = run(online(&["snapshot", "create", "--out", p(&snap)]));
    assert!(created.contains("snapshot at seq 0"), "{created}");
    child.kill().unwrap();
    child.wait().unwrap();

    // Offline, on the stopped server's dir.
    assert!(ok(&["stats", "--data-dir", p(&data)]).contains("modified_chunks: 0"));
    assert!(ok(&["zones", "list", "--data-dir", p(&data)]).contains("vault"));
    let gen = ok(&["inspect", "chunk", "2", "0", "1", "--data-dir", p(&data)]);
    assert_eq!(gen, inspect, "offline and online inspect agree");
    ok(&["zones", "remove", "vault", "--data-dir", p(&data)]);
    let snap_b = tmp.path().join("b.snap");
    ok(&[
        "snapshot",
        "create",
        "--out",
        p(&snap_b),
        "--data-dir",
        p(&data),
    ]);
    assert!(ok(&["snapshot", "verify", p(&snap)]).contains("ok: seq 0, 0 chunks"));
    assert!(ok(&["snapshot", "diff", p(&snap), p(&snap_b)]).contains("0 chunks differ"));

    // Restore: refuses a non-empty dir without --force.
    let msg = fails(&["snapshot", "restore", p(&snap), "--data-dir", p(&data)]);
    assert!(msg.contains("--force"), "{msg}");
    let fresh = tmp.path().join("fresh");
    ok(&["snapshot", "restore", p(&snap), "--data-dir", p(&fresh)]);
    assert!(ok(&["zones", "list", "--data-dir", p(&fresh)]).contains("vault"));
    // Sessions exist only on a running server.
    let msg = fails(&["players", "list", "--data-dir", p(&fresh)]);
    assert!(msg.contains("only on a running server"), "{msg}");

    // One corrupt byte in the header's zones: verify names it, restore refuses.
    let mut bytes = std::fs::read(&snap).unwrap();
    let at = bytes.len() - 20;
    bytes[at] ^= 0x40;
    let bad = tmp.path().join("bad.snap");
    std::fs::write(&bad, &bytes).unwrap();
    let msg = fails(&["snapshot", "verify", p(&bad)]);
    assert!(msg.contains("corrupt"), "{msg}");
    let msg = fails(&[
        "snapshot",
        "restore",
        p(&bad),
        "--data-dir",
        p(&tmp.path().join("never")),
    ]);
    assert!(msg.contains("nothing restored"), "{msg}");
    assert!(!tmp.path().join("never").exists(), "nothing written");
}
