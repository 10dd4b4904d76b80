//! Running the examples against a real server: a strata-server started in
//! this process on 127.0.0.1, a token minted with its secret, its
//! certificate in a file, and child processes bounded in time.

// Each test file uses a part of this module.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use strata_protocol::Role;
use strata_server::app::{self, Running};
use strata_server::auth;
use strata_server::config::ServerConfig;

pub mod ffi;

/// The longest an example may run.
pub const EXAMPLE_TIMEOUT: Duration = Duration::from_secs(60);

/// A server on 127.0.0.1 with its runtime, and a scratch dir.
pub struct Server {
    pub running: Running,
    pub dir: tempfile::TempDir,
    // Dropped last: the server's tasks run on it.
    pub runtime: tokio::runtime::Runtime,
}

/// A server shut down by [`Server::stop`]: its scratch dir and runtime.
pub struct Stopped {
    _dir: tempfile::TempDir,
    // Dropped last, as in [`Server`].
    _runtime: tokio::runtime::Runtime,
}

impl Server {
    pub fn start() -> Server {
        let runtime = tokio::runtime::Runtime::new().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = ServerConfig::default();
        cfg.server.listen = "127.0.0.1:0".parse().unwrap();
        cfg.server.data_dir = dir.path().join("data");
        cfg.validation.spawn_protection_radius = 0;
        cfg.interest.view_radius = 2;
        cfg.engine.tick_ms = 5;
        let running = runtime.block_on(app::start(cfg)).unwrap();
        Server {
            running,
            dir,
            runtime,
        }
    }

    /// Shuts the server down; what it returns keeps the scratch dir and the
    /// runtime until the caller drops it.
    pub fn stop(self) -> Stopped {
        let Server {
            running,
            dir,
            runtime,
        } = self;
        runtime.block_on(running.shutdown()).unwrap();
        Stopped {
            _dir: dir,
            _runtime: runtime,
        }
    }

    pub fn address(&self) -> String {
        self.running.addr.to_string()
    }

    /// The server's certificate (DER), written to a file.
    pub fn cert_file(&self) -> PathBuf {
        let path = self.dir.path().join("cert.der");
        std::fs::write(&path, &self.running.cert_der).unwrap();
        path
    }

    pub fn token(&self, player: &str) -> String {
        auth::issue(
            self.running.data_dir.secret(),
            player,
            Role::Player,
            Duration::from_secs(600),
            auth::unix_now(),
        )
        .unwrap()
    }
}

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// The directory holding libstrata.so and libstrata.a. The `cargo test`
/// that built this test built them beside it, in `deps/`, from the same
/// compile as the rlib it links: every crate type the lib declares (cargo
/// copies only the targets it was asked for up to the profile's
/// directory). Where they are missing, they are built once per test
/// process with this test's profile, at the cost of rebuilding the
/// dependencies whose features differ without the rest of the workspace.
pub fn lib_dir() -> PathBuf {
    static BUILT: OnceLock<PathBuf> = OnceLock::new();
    BUILT
        .get_or_init(|| {
            let exe = std::env::current_exe().unwrap();
            let deps = exe.parent().unwrap();
            if ["libstrata.so", "libstrata.a"]
                .iter()
                .all(|lib| deps.join(lib).exists())
            {
                return deps.to_path_buf();
            }
            let dir = deps.parent().unwrap().to_path_buf();
            let mut cmd = Command::new(env!("CARGO"));
            cmd.args(["build", "--locked", "-p", "strata-sdk", "--lib"])
                .arg("--target-dir")
                .arg(dir.parent().unwrap());
            match dir.file_name().and_then(|n| n.to_str()) {
                Some("release") => cmd.arg("--release"),
                _ => cmd.args(["--profile", "test"]),
            };
            // Cargo gives this test its package's variables; build scripts
            // (ring's) rerun when they see them, which would rebuild half
            // the tree on every run.
            for (key, _) in std::env::vars_os() {
                let k = key.to_string_lossy();
                let ours = [
                    "CARGO_PKG_",
                    "CARGO_MANIFEST_",
                    "CARGO_CRATE_",
                    "CARGO_PRIMARY_",
                ];
                if ours.iter().any(|p| k.starts_with(p)) || k == "OUT_DIR" {
                    cmd.env_remove(&key);
                }
            }
            assert!(cmd.status().unwrap().success(), "building libstrata failed");
            for lib in ["libstrata.so", "libstrata.a"] {
                assert!(dir.join(lib).exists(), "{lib} was not built");
            }
            dir
        })
        .clone()
}

/// Runs `cmd`, killing it after [`EXAMPLE_TIMEOUT`]; returns its output.
pub fn run_bounded(cmd: &mut Command) -> Output {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"));
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > EXAMPLE_TIMEOUT {
            child.kill().unwrap();
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    eprintln!(
        "--- stdout\n{}--- stderr\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The `key=value` fields of the first output line starting with `step`.
pub fn line(out: &str, step: &str) -> Vec<(String, String)> {
    let l = out
        .lines()
        .find(|l| l.split(' ').next() == Some(step))
        .unwrap_or_else(|| panic!("no {step:?} line in:\n{out}"));
    l.split(' ')
        .skip(1)
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
}

/// One field of [`line`], parsed.
pub fn field<T: std::str::FromStr>(out: &str, step: &str, key: &str) -> T {
    let fields = line(out, step);
    let (_, v) = fields
        .iter()
        .find(|(k, _)| k == key)
        .unwrap_or_else(|| panic!("no {key} on the {step:?} line"));
    v.parse()
        .unwrap_or_else(|_| panic!("{step} {key}={v} does not parse"))
}

/// Checks what both examples print: an accepted edit, its own delta at
/// the version the server gave, and non-empty meshes at LOD 0 and 1.
pub fn check_run(out: &str) {
    let chunks: usize = field(out, "accepted", "chunks");
    assert!(chunks > 0, "the dig changed no chunk");
    let version: u64 = field(out, "delta", "version");
    assert!(version > 0);
    let meshes: Vec<_> = out.lines().filter(|l| l.starts_with("mesh ")).collect();
    assert_eq!(meshes.len(), 2, "{out}");
    for m in meshes {
        let triangles: usize = field(m, "mesh", "triangles");
        let vertices: usize = field(m, "mesh", "vertices");
        assert!(triangles > 0 && vertices > 0, "empty mesh: {m}");
    }
    assert!(out.lines().any(|l| l == "bye"));
}

/// How long [`wait_for`] polls.
pub const EVENT_WAIT: Duration = Duration::from_secs(20);

/// Polls until `want` picks an event out (every event is kept in `seen`),
/// or panics after [`EVENT_WAIT`].
pub fn wait_for<T>(
    s: &strata_client::Session,
    seen: &mut Vec<strata_client::Event>,
    mut want: impl FnMut(&strata_client::Event) -> Option<T>,
) -> T {
    let start = Instant::now();
    while start.elapsed() < EVENT_WAIT {
        while let Some(e) = s.poll() {
            let found = want(&e);
            seen.push(e);
            if let Some(t) = found {
                return t;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    panic!("timed out; events so far: {seen:?}");
}
