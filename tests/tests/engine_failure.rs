//! When the store fails under the engine (here: the disk under the data
//! dir goes away), the server does not linger half-alive refusing
//! everyone: it closes its sessions and exits non-zero at once, so a
//! supervisor restarts it. Before that, `/healthz` reports it ready.

use std::time::{Duration, Instant};

use strata_tests::lazyfs::LazyFs;
use strata_tests::{await_lines, free_local_addr, http_get, spawn_bots, Server, SERVER_CONFIG};

/// How soon after the disk fails the process must be gone: the next
/// commit (edits every 200 ms) fails, then shutdown closes the sessions.
const EXIT_WITHIN: Duration = Duration::from_secs(2);

#[test]
fn a_failed_store_ends_the_process_with_an_error() {
    let Some(mut fs) = LazyFs::for_test("a_failed_store_ends_the_process_with_an_error") else {
        return;
    };
    let metrics = free_local_addr();
    let config = format!("{SERVER_CONFIG}\n[metrics]\nlisten = \"{metrics}\"\n");
    let data = fs.mount_dir().join("data");
    let mut server = Server::start_with(&data, "127.0.0.1:0", &config);
    let health = http_get(&metrics, "/healthz");
    assert!(health.starts_with("HTTP/1.1 200"), "{health}");
    // The ack log lives off LazyFS: it must not fail with the disk.
    let acks = fs.dir().join("acks.jsonl");
    let _bots = spawn_bots(
        &server,
        &[
            "--bots",
            "2",
            "--duration",
            "30s",
            "--edit-rate",
            "5",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    // The disk fails once edits are being committed.
    await_lines(&acks, 5, "edits before the disk failed");
    fs.fail();
    let failed = Instant::now();
    let status = server.proc.wait_timeout(Duration::from_secs(30));
    let took = failed.elapsed();
    assert!(!status.success(), "the server exited with {status}");
    assert!(took < EXIT_WITHIN, "the server took {took:?} to exit");
    eprintln!("server exited {took:?} after the disk failed, with {status}");
}
