//! `/healthz` answers from the moment the metrics port is bound: while the
//! server is still starting (here: its PostgreSQL world held by a lock) it
//! says 503, instead of leaving a probe's connection hanging until it
//! times out (which orchestrators read as a dead server).

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use strata_tests::{binary, free_local_addr, Guard, Server, SERVER_CONFIG};

/// How long the test waits for each answer it expects.
const WITHIN: Duration = Duration::from_secs(20);

/// `GET /healthz`'s status line, or `None` when nothing answers in time.
fn health(addr: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(2))).ok()?;
    write!(
        s,
        "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    out.lines().next().map(str::to_string)
}

/// The first status line within [`WITHIN`] that starts with `want`.
fn await_health(addr: &str, want: &str) -> String {
    let deadline = Instant::now() + WITHIN;
    let mut last = None;
    while Instant::now() < deadline {
        last = health(addr);
        if last.as_deref().is_some_and(|l| l.starts_with(want)) {
            return last.unwrap();
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("no {want:?} from /healthz within {WITHIN:?}; last {last:?}");
}

/// A server started again on `test`'s PostgreSQL world while a session
/// holds the world's table locked, so it stays starting; its `/healthz`
/// already answers 503. Release the lock by writing `COMMIT;` to the
/// returned stdin.
struct Starting {
    _db: strata_tests::postgres::PgDb,
    _tmp: tempfile::TempDir,
    metrics: String,
    sql: std::process::ChildStdin,
    lock: Guard,
    server: Guard,
}

fn starting_behind_a_lock(test: &str) -> Option<Starting> {
    let db = strata_tests::postgres::database(test)?;
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let metrics = free_local_addr();
    let config = format!(
        "{SERVER_CONFIG}{}[metrics]\nlisten = \"{metrics}\"\n",
        db.store_toml()
    );
    // A first start makes the world's tables.
    Server::start_with(&data, "127.0.0.1:0", &config).stop();

    // A session holds the world's row table while the server starts again.
    let psql = strata_tests::postgres::bin_dir().unwrap().join("psql");
    let mut lock = Guard(
        Command::new(psql)
            .args(["-X", "-v", "ON_ERROR_STOP=1", &db.url()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("psql starts"),
    );
    let mut sql = lock.0.stdin.take().unwrap();
    writeln!(sql, "BEGIN; LOCK TABLE world IN ACCESS EXCLUSIVE MODE;").unwrap();
    let mut said = BufReader::new(lock.0.stdout.take().unwrap()).lines();
    assert!(
        said.by_ref().any(|l| l.unwrap() == "LOCK TABLE"),
        "the lock was taken"
    );
    let server = Guard(
        Command::new(binary("strata-server"))
            .arg("--config")
            .arg(data.with_extension("toml"))
            .arg("--data-dir")
            .arg(&data)
            .args(["--listen", "127.0.0.1:0"])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .spawn()
            .expect("strata-server starts"),
    );
    let metrics = metrics.to_string();
    let starting = await_health(&metrics, "HTTP/1.1 503");
    eprintln!("while starting: {starting}");
    Some(Starting {
        _db: db,
        _tmp: tmp,
        metrics,
        sql,
        lock,
        server,
    })
}

#[test]
fn healthz_says_not_ready_while_the_server_starts() {
    let Some(mut s) = starting_behind_a_lock("healthz_starting") else {
        return;
    };
    // Let it go: the start finishes and the server is ready.
    writeln!(s.sql, "COMMIT;").unwrap();
    drop(s.sql);
    let ready = await_health(&s.metrics, "HTTP/1.1 200");
    eprintln!("started: {ready}");
    s.server.terminate();
    assert!(s.server.wait_timeout(Duration::from_secs(30)).success());
    s.lock.wait_timeout(Duration::from_secs(10));
}

/// SIGTERM while the server starts (a supervisor stopping it at once) is
/// caught, not the default kill: the start finishes and the server shuts
/// down cleanly, exit status 0.
#[test]
fn a_stop_while_starting_is_a_clean_shutdown() {
    let Some(mut s) = starting_behind_a_lock("stop_while_starting") else {
        return;
    };
    s.server.terminate();
    std::thread::sleep(Duration::from_millis(300));
    writeln!(s.sql, "COMMIT;").unwrap();
    drop(s.sql);
    let status = s.server.wait_timeout(Duration::from_secs(30));
    assert!(status.success(), "strata-server exited with {status}");
    s.lock.wait_timeout(Duration::from_secs(10));
}
