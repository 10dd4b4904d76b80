//! When the store fails under the engine (here: the disk under the data
//! dir goes away), the server does not linger half-alive refusing
//! everyone: it closes its sessions and exits non-zero at once, so a
//! supervisor restarts it. Before that, `/healthz` reports it ready.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use strata_tests::lazyfs::LazyFs;
use strata_tests::{spawn_bots, Server, SERVER_CONFIG};

/// How soon after the disk fails the process must be gone: the next
/// commit (edits every 200 ms) fails, then shutdown closes the sessions.
const EXIT_WITHIN: Duration = Duration::from_secs(2);

fn get(addr: &str, path: &str) -> String {
    let mut s = std::net::TcpStream::connect(addr).expect("metrics listener");
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).unwrap();
    out
}

#[test]
fn a_failed_store_ends_the_process_with_an_error() {
    let Some(mut fs) = LazyFs::for_test("a_failed_store_ends_the_process_with_an_error") else {
        return;
    };
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let metrics = format!("127.0.0.1:{port}");
    let config = format!("{SERVER_CONFIG}\n[metrics]\nlisten = \"{metrics}\"\n");
    let data = fs.mount_dir().join("data");
    let mut server = Server::start_with(&data, "127.0.0.1:0", &config);
    let health = get(&metrics, "/healthz");
    assert!(health.starts_with("HTTP/1.1 200"), "{health}");
    let _bots = spawn_bots(
        &server,
        &["--bots", "2", "--duration", "30s", "--edit-rate", "5"],
    );
    std::thread::sleep(Duration::from_secs(3));
    fs.fail();
    let failed = Instant::now();
    let status = server.proc.wait_timeout(Duration::from_secs(30));
    let took = failed.elapsed();
    assert!(!status.success(), "the server exited with {status}");
    assert!(took < EXIT_WITHIN, "the server took {took:?} to exit");
    eprintln!("server exited {took:?} after the disk failed, with {status}");
}
