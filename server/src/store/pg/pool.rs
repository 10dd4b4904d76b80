//! A small pool of PostgreSQL connections, each with its cached prepared
//! statements, and the one way the store talks to them: [`Pool::run`]
//! (one call) and [`Pool::run_tx`] (one transaction), each under the
//! statement timeout, and [`Pool::hold`] (one connection for a transaction
//! that spans calls, each under the statement timeout).

use std::collections::HashMap;
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use tokio_postgres::types::ToSql;
use tokio_postgres::{Client, NoTls, Row, Statement};
use tracing::warn;

use super::config::PgConfig;
use super::wait::wait;
use crate::store::StoreError;

/// SQL parameters, as `tokio-postgres` takes them.
pub type Params<'a> = &'a [&'a (dyn ToSql + Sync)];

/// One connection and the statements it has prepared.
#[derive(Debug)]
pub struct Conn {
    client: Client,
    statements: HashMap<&'static str, Statement>,
}

impl Conn {
    /// `sql` prepared once per connection: later calls skip the parse.
    async fn statement(&mut self, sql: &'static str) -> Result<Statement, StoreError> {
        if let Some(s) = self.statements.get(sql) {
            return Ok(s.clone());
        }
        let s = self.client.prepare(sql).await?;
        self.statements.insert(sql, s.clone());
        Ok(s)
    }

    pub async fn query(
        &mut self,
        sql: &'static str,
        p: Params<'_>,
    ) -> Result<Vec<Row>, StoreError> {
        let s = self.statement(sql).await?;
        Ok(self.client.query(&s, p).await?)
    }

    pub async fn query_opt(
        &mut self,
        sql: &'static str,
        p: Params<'_>,
    ) -> Result<Option<Row>, StoreError> {
        let s = self.statement(sql).await?;
        Ok(self.client.query_opt(&s, p).await?)
    }

    pub async fn execute(&mut self, sql: &'static str, p: Params<'_>) -> Result<u64, StoreError> {
        let s = self.statement(sql).await?;
        Ok(self.client.execute(&s, p).await?)
    }

    /// The first column of the first row of a statement built at run
    /// time (simple protocol: nothing is prepared or cached).
    pub async fn simple_value(&mut self, sql: &str) -> Result<Option<String>, StoreError> {
        Ok(self
            .simple_row(sql)
            .await?
            .and_then(|r| r.into_iter().next().flatten()))
    }

    /// The columns of the first row the statements return, as text, in
    /// one round trip (simple protocol).
    pub async fn simple_row(
        &mut self,
        sql: &str,
    ) -> Result<Option<Vec<Option<String>>>, StoreError> {
        for m in self.client.simple_query(sql).await? {
            if let tokio_postgres::SimpleQueryMessage::Row(r) = m {
                return Ok(Some(
                    (0..r.len()).map(|i| r.get(i).map(str::to_string)).collect(),
                ));
            }
        }
        Ok(None)
    }

    /// Whether the connection ended.
    pub fn is_closed(&self) -> bool {
        self.client.is_closed()
    }

    /// Statements without parameters, in one round trip (simple protocol).
    pub async fn batch(&mut self, sql: &str) -> Result<(), StoreError> {
        Ok(self.client.batch_execute(sql).await?)
    }
}

#[derive(Debug, Default)]
struct Idle {
    conns: Vec<Conn>,
    /// Connections open, idle or lent.
    open: usize,
}

/// Seconds a connection idles before the server probes its client.
const KEEPALIVE_IDLE_S: u32 = 10;
/// Seconds between probes.
const KEEPALIVE_INTERVAL_S: u32 = 5;
/// Probes unanswered before the server ends the session.
const KEEPALIVE_COUNT: u32 = 4;
/// About how long a dead client's session holds its locks.
pub const KEEPALIVE_S: u32 = KEEPALIVE_IDLE_S + KEEPALIVE_INTERVAL_S * KEEPALIVE_COUNT;

/// The store's connections and the runtime that drives them.
#[derive(Debug)]
pub struct Pool {
    config: tokio_postgres::Config,
    /// Runs each connection's I/O task; the store's calls only wait on
    /// channels to them (see `wait`). `None` once dropped.
    runtime: Option<tokio::runtime::Runtime>,
    idle: Mutex<Idle>,
    freed: Condvar,
    max: usize,
    connect_timeout: Duration,
    pool_wait: Duration,
    statement_timeout: Duration,
    /// `[store.postgres] commit_retry_ms`.
    commit_retry: Duration,
    /// The server ends a session left idle inside a transaction this long
    /// (a paused node), rolling it back and freeing its row locks.
    idle_in_transaction: Duration,
}

impl Pool {
    /// A pool for `cfg`; opens one connection to prove the server answers.
    pub fn open(cfg: &PgConfig) -> Result<Self, StoreError> {
        Self::open_idle(cfg, Duration::from_millis(cfg.statement_timeout_ms))
    }

    /// [`Self::open`], its sessions ended by the server when idle inside a
    /// transaction for `idle_in_transaction` (a cluster node: its lease, so
    /// a node paused mid-commit cannot hold a takeover up).
    pub fn open_idle(cfg: &PgConfig, idle_in_transaction: Duration) -> Result<Self, StoreError> {
        let config = cfg.client_config().map_err(|reason| StoreError::PgSetup {
            reason: format!("store.postgres.url {reason}"),
        })?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("strata-pg")
            .enable_all()
            .build()?;
        let pool = Self {
            config,
            runtime: Some(runtime),
            idle: Mutex::new(Idle::default()),
            freed: Condvar::new(),
            max: cfg.max_connections.max(1),
            connect_timeout: Duration::from_millis(cfg.connect_timeout_ms),
            pool_wait: Duration::from_millis(cfg.pool_wait_ms),
            statement_timeout: Duration::from_millis(cfg.statement_timeout_ms),
            commit_retry: Duration::from_millis(cfg.commit_retry_ms),
            idle_in_transaction: idle_in_transaction.max(Duration::from_millis(1)),
        };
        let first = pool.take()?;
        pool.give(Some(first));
        Ok(pool)
    }

    /// The statement timeout every connection runs under.
    pub fn statement_timeout(&self) -> Duration {
        self.statement_timeout
    }

    /// How long a commit may wait out an outage ([`super::patience`]).
    pub fn commit_retry(&self) -> Duration {
        self.commit_retry
    }

    /// One call on a pooled connection, under the statement timeout. A
    /// connection that failed or timed out is closed, not pooled again.
    pub fn run<T>(
        &self,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        self.run_for(what, self.statement_timeout, f)
    }

    /// [`Pool::run`] given `limit` instead of the statement timeout (the
    /// session's own timeout is the caller's to lift).
    pub fn run_for<T>(
        &self,
        what: &'static str,
        limit: Duration,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut conn = self.take()?;
        let (result, late) = timed(what, limit, f(&mut conn));
        // Our own refusals leave the connection clean; a database error
        // may leave it mid-transaction.
        let keep = !late && result.as_ref().err().is_none_or(|e| !e.is_postgres());
        self.give(keep.then_some(conn));
        result
    }

    /// [`Pool::run`] on a connection of the caller's own, kept in `slot`
    /// between calls and outside the pool's limit: for the commits, which
    /// must not wait behind the pool's other users (a login storm's reads,
    /// console renders) and time out, which stops the engine.
    pub fn run_own<T>(
        &self,
        slot: &Mutex<Option<Box<Conn>>>,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut held = slot.lock().unwrap_or_else(|p| p.into_inner());
        let mut conn = match held.take() {
            Some(c) if !c.is_closed() => c,
            _ => Box::new(self.connect()?),
        };
        let (result, late) = timed(what, self.statement_timeout, f(&mut conn));
        // As `run`: one that failed or timed out is closed, not kept.
        if !late && result.as_ref().err().is_none_or(|e| !e.is_postgres()) {
            *held = Some(conn);
        }
        result
    }

    /// [`Pool::run`] inside `begin` ... `COMMIT`; rolled back when `f`
    /// refuses. `COMMIT` returns once PostgreSQL made it durable (every
    /// session runs with `synchronous_commit = on` unless `begin` says
    /// otherwise for its own transaction).
    pub fn run_tx<T>(
        &self,
        what: &'static str,
        begin: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        self.run_tx_for(what, begin, self.statement_timeout, f)
    }

    /// [`Pool::run_tx`] within `limit` ([`Pool::run_for`]).
    pub fn run_tx_for<T>(
        &self,
        what: &'static str,
        begin: &'static str,
        limit: Duration,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        self.run_for(what, limit, async |c: &mut Conn| {
            c.batch(begin).await?;
            match f(c).await {
                Ok(v) => {
                    c.batch("COMMIT").await?;
                    Ok(v)
                }
                Err(e) => {
                    if !e.is_postgres() {
                        c.batch("ROLLBACK").await?;
                    }
                    Err(e)
                }
            }
        })
    }

    /// A connection outside the pool (not counted against its limit), for
    /// a session-level lock held as long as the store; one call on it runs
    /// under the statement timeout. It closes with the pool's runtime.
    pub fn dedicated<T>(
        &self,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<(Conn, T), StoreError> {
        let mut conn = self.connect()?;
        let (result, _) = timed(what, self.statement_timeout, f(&mut conn));
        result.map(|v| (conn, v))
    }

    /// One call on a connection [`Pool::dedicated`] made, under the
    /// statement timeout.
    pub fn on_dedicated<T>(
        &self,
        conn: &mut Conn,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        self.on_dedicated_within(conn, what, self.statement_timeout, f)
    }

    /// [`Pool::on_dedicated`] within `limit`.
    pub fn on_dedicated_within<T>(
        &self,
        conn: &mut Conn,
        what: &'static str,
        limit: Duration,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        timed(what, limit, f(conn)).0
    }

    /// A connection of its own, for a transaction that spans several calls
    /// ([`Held`]).
    pub fn hold(&self) -> Result<Held<'_>, StoreError> {
        Ok(Held {
            pool: self,
            conn: Some(self.take()?),
            clean: true,
        })
    }

    /// An idle connection, a new one while under the limit, or the next
    /// one given back within `pool_wait`.
    fn take(&self) -> Result<Conn, StoreError> {
        let deadline = Instant::now() + self.pool_wait;
        let mut idle = self.idle.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            while let Some(c) = idle.conns.pop() {
                if !c.client.is_closed() {
                    return Ok(c);
                }
                idle.open -= 1;
            }
            if idle.open < self.max {
                idle.open += 1;
                drop(idle);
                let made = self.connect();
                if made.is_err() {
                    self.give(None);
                }
                return made;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(StoreError::PgTimeout {
                    what: "waiting for a free connection",
                    limit_ms: self.pool_wait.as_millis() as u64,
                });
            }
            idle = self
                .freed
                .wait_timeout(idle, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    /// Returns a connection to the pool, or (`None`) forgets a closed one.
    fn give(&self, conn: Option<Conn>) {
        let mut idle = self.idle.lock().unwrap_or_else(|p| p.into_inner());
        match conn {
            Some(c) => idle.conns.push(c),
            None => idle.open -= 1,
        }
        self.freed.notify_one();
    }

    fn connect(&self) -> Result<Conn, StoreError> {
        let runtime = self.runtime.as_ref().ok_or_else(|| StoreError::PgSetup {
            reason: "the store is closed".into(),
        })?;
        let config = self.config.clone();
        let task = runtime.spawn(async move {
            let (client, connection) = config.connect(NoTls).await?;
            tokio::spawn(async move {
                if let Err(e) = connection.await {
                    warn!(error = %e, "postgres connection ended");
                }
            });
            Ok::<_, tokio_postgres::Error>(client)
        });
        let abort = task.abort_handle();
        let client = match wait(task, self.connect_timeout) {
            Ok(Ok(r)) => r?,
            Ok(Err(join)) => {
                return Err(StoreError::PgSetup {
                    reason: format!("connecting: {join}"),
                })
            }
            Err(_) => {
                abort.abort();
                return Err(StoreError::PgTimeout {
                    what: "connecting",
                    limit_ms: self.connect_timeout.as_millis() as u64,
                });
            }
        };
        let mut conn = Conn {
            client,
            statements: HashMap::new(),
        };
        // Every commit waits for the WAL flush; no statement runs forever;
        // the server probes an idle connection, so one whose client died
        // without closing it (a crashed host) gives its locks up within
        // about `KEEPALIVE_S` seconds, not the OS's two hours.
        let settings = format!(
            "SET synchronous_commit = on; SET statement_timeout = {}; \
             SET idle_in_transaction_session_timeout = {}; \
             SET tcp_keepalives_idle = {KEEPALIVE_IDLE_S}; \
             SET tcp_keepalives_interval = {KEEPALIVE_INTERVAL_S}; \
             SET tcp_keepalives_count = {KEEPALIVE_COUNT}",
            self.statement_timeout.as_millis(),
            self.idle_in_transaction.as_millis()
        );
        match wait(conn.batch(&settings), self.connect_timeout) {
            Ok(r) => r?,
            Err(_) => {
                return Err(StoreError::PgTimeout {
                    what: "setting up a connection",
                    limit_ms: self.connect_timeout.as_millis() as u64,
                })
            }
        }
        Ok(conn)
    }
}

/// A connection taken out of the pool for a transaction that spans calls.
/// It goes back to the pool only when clean (no transaction open); one
/// dropped mid-transaction is closed, and PostgreSQL rolls it back.
#[derive(Debug)]
pub struct Held<'p> {
    pool: &'p Pool,
    /// `None` once a call failed or timed out: the connection was closed.
    conn: Option<Conn>,
    /// No transaction open on it.
    clean: bool,
}

impl Held<'_> {
    /// One call on the held connection, under the statement timeout. A
    /// database error, a timeout or any error inside a transaction closes
    /// the connection (so the transaction is rolled back) and later calls
    /// fail; our own refusals outside a transaction leave it as it was.
    pub fn run<T>(
        &mut self,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        self.run_within(self.pool.statement_timeout, what, f)
    }

    /// [`Held::run`] with a limit of its own (a statement whose own
    /// timeout the transaction set).
    pub fn run_within<T>(
        &mut self,
        limit: Duration,
        what: &'static str,
        f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let Some(conn) = self.conn.as_mut() else {
            return Err(StoreError::PgSetup {
                reason: format!("{what}: the connection was closed by an earlier failure"),
            });
        };
        let (result, late) = timed(what, limit, f(conn));
        // Inside a transaction an error may stand for one PostgreSQL
        // aborted (a mapped lock timeout): never kept.
        let close = late
            || result
                .as_ref()
                .err()
                .is_some_and(|e| e.is_postgres() || !self.clean);
        if close {
            // PostgreSQL sends an error before it has rolled the transaction
            // back and let its locks go (a restore's serving lock): the
            // answer to a ROLLBACK comes after, so a caller told of the
            // failure finds them free.
            let answered =
                matches!(&result, Err(StoreError::Postgres(e)) if e.as_db_error().is_some());
            if let (Some(conn), true, false) = (self.conn.as_mut(), answered, late) {
                let _ = timed(
                    "rolling back",
                    self.pool.statement_timeout,
                    conn.batch("ROLLBACK"),
                );
            }
            self.conn = None;
            self.pool.give(None);
        }
        result
    }

    /// Statements that open a transaction (`BEGIN ...`).
    pub fn begin(&mut self, what: &'static str, begin: &str) -> Result<(), StoreError> {
        self.clean = false;
        self.run(what, async |c: &mut Conn| c.batch(begin).await)
    }

    /// The statement timeout every connection runs under.
    pub fn statement_timeout(&self) -> Duration {
        self.pool.statement_timeout
    }

    /// `COMMIT`s the open transaction: durable when it returns.
    pub fn commit(&mut self, what: &'static str) -> Result<(), StoreError> {
        self.run(what, async |c: &mut Conn| c.batch("COMMIT").await)?;
        self.clean = true;
        Ok(())
    }
}

impl Drop for Held<'_> {
    fn drop(&mut self) {
        if let Some(conn) = self.conn.take() {
            // Closing the connection rolls an open transaction back.
            self.pool.give(self.clean.then_some(conn));
        }
    }
}

/// `f` under `limit`: its result, or [`StoreError::PgTimeout`] naming
/// `what`, and whether it ran out of time (its connection must close).
fn timed<T>(
    what: &'static str,
    limit: Duration,
    f: impl std::future::Future<Output = Result<T, StoreError>>,
) -> (Result<T, StoreError>, bool) {
    match wait(f, limit) {
        Ok(result) => (result, false),
        Err(_) => (
            Err(StoreError::PgTimeout {
                what,
                limit_ms: limit.as_millis() as u64,
            }),
            true,
        ),
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        self.idle
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .conns
            .clear();
        // Callable anywhere, a tokio task included (a plain drop is not).
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}
