//! Power cuts under load, on LazyFS: the server is SIGKILLed while bots
//! edit, every write it never fsynced is dropped, and it restarts on what
//! is left. No acknowledged edit is lost and no seq is handed out twice
//! (`strata-admin verify-acks` over all the cycles' acknowledgements),
//! the store checks clean, and the bots reconnect and converge.
//!
//! Each cycle runs sled's background thread differently (off, the
//! default period, a long one): durability must not depend on it. Then
//! power cuts while the server starts again (sled's recovery rewrites its
//! log's tail, the engine reloads): what the next start finds still opens,
//! and still holds every acknowledged edit.

use std::process::{Command, Stdio};
use std::time::Duration;

use strata_tests::lazyfs::LazyFs;
use strata_tests::{
    assert_converged, await_lines, binary, bots_summary, num, spawn_bots, verify_acks, Server,
};

/// sled background periods the cycles take in turn, in ms (0: no
/// background thread).
const PERIODS: [u64; 3] = [0, 20, 500];
/// Power cuts during the bots' run, unless `STRATA_POWER_CUTS` says how
/// many (a longer soak: the run lasts 4 s more per cut).
const DEFAULT_CUTS: usize = 3;
/// New acknowledgements each cycle waits for before its cut: the bots
/// (6 at 4 edits a second) reconnected and edit again.
const NEW_ACKS_PER_CYCLE: usize = 12;
/// After the run, power cuts this long after a start, before or after the
/// server has opened its store and printed its address.
const STARTUP_CUTS_MS: [u64; 5] = [5, 40, 150, 400, 1_000];

fn config(flush_every_ms: u64) -> String {
    format!("[engine]\ntick_ms = 10\n\n[store]\nflush_every_ms = {flush_every_ms}\n")
}

#[test]
fn power_cuts_lose_no_acknowledged_edit_and_reuse_no_seq() {
    let Some(mut fs) = LazyFs::for_test("power_cuts_lose_no_acknowledged_edit_and_reuse_no_seq")
    else {
        return;
    };
    // The ack log lives off LazyFS: it is the clients' memory, not the server's.
    let acks = fs.dir().join("acks.jsonl");
    let data = fs.mount_dir().join("data");

    let cuts = std::env::var("STRATA_POWER_CUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(DEFAULT_CUTS);
    // Ended by SIGTERM once the last restart took edits: the cycles wait
    // for edits, however long a slow box takes.
    let run = "600s";
    let mut server = Server::start_with(&data, "127.0.0.1:0", &config(PERIODS[0]));
    let listen = server.addr.to_string();
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "6",
            "--duration",
            run,
            "--silence-limit",
            "2s",
            "--edit-rate",
            "4",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    let mut acked_before_cuts = Vec::new();
    for i in 0..cuts {
        // Each cut once edits flow again (the bots joined, or reconnected
        // to the restarted server), however long that took.
        let last = acked_before_cuts.last().copied().unwrap_or(0);
        let what = format!("edits acknowledged before cut {}", i + 1);
        acked_before_cuts.push(await_lines(&acks, last + NEW_ACKS_PER_CYCLE, &what));
        server.kill();
        fs.power_cut();
        let next = PERIODS[(i + 1) % PERIODS.len()];
        server = Server::start_with(&data, &listen, &config(next));
    }
    let last = acked_before_cuts.last().copied().unwrap_or(0);
    await_lines(
        &acks,
        last + NEW_ACKS_PER_CYCLE,
        "edits acknowledged after the last restart",
    );
    bots.terminate();
    let (status, s) = bots_summary(bots);
    // A last cut after the run: the final acknowledgements must survive too.
    server.kill();
    fs.power_cut();
    // Cuts during recovery, then a start that must get through it.
    for ms in STARTUP_CUTS_MS {
        let mut starting = Server::spawn(&data, &listen, &config(PERIODS[0]), Stdio::inherit());
        std::thread::sleep(Duration::from_millis(ms));
        starting.0.kill().expect("kill the starting server");
        starting.0.wait().expect("reap the starting server");
        fs.power_cut();
    }
    Server::start_with(&data, &listen, &config(PERIODS[1])).stop();

    // Durability first: the clients' acknowledgements against the store.
    let (verified, report) = verify_acks(&data, &acks);
    assert_eq!(
        num(&report, "failure_count"),
        0,
        "acknowledged edits lost or changed: {report}"
    );
    assert!(verified.success(), "verify-acks: {report}");
    assert_eq!(
        num(&report, "records"),
        num(&s, "edits_accepted"),
        "{report}"
    );
    eprintln!(
        "power cuts: {} during the run, 1 after and {} while starting, {} acknowledged edits, none lost",
        cuts,
        STARTUP_CUTS_MS.len(),
        num(&report, "records")
    );
    assert!(status.success(), "strata-bots exit {status}: {s}");

    let mut last = 0;
    for n in &acked_before_cuts {
        assert!(
            *n > last,
            "edits were acknowledged before every cut: {acked_before_cuts:?}"
        );
        last = *n;
    }
    assert!(num(&s, "reconnects") >= 6 * cuts as u64, "{s}");
    assert_eq!(num(&s, "connected_at_end"), 6, "{s}");
    assert!(
        num(&s, "edits_accepted") as usize > last,
        "edits after the last restart: {s}"
    );
    assert_converged(&s);

    let check = Command::new(binary("strata-admin"))
        .args(["check", "--data-dir"])
        .arg(&data)
        .output()
        .expect("strata-admin check runs");
    assert!(
        check.status.success(),
        "check after the power cuts: {}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
}
