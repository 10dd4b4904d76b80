//! SIGKILL the server while bots edit, restart it on the same port: nothing
//! acknowledged is lost (`strata-admin verify-acks`), and the bots
//! reconnect, resync and converge again. The same run on the PostgreSQL
//! store ends with an offline snapshot of it.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use strata_tests::postgres::database;
use strata_tests::{
    assert_converged, await_lines, binary, bots_summary, count, num, spawn_bots, verify_acks,
    wait_with_output, Guard, Server, SERVER_CONFIG,
};

/// Acknowledged edits before the kill: the bots are editing (8 bots at 3
/// edits a second make these in about a second).
const ACKED_BEFORE_KILL: usize = 24;

#[test]
fn killed_server_loses_no_acknowledged_edit_and_bots_converge() {
    let tmp = tempfile::tempdir().unwrap();
    crash_run(tmp.path(), SERVER_CONFIG);
}

#[test]
fn killed_server_on_postgres_loses_no_acknowledged_edit_and_snapshots() {
    let Some(db) = database("crash_restart") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let data = crash_run(tmp.path(), &format!("{SERVER_CONFIG}{}", db.store_toml()));
    let snap = tmp.path().join("world.snap");
    admin(&[
        "snapshot",
        "create",
        "--out",
        p(&snap),
        "--data-dir",
        p(&data),
    ]);
    let verified = admin(&["snapshot", "verify", p(&snap)]);
    // Taken from PostgreSQL after the run: it holds the run's edits.
    let seq: u64 = verified
        .trim_start_matches("ok: seq ")
        .split(',')
        .next()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or_else(|| panic!("no seq in {verified:?}"));
    assert!(seq > 0, "{verified} (database {})", db.name());
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Runs `strata-admin ARGS` to success and returns its stdout.
fn admin(args: &[&str]) -> String {
    let child = Command::new(binary("strata-admin"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("strata-admin starts");
    let (status, out) = wait_with_output(Guard(child), Duration::from_secs(60));
    assert!(status.success(), "strata-admin {args:?}: {status}: {out}");
    out
}

/// Bots edit, the server is SIGKILLed and restarted, and verify-acks finds
/// every acknowledged edit. Returns the data dir, which names its store
/// in `strata.toml` for the offline tools.
fn crash_run(tmp: &Path, config: &str) -> std::path::PathBuf {
    let data = tmp.join("data");
    let acks = tmp.join("acks.jsonl");
    let server = Server::start_with(&data, "127.0.0.1:0", config);
    std::fs::write(data.join("strata.toml"), config).unwrap();
    let listen = server.addr.to_string();
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "8",
            "--duration",
            "14s",
            "--silence-limit",
            "2s",
            "--edit-rate",
            "3",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    // Killed once edits flow, however long the bots took to join.
    let before_kill = await_lines(&acks, ACKED_BEFORE_KILL, "edits before the kill");
    server.kill();
    std::thread::sleep(Duration::from_millis(500));
    let server = Server::start_with(&data, &listen, config);
    let (status, s) = bots_summary(bots);
    assert!(status.success(), "strata-bots exit {status}: {s}");
    assert!(before_kill > 0, "edits were acknowledged before the kill");
    assert!(num(&s, "reconnects") >= 8, "every bot reconnected: {s}");
    assert_eq!(num(&s, "connected_at_end"), 8, "{s}");
    assert!(
        num(&s, "edits_accepted") as usize > before_kill,
        "edits were acknowledged after the restart: {s}"
    );
    assert_converged(&s);
    server.kill();
    let (status, report) = verify_acks(&data, &acks);
    assert!(status.success(), "verify-acks: {report}");
    assert_eq!(num(&report, "records"), num(&s, "edits_accepted"));
    assert_eq!(count(&report, "failure_count"), 0);
    data
}
