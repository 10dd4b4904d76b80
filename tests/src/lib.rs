//! Helpers for the end-to-end tests in `tests/tests/`: they run the real
//! `strata-server`, `strata-bots` and `strata-admin` binaries as child
//! processes, bounded in time and killed if a test fails.
//!
//! The binaries belong to other packages, so they are looked up next to the
//! test executable (`target/<profile>/`) and built with cargo if missing.

use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

pub mod chromium;
pub mod lazyfs;
pub mod postgres;

/// Longest any child process may run before the test fails.
pub const PROCESS_TIMEOUT: Duration = Duration::from_secs(120);
/// Longest wait for a server to print its address.
pub const SERVER_START_TIMEOUT: Duration = Duration::from_secs(30);

/// Server config for the tests: small and fast, loopback only.
pub const SERVER_CONFIG: &str = "[engine]\ntick_ms = 10\n";

/// `target/<profile>/`, where cargo puts the workspace binaries.
fn bin_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let deps = exe.parent().expect("deps dir");
    deps.parent().expect("profile dir").to_path_buf()
}

/// The path of a workspace binary, building its package once if absent.
pub fn binary(name: &str) -> PathBuf {
    static BUILT: OnceLock<()> = OnceLock::new();
    let dir = bin_dir();
    let path = dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    if !path.exists() {
        BUILT.get_or_init(|| {
            let target = dir.parent().expect("target dir");
            let mut cmd = Command::new(env!("CARGO"));
            cmd.args([
                "build",
                "-p",
                "strata-server",
                "-p",
                "strata-client-sim",
                "--bins",
            ])
            .arg("--target-dir")
            .arg(target);
            // The profile the tests were built with: `test` lives in debug/.
            match dir.file_name().and_then(|n| n.to_str()) {
                Some("release") => cmd.arg("--release"),
                _ => cmd.args(["--profile", "test"]),
            };
            let status = cmd.status().expect("cargo runs");
            assert!(status.success(), "building the binaries failed");
        });
    }
    assert!(path.exists(), "{} was not built", path.display());
    path
}

/// Says that `test` did not run for want of `what` (and why) and returns
/// `None`; under `CI=true` the test fails instead.
pub fn not_run<T>(test: &str, what: &str, why: &str) -> Option<T> {
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{test} needs {what} under CI: {why}");
    }
    eprintln!("NOT RUN: {test} needs {what}: {why}");
    None
}

/// A child process killed when dropped (a failing test leaves nothing behind).
#[derive(Debug)]
pub struct Guard(pub Child);

impl Guard {
    /// Sends SIGTERM (`strata-bots`: the edits end early, the summary
    /// follows).
    pub fn terminate(&self) {
        let pid = self.0.id().to_string();
        let ok = Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill -TERM {pid}");
    }

    /// Waits for the process to exit, killing it after `limit`.
    pub fn wait_timeout(&mut self, limit: Duration) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(status) = self.0.try_wait().expect("try_wait") {
                return status;
            }
            if start.elapsed() > limit {
                let _ = self.0.kill();
                panic!("process {} ran longer than {limit:?}", self.0.id());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Guard {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// A `strata-server` child process.
#[derive(Debug)]
pub struct Server {
    pub proc: Guard,
    pub addr: SocketAddr,
    pub data_dir: PathBuf,
}

impl Server {
    /// Starts the server on `listen` (port 0 picks one) and reads the
    /// address it prints.
    pub fn start(data_dir: &Path, listen: &str) -> Server {
        Self::start_with(data_dir, listen, SERVER_CONFIG)
    }

    /// [`Server::start`] with the config file's text.
    pub fn start_with(data_dir: &Path, listen: &str, config_text: &str) -> Server {
        Self::start_logging(data_dir, listen, config_text, Stdio::inherit())
    }

    /// [`Server::start_with`], its log (stderr) going to `stderr`.
    pub fn start_logging(
        data_dir: &Path,
        listen: &str,
        config_text: &str,
        stderr: Stdio,
    ) -> Server {
        let mut proc = Self::spawn(data_dir, listen, config_text, stderr);
        let stdout = proc.0.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let line = rx
            .recv_timeout(SERVER_START_TIMEOUT)
            .expect("strata-server printed its address");
        let addr = line
            .split_whitespace()
            .find_map(|w| w.parse::<SocketAddr>().ok())
            .unwrap_or_else(|| panic!("no address in {line:?}"));
        Server {
            proc,
            addr,
            data_dir: data_dir.to_path_buf(),
        }
    }

    /// The server's process, its stdout piped and not read: it may still
    /// be opening its store (a test that kills it during recovery).
    pub fn spawn(data_dir: &Path, listen: &str, config_text: &str, stderr: Stdio) -> Guard {
        let config = data_dir.with_extension("toml");
        std::fs::write(&config, config_text).expect("write config");
        let child = Command::new(binary("strata-server"))
            .arg("--config")
            .arg(&config)
            .arg("--data-dir")
            .arg(data_dir)
            .arg("--listen")
            .arg(listen)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .expect("strata-server starts");
        Guard(child)
    }

    /// SIGKILL: no shutdown, no final flush.
    pub fn kill(mut self) {
        self.proc.0.kill().expect("kill strata-server");
        self.proc.0.wait().expect("reap strata-server");
    }

    /// SIGTERM: the server finishes its batch and exits.
    pub fn stop(mut self) {
        let pid = self.proc.0.id().to_string();
        let ok = Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "sending SIGTERM to {pid}");
        let status = self.proc.wait_timeout(Duration::from_secs(30));
        assert!(status.success(), "strata-server exited with {status}");
    }
}

/// Starts `strata-bots` against `server` with extra arguments; stdout is
/// piped (the `--json` summary).
pub fn spawn_bots(server: &Server, args: &[&str]) -> Guard {
    let child = Command::new(binary("strata-bots"))
        .arg("--server")
        .arg(server.addr.to_string())
        .arg("--data-dir")
        .arg(&server.data_dir)
        .arg("--json")
        .args(args)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("strata-bots starts");
    Guard(child)
}

/// Waits (bounded) for a child whose stdout is piped; returns its status
/// and everything it printed.
pub fn wait_with_output(mut child: Guard, limit: Duration) -> (ExitStatus, String) {
    let mut stdout = child.0.stdout.take().expect("stdout is piped");
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stdout.read_to_string(&mut s);
        s
    });
    let status = child.wait_timeout(limit);
    (status, reader.join().expect("reader thread"))
}

/// Waits (bounded) for a child whose stdout is piped; returns its status
/// and the last line it printed, parsed as JSON.
pub fn json_result(child: Guard, limit: Duration) -> (ExitStatus, serde_json::Value) {
    let (status, out) = wait_with_output(child, limit);
    let line = out.lines().last().unwrap_or_default();
    let value = serde_json::from_str(line)
        .unwrap_or_else(|e| panic!("bad JSON line {out:?} (exit {status}): {e}"));
    (status, value)
}

/// Waits for a bots run and parses its summary line.
pub fn bots_summary(bots: Guard) -> (ExitStatus, serde_json::Value) {
    json_result(bots, PROCESS_TIMEOUT)
}

/// Runs `strata-admin verify-acks`; returns its status and report line.
pub fn verify_acks(data_dir: &Path, ack_log: &Path) -> (ExitStatus, serde_json::Value) {
    let child = Command::new(binary("strata-admin"))
        .arg("verify-acks")
        .arg("--data-dir")
        .arg(data_dir)
        .arg(ack_log)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("strata-admin starts");
    json_result(Guard(child), Duration::from_secs(60))
}

/// Lines in a file written line by line (an ack log); 0 while it is missing.
pub fn lines_in(path: &Path) -> usize {
    std::fs::read(path).map_or(0, |b| b.iter().filter(|&&c| c == b'\n').count())
}

/// Longest [`await_lines`] waits: generous, for a debug build on a busy
/// 2-core box.
pub const LINES_TIMEOUT: Duration = Duration::from_secs(60);

/// Waits until `path` (an ack log) holds at least `n` whole lines, polling;
/// fails the test after [`LINES_TIMEOUT`]. Returns the count it saw.
pub fn await_lines(path: &Path, n: usize, what: &str) -> usize {
    let start = Instant::now();
    loop {
        let have = lines_in(path);
        if have >= n {
            return have;
        }
        assert!(
            start.elapsed() < LINES_TIMEOUT,
            "{what}: {} holds {have} lines, not {n}, after {LINES_TIMEOUT:?}",
            path.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A counter from a summary or report (0 when absent).
pub fn num(v: &serde_json::Value, key: &str) -> u64 {
    v[key].as_u64().unwrap_or(0)
}

/// A counter that must be there: a renamed key fails the check instead
/// of reading as 0.
pub fn count(v: &serde_json::Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("no counter {key:?} in {v}"))
}

/// Asserts every replica converged on the server's world.
pub fn assert_converged(s: &serde_json::Value) {
    for key in [
        "bots_failed",
        "replica_mismatches",
        "mesh_mismatches",
        "chunks_unverified",
        "order_violations",
        "ack_missing",
    ] {
        assert_eq!(count(s, key), 0, "{key} in {s}");
    }
    assert_eq!(s["quiet"], true, "the world went quiet: {s}");
    assert!(count(s, "chunks_verified") > 0, "{s}");
}

/// A `127.0.0.1:PORT` nobody listens on now (for a server's `[metrics]`).
pub fn free_local_addr() -> String {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    format!("127.0.0.1:{port}")
}

/// `GET path` over plain HTTP/1.1; the whole response, head and body.
pub fn http_get(addr: &str, path: &str) -> String {
    use std::io::Write;
    let mut s = std::net::TcpStream::connect(addr).expect("an HTTP listener");
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

/// The unlabelled sample `name` (a counter or gauge) on the Prometheus
/// endpoint at `addr` (a server's `[metrics] listen`); `None` when the
/// server exports no such sample.
pub fn metric(addr: &str, name: &str) -> Option<f64> {
    let text = http_get(addr, "/metrics");
    let prefix = format!("{name} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .and_then(|v| v.trim().parse().ok())
}
