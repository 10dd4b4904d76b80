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
];

/// Key of the advisory lock migrations take ("strata" in ASCII).
const MIGRATION_LOCK: i64 = 0x7374_7261_7461;

/// Applies the migrations the database lacks. Refuses a database that a
/// newer build migrated further than this one knows.
pub fn apply(pool: &Pool) -> Result<(), StoreError> {
    let known = MIGRATIONS.last().map_or(0, |m| m.0);
    pool.run_tx("applying migrations", "BEGIN", async |c: &mut Conn| {
        c.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
            .await?;
        // A restore holds the world's tables: a migration would wait on
        // them until its statement timeout. Say why at once instead.
        let free: bool = c
            .query_opt(
                "SELECT pg_try_advisory_xact_lock_shared($1)",
                &[&super::import::SERVING_LOCK],
            )
            .await?
            .is_some_and(|r| r.get(0));
        if !free {
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
    })
}
