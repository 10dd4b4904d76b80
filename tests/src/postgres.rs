//! A real PostgreSQL 15 for tests of the PostgreSQL store: `initdb` into a
//! temp dir, `pg_ctl start` on 127.0.0.1 with a free port (its unix socket
//! in the temp dir), one database per test.
//!
//! The binaries are looked up in `STRATA_PG_BIN` (`scripts/test` installs
//! Debian's `postgresql-15` and sets it), then on `PATH`, then in Debian's
//! `/usr/lib/postgresql/15/bin`. Without them a test fails under `CI=true`
//! and otherwise says that it did not run.
//!
//! PostgreSQL refuses to run as root, so as root (CI) the cluster is made
//! and run as `nobody`, its temp dir handed to that user. Commits run as in
//! production: `fsync` and `synchronous_commit` on.
//!
//! A [`PgCluster`] stops on drop. The cluster a test process shares
//! ([`database`]) lives in a static, which Rust never drops, so a watchdog
//! process stops it and removes its files once the test process is gone.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;

/// Environment variable naming the directory of `initdb` and `pg_ctl`.
pub const PG_BIN_ENV: &str = "STRATA_PG_BIN";
/// Where Debian's `postgresql-15` puts them.
pub const DEBIAN_PG_BIN: &str = "/usr/lib/postgresql/15/bin";
/// The superuser `initdb` creates (trusted on loopback only).
pub const PG_USER: &str = "strata";
/// Connections the test cluster accepts (tests run servers side by side).
const MAX_CONNECTIONS: u32 = 300;
/// Longest `pg_ctl` waits for the server to start or stop.
const PG_CTL_WAIT_S: u32 = 60;
/// Longest `createdb` or `dropdb` waits to connect.
const CONNECT_TIMEOUT_S: u32 = 10;
/// Ports tried before giving up (another process may take a free port).
const START_ATTEMPTS: u32 = 5;

/// The directory holding `initdb`, or why there is none.
pub fn bin_dir() -> Result<PathBuf, String> {
    if let Some(dir) = std::env::var_os(PG_BIN_ENV).map(PathBuf::from) {
        return if dir.join("initdb").is_file() {
            Ok(dir)
        } else {
            Err(format!("{PG_BIN_ENV}={} has no initdb", dir.display()))
        };
    }
    // A PATH entry may hold links to the real directory (which also has
    // createdb and dropdb): follow them.
    let on_path = std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .filter_map(|d| std::fs::canonicalize(d.join("initdb")).ok())
        .find_map(|exe| exe.parent().map(Path::to_path_buf))
        .filter(|d| d.join("pg_ctl").is_file());
    let debian = Path::new(DEBIAN_PG_BIN);
    on_path
        .or_else(|| {
            debian
                .join("initdb")
                .is_file()
                .then(|| debian.to_path_buf())
        })
        .ok_or_else(|| {
            format!("{PG_BIN_ENV} is not set and neither PATH nor {DEBIAN_PG_BIN} has initdb")
        })
}

/// A running PostgreSQL cluster in a temp dir.
#[derive(Debug)]
pub struct PgCluster {
    root: tempfile::TempDir,
    bin: PathBuf,
    port: u16,
    /// `nobody` when the tests run as root.
    run_as: Option<&'static str>,
}

impl PgCluster {
    /// Makes and starts a cluster with the binaries in `bin`.
    pub fn start(bin: &Path) -> Result<PgCluster, String> {
        let root = tempfile::Builder::new()
            .prefix("strata-pg-")
            .tempdir()
            .map_err(|e| format!("temp dir: {e}"))?;
        let run_as = is_root().then_some("nobody");
        if let Some(user) = run_as {
            run(Command::new("chown").arg(user).arg(root.path()))?;
        }
        let mut cluster = PgCluster {
            root,
            bin: bin.to_path_buf(),
            port: 0,
            run_as,
        };
        cluster.initdb()?;
        let mut last = String::new();
        for _ in 0..START_ATTEMPTS {
            cluster.port = free_port()?;
            match cluster.pg_ctl_start() {
                Ok(()) => {
                    cluster.watch();
                    return Ok(cluster);
                }
                Err(e) => last = e,
            }
        }
        Err(format!(
            "pg_ctl start failed {START_ATTEMPTS} times: {last}"
        ))
    }

    pub fn port(&self) -> u16 {
        self.port
    }

    fn data(&self) -> PathBuf {
        self.root.path().join("data")
    }

    /// A command for one of the cluster's binaries, as the cluster's user.
    fn as_owner(&self, tool: &str) -> Command {
        let exe = self.bin.join(tool);
        match self.run_as {
            Some(user) => {
                let mut c = Command::new("runuser");
                c.args(["-u", user, "--"]).arg(exe);
                c
            }
            None => Command::new(exe),
        }
    }

    fn initdb(&self) -> Result<(), String> {
        run(self
            .as_owner("initdb")
            .arg("-D")
            .arg(self.data())
            .args(["-U", PG_USER, "--auth=trust", "--encoding=UTF8"])
            .args(["--locale=C", "--no-sync", "--no-instructions"]))
    }

    fn pg_ctl_start(&self) -> Result<(), String> {
        let options = format!(
            "-c listen_addresses=127.0.0.1 -p {} -k {} -c max_connections={MAX_CONNECTIONS} \
             -c fsync=on -c synchronous_commit=on",
            self.port,
            self.root.path().display()
        );
        run(self
            .as_owner("pg_ctl")
            .arg("-D")
            .arg(self.data())
            .arg("-l")
            .arg(self.root.path().join("server.log"))
            .args([
                "-w",
                "-t",
                &PG_CTL_WAIT_S.to_string(),
                "-o",
                &options,
                "start",
            ]))
    }

    /// Stops the cluster and removes its files once this process is gone,
    /// whether or not anything drops the cluster.
    fn watch(&self) {
        let stop = format!(
            "{} {} -D {} -m immediate stop",
            self.run_as
                .map_or(String::new(), |u| format!("runuser -u {u} --")),
            self.bin.join("pg_ctl").display(),
            self.data().display()
        );
        let script = format!(
            "while kill -0 {pid} 2>/dev/null; do sleep 1; done; {stop} >/dev/null 2>&1; rm -rf {root}",
            pid = std::process::id(),
            root = self.root.path().display()
        );
        // Detached: it outlives nothing but this process.
        let _ = Command::new("sh")
            .args(["-c", &script])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn();
    }

    /// Creates a new, empty database.
    pub fn create_database(&self, name: &str) -> Result<(), String> {
        run(self.client("createdb").arg(name))
    }

    /// Drops a database, ending its sessions.
    pub fn drop_database(&self, name: &str) -> Result<(), String> {
        run(self
            .client("dropdb")
            .args(["--force", "--if-exists"])
            .arg(name))
    }

    fn client(&self, tool: &str) -> Command {
        let mut c = Command::new(self.bin.join(tool));
        c.args([
            "-h",
            "127.0.0.1",
            "-p",
            &self.port.to_string(),
            "-U",
            PG_USER,
        ])
        .env("PGCONNECT_TIMEOUT", CONNECT_TIMEOUT_S.to_string());
        c
    }

    /// A libpq connection string for `dbname`.
    pub fn url(&self, dbname: &str) -> String {
        format!(
            "host=127.0.0.1 port={} user={PG_USER} dbname={dbname}",
            self.port
        )
    }

    /// Stops the server as an operator's restart does (`-m fast`: sessions
    /// ended, their transactions rolled back).
    pub fn stop(&self) -> Result<(), String> {
        run(self.as_owner("pg_ctl").arg("-D").arg(self.data()).args([
            "-m",
            "fast",
            "-w",
            "-t",
            &PG_CTL_WAIT_S.to_string(),
            "stop",
        ]))
    }

    /// Starts a [`Self::stop`]ped server again, on its port.
    pub fn start_again(&self) -> Result<(), String> {
        self.pg_ctl_start()
    }

    /// The server's log so far (for a failing test's message).
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.root.path().join("server.log")).unwrap_or_default()
    }
}

impl Drop for PgCluster {
    fn drop(&mut self) {
        let _ = self
            .as_owner("pg_ctl")
            .arg("-D")
            .arg(self.data())
            .args(["-m", "fast", "-w", "stop"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status();
    }
}

/// One test's database in the process's shared cluster, dropped on drop.
#[derive(Debug)]
pub struct PgDb {
    cluster: &'static PgCluster,
    name: String,
}

impl PgDb {
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its libpq connection string.
    pub fn url(&self) -> String {
        self.cluster.url(&self.name)
    }

    /// A server config section selecting this database as the store.
    pub fn store_toml(&self) -> String {
        format!(
            "[store]\nbackend = \"postgres\"\n[store.postgres]\nurl = \"{}\"\n",
            self.url()
        )
    }

    pub fn cluster(&self) -> &'static PgCluster {
        self.cluster
    }

    /// Runs `statements` (ones taking row or table locks; the last needs
    /// no `;`) in a transaction of their own, through `psql`, and returns once they ran; the locks
    /// are held until the returned guard is released or dropped (then the
    /// transaction rolls back).
    pub fn hold(&self, statements: &str) -> Result<HeldLocks, String> {
        let mut psql = self
            .cluster
            .client("psql")
            .args(["-X", "-q", "-o", "/dev/null", "-v", "ON_ERROR_STOP=1"])
            .args(["-d", &self.name])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| format!("psql: {e}"))?;
        let mut stdin = psql.stdin.take().ok_or("psql: no stdin")?;
        let stdout = psql.stdout.take().ok_or("psql: no stdout")?;
        writeln!(stdin, "BEGIN;\n{statements};\n\\echo held").map_err(|e| e.to_string())?;
        // Query results go to /dev/null (`-o`); `\echo` still comes here.
        let mut line = String::new();
        std::io::BufReader::new(stdout)
            .read_line(&mut line)
            .map_err(|e| e.to_string())?;
        if line.trim() != "held" {
            let _ = psql.kill();
            let _ = psql.wait();
            return Err(format!("psql did not take the locks: {line:?}"));
        }
        Ok(HeldLocks {
            psql,
            stdin: Some(stdin),
        })
    }
}

/// Locks [`PgDb::hold`] took, in a `psql` transaction still open.
#[derive(Debug)]
pub struct HeldLocks {
    psql: std::process::Child,
    stdin: Option<std::process::ChildStdin>,
}

impl HeldLocks {
    /// Rolls the transaction back and waits for `psql` to end.
    pub fn release(mut self) {
        self.end();
    }

    fn end(&mut self) {
        if let Some(mut stdin) = self.stdin.take() {
            let _ = writeln!(stdin, "ROLLBACK;\n\\q");
        }
        let _ = self.psql.wait();
    }
}

impl Drop for HeldLocks {
    fn drop(&mut self) {
        self.end();
    }
}

impl Drop for PgDb {
    fn drop(&mut self) {
        let _ = self.cluster.drop_database(&self.name);
    }
}

/// A fresh database for `test` in this process's cluster (started on first
/// use). `None` (after saying so) without PostgreSQL outside CI; under
/// `CI=true` a missing or broken PostgreSQL fails the test.
pub fn database(test: &str) -> Option<PgDb> {
    static CLUSTER: OnceLock<Result<PgCluster, String>> = OnceLock::new();
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let cluster = CLUSTER.get_or_init(|| bin_dir().and_then(|bin| PgCluster::start(&bin)));
    let cluster = match cluster {
        Ok(c) => c,
        Err(why) => {
            return crate::not_run(test, "PostgreSQL 15 (apt-get install postgresql-15)", why)
        }
    };
    let safe: String = test
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .take(40)
        .collect();
    let name = format!(
        "t{}_{}_{safe}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    );
    if let Err(e) = cluster.create_database(&name) {
        panic!("creating database {name}: {e}\n{}", cluster.log());
    }
    Some(PgDb { cluster, name })
}

/// A cluster of `test`'s own, for a test that stops it: `None` as for
/// [`database`].
pub fn private_cluster(test: &str) -> Option<PgCluster> {
    match bin_dir().and_then(|bin| PgCluster::start(&bin)) {
        Ok(c) => Some(c),
        Err(why) => crate::not_run(test, "PostgreSQL 15 (apt-get install postgresql-15)", &why),
    }
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
}

fn free_port() -> Result<u16, String> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| format!("free port: {e}"))?;
    l.local_addr()
        .map(|a| a.port())
        .map_err(|e| format!("free port: {e}"))
}

/// Runs `cmd` to completion (bounded: every tool here is given its own
/// wait limit), failing with its output.
fn run(cmd: &mut Command) -> Result<(), String> {
    let out = cmd
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("{cmd:?}: {e}"))?;
    if out.status.success() {
        return Ok(());
    }
    Err(format!(
        "{cmd:?} exited with {}: {}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    ))
}
