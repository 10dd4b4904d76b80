//! Schema migrations: the SQL files in `server/migrations/`, compiled in
//! and applied at open, in order, each recorded in [`MIGRATIONS_TABLE`].
//! All of them run in one transaction under an advisory lock, so nodes
//! starting together apply each exactly once, and a failed one leaves the
//! database as it was.

use super::pool::{Conn, Pool};
use crate::store::StoreError;

/// Table of applied migrations: version, name, time applied.
pub const MIGRATIONS_TABLE: &str = "schema_migrations";

/// Every migration this build knows: (version, name, SQL), versions rising.
pub const MIGRATIONS: &[(i32, &str, &str)] = &[
    (
        1,
        "0001_init",
        include_str!("../../../migrations/0001_init.sql"),
    ),
    (
        2,
        "0002_regions",
        include_str!("../../../migrations/0002_regions.sql"),
    ),
    (
        3,
        "0003_region_stats",
        include_str!("../../../migrations/0003_region_stats.sql"),
    ),
    (
        4,
        "0004_seq_blocks",
        include_str!("../../../migrations/0004_seq_blocks.sql"),
    ),
    (
        5,
        "0005_delta_spans",
        include_str!("../../../migrations/0005_delta_spans.sql"),
    ),
    (
        6,
        "0006_generated_records",
        include_str!("../../../migrations/0006_generated_records.sql"),
    ),
    (
        7,
        "0007_generated_rows",
        include_str!("../../../migrations/0007_generated_rows.sql"),
    ),
    (
        8,
        "0008_position_times",
        include_str!("../../../migrations/0008_position_times.sql"),
    ),
    (
        9,
        "0009_node_incarnations",
        include_str!("../../../migrations/0009_node_incarnations.sql"),
    ),
    (
        10,
        "0010_world_generation",
        include_str!("../../../migrations/0010_world_generation.sql"),
    ),
    (
        11,
        "0011_seq_block_pruning",
        include_str!("../../../migrations/0011_seq_block_pruning.sql"),
    ),
    (
        12,
        "0012_region_handoffs",
        include_str!("../../../migrations/0012_region_handoffs.sql"),
    ),
    (
        13,
        "0013_seq_block_ends",
        include_str!("../../../migrations/0013_seq_block_ends.sql"),
    ),
];

/// How long applying the migrations may take in all (waiting for another
/// node's included).
/// (`apply` sets the same as the transaction's statement timeout.)
pub const MIGRATION_LIMIT: std::time::Duration = std::time::Duration::from_secs(600);

/// Key of the advisory lock migrations take ("strata" in ASCII).
const MIGRATION_LOCK: i64 = 0x7374_7261_7461;

/// Who opens the database, which decides when its migrations may run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Migrator {
    /// A server starting: applies what the database lacks (nodes starting
    /// together each apply it once).
    Server,
    /// An admin tool: applies what the database lacks only while no server
    /// uses it. Running servers of an older build would otherwise find
    /// their schema changed under them and could not start again.
    Admin,
}

/// Applies the migrations the database lacks. Refuses a database that a
/// newer build migrated further than this one knows, and, for
/// [`Migrator::Admin`], one behind this build that a server is using.
pub fn apply(pool: &Pool, by: Migrator) -> Result<(), StoreError> {
    let known = MIGRATIONS.last().map_or(0, |m| m.0);
    // Not under the statement timeout meant for a tick's statements: a
    // migration may rewrite whole tables, once. The server's own limit is
    // the client's, so nothing runs on once this client gave up.
    let begin = "BEGIN; SET LOCAL statement_timeout = '600s'";
    pool.run_tx_for(
        "applying migrations",
        begin,
        MIGRATION_LIMIT,
        async |c: &mut Conn| {
            c.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
                .await?;
            // A restore holds the world's tables: a migration would wait on
            // them until its statement timeout. Say why at once instead.
            if !try_serving_lock(c, "SELECT pg_try_advisory_xact_lock_shared($1)").await? {
                return Err(super::import::restore_running());
            }
            c.batch(
                "CREATE TABLE IF NOT EXISTS schema_migrations (\
             version integer PRIMARY KEY, name text NOT NULL, \
             applied_at timestamptz NOT NULL DEFAULT now())",
            )
            .await?;
            let applied: Vec<i32> = c
                .query(
                    "SELECT version FROM schema_migrations ORDER BY version",
                    &[],
                )
                .await?
                .iter()
                .map(|r| r.get(0))
                .collect();
            if let Some(&newest) = applied.last() {
                if newest > known {
                    return Err(StoreError::UnsupportedFormat {
                        found: newest as u32,
                        supported: known as u32,
                    });
                }
            }
            let missing = MIGRATIONS.iter().any(|m| !applied.contains(&m.0));
            if missing && by == Migrator::Admin {
                // Alone for this transaction: no server holds it shared.
                if !try_serving_lock(c, "SELECT pg_try_advisory_xact_lock($1)").await? {
                    return Err(StoreError::SchemaBehind {
                        found: applied_through(&applied) as u32,
                        needed: known as u32,
                    });
                }
            }
            for &(version, name, sql) in MIGRATIONS {
                if applied.contains(&version) {
                    continue;
                }
                c.batch(sql).await?;
                c.execute(
                    "INSERT INTO schema_migrations (version, name) VALUES ($1, $2)",
                    &[&version, &name],
                )
                .await?;
            }
            Ok(())
        },
    )
}

/// Runs `sql`, a try-lock of the serving lock for this transaction
/// (`$1`), and says whether it was taken.
async fn try_serving_lock(c: &mut Conn, sql: &'static str) -> Result<bool, StoreError> {
    Ok(c.query_opt(sql, &[&super::import::SERVING_LOCK])
        .await?
        .is_some_and(|r| r.get(0)))
}

/// The highest version up to which every migration is applied.
fn applied_through(applied: &[i32]) -> i32 {
    MIGRATIONS
        .iter()
        .take_while(|m| applied.contains(&m.0))
        .last()
        .map_or(0, |m| m.0)
}

/// The schema's version, checked again once a server holds the serving
/// lock: a newer build's admin tool may have migrated it between this
/// server's migrations and its lock (it migrates only while no server
/// holds the lock).
pub(super) async fn check_current(c: &mut Conn) -> Result<(), StoreError> {
    let known = MIGRATIONS.last().map_or(0, |m| m.0);
    let newest: Option<i32> = c
        .query_opt("SELECT max(version) FROM schema_migrations", &[])
        .await?
        .and_then(|r| r.get(0));
    match newest {
        Some(v) if v > known => Err(StoreError::UnsupportedFormat {
            found: v as u32,
            supported: known as u32,
        }),
        _ => Ok(()),
    }
}
