//! A bot that stops reading its updates does not hold back the others:
//! their edits are acknowledged, their deltas keep arriving, and their
//! replicas converge.

use strata_tests::{assert_converged, bots_summary, num, spawn_bots, Server};

#[test]
fn a_stalled_reader_does_not_stop_the_others() {
    let tmp = tempfile::tempdir().unwrap();
    let server = Server::start(&tmp.path().join("data"), "127.0.0.1:0");
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "6",
            "--stalled",
            "1",
            "--profile",
            "explorers",
            "--view-radius",
            "3",
            "--edit-rate",
            "2",
            "--duration",
            "8s",
        ],
    );
    let (status, s) = bots_summary(bots);
    assert!(status.success(), "strata-bots exit {status}: {s}");
    assert_eq!(num(&s, "stalled"), 1);
    assert_converged(&s);
    assert!(num(&s, "edits_accepted") >= 40, "{s}");
    assert!(num(&s["broadcast_latency_ms"], "count") > 0, "{s}");
    server.stop();
}
