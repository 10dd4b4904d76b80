//! SIGKILL the server while bots edit, restart it on the same port: nothing
//! acknowledged is lost (`strata-admin verify-acks`), and the bots
//! reconnect, resync and converge again.

use std::time::Duration;

use strata_tests::{assert_converged, bots_summary, num, spawn_bots, verify_acks, Server};

#[test]
fn killed_server_loses_no_acknowledged_edit_and_bots_converge() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let acks = tmp.path().join("acks.jsonl");
    let server = Server::start(&data, "127.0.0.1:0");
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
    std::thread::sleep(Duration::from_secs(4));
    let before_kill = std::fs::read_to_string(&acks).unwrap().lines().count();
    server.kill();
    std::thread::sleep(Duration::from_millis(500));
    let server = Server::start(&data, &listen);
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
    assert_eq!(num(&report, "failure_count"), 0);
}
