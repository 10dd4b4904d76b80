//! A bot that stops reading its updates does not hold back the others:
//! their edits are acknowledged every second, their deltas keep arriving
//! promptly (not held back and then caught up), and their replicas
//! converge.

use strata_tests::{assert_converged, bots_summary, num, spawn_bots, Server};

/// Bound on the honest bots' broadcast p99 (a debug build on a busy 2-core
/// box: tens of ms usually, slow ticks of a few hundred): a delta the
/// stalled reader held back for a couple of seconds would exceed it.
const MAX_BROADCAST_P99_MS: f64 = 2_000.0;

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
    // Not held back and then caught up: the stall lasts the whole edit
    // window, and no delta reached an honest bot late (a delta held back
    // for a while carries that while in its latency), and the server
    // acknowledged edits in every second of it.
    let broadcast_p99 = s["broadcast_latency_ms"]["p99"].as_f64().expect("p99");
    assert!(
        broadcast_p99 < MAX_BROADCAST_P99_MS,
        "broadcast p99 {broadcast_p99} ms: deltas held back: {}",
        s["latency_by_second"]
    );
    let seconds = s["latency_by_second"]
        .as_array()
        .expect("latency_by_second");
    let window = s["duration_s"].as_f64().expect("duration_s") as usize;
    assert!(seconds.len() >= window, "{}", s["latency_by_second"]);
    for second in &seconds[..window] {
        assert!(
            num(&second["ack"], "count") > 0,
            "no edit acknowledged in second {}: {}",
            second["second"],
            s["latency_by_second"]
        );
    }
    server.stop();
}
