//! Twenty bots with the mixed profile against a `strata-server` process:
//! every replica ends equal to the server's world, every mesh matches, all
//! bots saw one global order of versions, and the store holds every
//! acknowledged edit.

use strata_tests::{assert_converged, bots_summary, num, spawn_bots, verify_acks, Server};

#[test]
fn twenty_mixed_bots_converge_in_one_global_order() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let acks = tmp.path().join("acks.jsonl");
    let server = Server::start(&data, "127.0.0.1:0");
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "20",
            "--profile",
            "mixed",
            "--duration",
            "20s",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    let (status, s) = bots_summary(bots);
    assert!(status.success(), "strata-bots exit {status}: {s}");
    assert_eq!(num(&s, "bots"), 20);
    assert_eq!(num(&s, "connected_at_end"), 20, "{s}");
    assert_converged(&s);
    // Mostly accepted edits, whose deltas reached other bots and were meshed.
    let accepted = num(&s, "edits_accepted");
    assert!(accepted * 10 >= num(&s, "edits_sent") * 9, "{s}");
    assert!(accepted >= 100, "{s}");
    assert!(num(&s["broadcast_latency_ms"], "count") > 0, "{s}");
    assert!(num(&s, "meshes_checked") > 0, "{s}");
    assert!(s["mean_delta_bytes"].as_f64().unwrap() > 0.0, "{s}");
    // Ordering: any two bots holding one chunk version held the same bytes,
    // and no replica's versions went backwards (order_violations == 0 above).
    server.stop();
    let (status, report) = verify_acks(&data, &acks);
    assert!(status.success(), "verify-acks: {report}");
    assert_eq!(num(&report, "records"), accepted, "{report}");
    // An acknowledgement the store never saw fails the check.
    let mut log = std::fs::read_to_string(&acks).unwrap();
    log.push_str(&format!(
        "{{\"seq\":{},\"chunks\":[]}}\n",
        num(&report, "last_seq") + 1
    ));
    std::fs::write(&acks, log).unwrap();
    let (status, report) = verify_acks(&data, &acks);
    assert!(!status.success(), "{report}");
    assert_eq!(num(&report, "failure_count"), 1, "{report}");
}
