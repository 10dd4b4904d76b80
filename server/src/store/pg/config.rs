//! `[store.postgres]`: where the PostgreSQL store lives and how long it
//! may wait for it.

use serde::{Deserialize, Serialize};

/// Connections the store keeps at most: the commit thread, the checkpoint
/// thread, the engine's chunk loads and a few admin or console readers.
pub const DEFAULT_PG_MAX_CONNECTIONS: usize = 8;
/// Largest allowed `max_connections`.
pub const MAX_PG_MAX_CONNECTIONS: usize = 256;
/// How long opening one connection may take.
pub const DEFAULT_PG_CONNECT_TIMEOUT_MS: u64 = 5_000;
/// How long a caller waits for a free connection when all are busy.
pub const DEFAULT_PG_POOL_WAIT_MS: u64 = 5_000;
/// How long one store call (one transaction) may run, enforced by the
/// server (`statement_timeout`) and by the client's wait.
pub const DEFAULT_PG_STATEMENT_TIMEOUT_MS: u64 = 30_000;
/// How long a server without `[cluster]` keeps trying a commit while
/// PostgreSQL is unreachable before it stops (0: it stops at once).
pub const DEFAULT_PG_COMMIT_RETRY_MS: u64 = 30_000;
/// Longest allowed timeout of each kind.
pub const MAX_PG_TIMEOUT_MS: u64 = 600_000;

/// The `[store.postgres]` section (used when `[store] backend = "postgres"`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PgConfig {
    /// A libpq connection string, key-value (`host=127.0.0.1 port=5432
    /// user=strata dbname=strata`) or URL (`postgresql://strata@host/strata`).
    pub url: String,
    /// Connections kept at most.
    pub max_connections: usize,
    pub connect_timeout_ms: u64,
    pub pool_wait_ms: u64,
    pub statement_timeout_ms: u64,
    /// See [`DEFAULT_PG_COMMIT_RETRY_MS`].
    pub commit_retry_ms: u64,
    /// The `application_name` its connections give when the URL names
    /// none: [`SERVER_APPLICATION`] unless [`PgConfig::for_admin`] set it.
    #[serde(skip)]
    pub program: Option<&'static str>,
}

/// What a running server's connections are named in `pg_stat_activity`.
pub const SERVER_APPLICATION: &str = "strata-server";
/// What the admin tools' connections are named.
pub const ADMIN_APPLICATION: &str = "strata-admin";

impl Default for PgConfig {
    fn default() -> Self {
        Self {
            url: String::new(),
            max_connections: DEFAULT_PG_MAX_CONNECTIONS,
            connect_timeout_ms: DEFAULT_PG_CONNECT_TIMEOUT_MS,
            pool_wait_ms: DEFAULT_PG_POOL_WAIT_MS,
            statement_timeout_ms: DEFAULT_PG_STATEMENT_TIMEOUT_MS,
            commit_retry_ms: DEFAULT_PG_COMMIT_RETRY_MS,
            program: None,
        }
    }
}

impl PgConfig {
    /// The same database, its connections named [`ADMIN_APPLICATION`]
    /// (so that a restore can tell running servers from admin tools).
    pub fn for_admin(&self) -> Self {
        Self {
            program: Some(ADMIN_APPLICATION),
            ..self.clone()
        }
    }

    /// The parsed connection string with the connect timeout applied.
    pub fn client_config(&self) -> Result<tokio_postgres::Config, String> {
        if self.url.trim().is_empty() {
            return Err("is empty; name the PostgreSQL database to use".into());
        }
        let mut c: tokio_postgres::Config = self.url.parse().map_err(|e| format!("{e}"))?;
        c.connect_timeout(std::time::Duration::from_millis(self.connect_timeout_ms));
        if c.get_application_name().is_none() {
            c.application_name(self.program.unwrap_or(SERVER_APPLICATION));
        }
        Ok(c)
    }
}
