//! A bot that stops reading its updates does not hold back the others:
//! their edits are acknowledged every second, their deltas keep arriving
//! promptly (not held back and then caught up), and their replicas
//! converge. And the stalled bot does put the server under backpressure:
//! its updates stream's small receive window (`--stalled-window`) fills,
//! then its writer queue (`[net] writer_queue`), and the server drops the
//! deltas meant for it (withdrawing their chunks) instead of waiting.

use strata_tests::{
    assert_converged, bots_summary, free_local_addr, metric, num, spawn_bots, Server, SERVER_CONFIG,
};

/// Bound on the honest bots' broadcast p99 (a debug build on a busy 2-core
/// box: tens of ms usually, slow ticks of a few hundred): a delta the
/// stalled reader held back for a couple of seconds would exceed it.
const MAX_BROADCAST_P99_MS: f64 = 2_000.0;

/// Frames the server queues per session's updates stream (default 256):
/// small, so that the stalled bot's queue fills within a couple of seconds
/// of edits. Still room for 16 ticks of updates an honest bot's writer has
/// not taken yet (160 ms at `tick_ms = 10`), where it takes each at once.
const WRITER_QUEUE: usize = 16;

/// The stalled bot's updates-stream receive window, bytes (the client's
/// own is 1.25 MB, more than 8 s of these edits send it): what the server
/// can write to it before QUIC's flow control holds the rest in the queue.
const STALLED_WINDOW: &str = "1024";

#[test]
fn a_stalled_reader_does_not_stop_the_others() {
    let tmp = tempfile::tempdir().unwrap();
    let metrics = free_local_addr();
    let config = format!(
        "{SERVER_CONFIG}[net]\nwriter_queue = {WRITER_QUEUE}\n\
         [metrics]\nlisten = \"{metrics}\"\n"
    );
    let server = Server::start_with(&tmp.path().join("data"), "127.0.0.1:0", &config);
    // Demolition: every edit changes chunks, all in the stalled bot's
    // view (six bots' homes span three chunks; radius 3 covers them), so
    // each tick with an edit owes it a batch of deltas.
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "6",
            "--stalled",
            "1",
            "--stalled-window",
            STALLED_WINDOW,
            "--profile",
            "demolition",
            "--view-radius",
            "3",
            "--edit-rate",
            "3",
            "--duration",
            "8s",
        ],
    );
    let (status, s) = bots_summary(bots);
    assert!(status.success(), "strata-bots exit {status}: {s}");
    assert_eq!(num(&s, "stalled"), 1);
    // The server refused the stalled session's updates (its queue was
    // full) and dropped their deltas: backpressure, not just a client
    // reading nothing while little came.
    let dropped = metric(&metrics, "strata_deltas_dropped_total");
    let sent = metric(&metrics, "strata_deltas_sent_total");
    assert!(
        dropped.is_some_and(|d| d > 0.0),
        "no delta dropped (the stalled bot's queue never filled): \
         strata_deltas_dropped_total {dropped:?}, strata_deltas_sent_total {sent:?}"
    );
    eprintln!("stalled_bot: deltas dropped {dropped:?}, sent {sent:?}");
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
