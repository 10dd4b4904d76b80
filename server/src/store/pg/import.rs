//! Filling a PostgreSQL store from a snapshot (`strata-admin snapshot
//! restore --config` naming `[store] backend = "postgres"`) in one
//! transaction on one connection ([`PgImport`]): the check that the store
//! is empty (or, replacing a world, its tables emptied), every chunk row,
//! the zones blob and the world row commit together. A restore cut short
//! anywhere, by an error, Ctrl-C or a kill, leaves the store as it was.
//! The world row names the snapshot's seq as both `last_seq` and
//! `log_base`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::commit::Rows;
use super::pool::{Conn, Held};
use super::{to_sql, PgStore, SERVER_APPLICATION};
use crate::auth::ACCESS_BLOB;
use crate::store::import::check_import_format;
use crate::store::rules::check_blob;
use crate::store::types::{RawChunk, WorldMeta};
use crate::store::{ImportTarget, StoreError};
use tokio_postgres::error::SqlState;

/// The world's tables a restore empties (`schema_migrations`, `layout` and
/// `nodes` stay; `regions` keeps its rows, freed at a higher epoch, so a
/// node paused across the restore is fenced). `seq_blocks` goes too: a
/// restored world reserves its blocks from its own `last_seq` again.
/// `blobs` keeps the bans and revocations (`ACCESS_BLOB`).
macro_rules! emptied_tables {
    () => {
        "world, chunks, chunk_deltas, edit_log, players, seq_blocks"
    };
}
const EMPTIED_TABLES: &str = emptied_tables!();

/// Every table a restore locks: those it empties, `blobs` and `regions`.
const LOCKED_TABLES: &str = concat!(emptied_tables!(), ", blobs, regions");

/// The advisory lock a running server holds shared for as long as it uses
/// the database ([`crate::store::ChunkStore::serve`]), and a forced restore
/// takes alone for its transaction: whatever the sessions are named,
/// neither runs while the other does.
pub const SERVING_LOCK: i64 = 0x5354_5241_5441; // "STRATA"

/// The advisory lock a server without `[cluster]` holds alone while it
/// serves, and a cluster's nodes hold shared: such a server's commits are
/// not fenced, so it may share its database with no other server.
pub const SOLO_LOCK: i64 = 0x5354_5241_534F; // "STRASO"

/// What opening or serving a store says while a restore (or an offline
/// snapshot) holds [`SERVING_LOCK`] alone.
pub(super) fn restore_running() -> StoreError {
    StoreError::PgSetup {
        reason: "a restore is replacing this database's world, an offline snapshot is \
                 reading it, or a newer strata-admin is migrating it: start the server once it \
                 is done"
            .into(),
    }
}

/// How long a restore waits, in all, for the world's tables, and for
/// running servers' sessions to leave the database.
pub const IMPORT_LOCK_WAIT_MS: u64 = 5_000;

/// The longest pause between two statements of a restore's transaction
/// (reading the snapshot's next batch) before PostgreSQL ends it.
const IMPORT_IDLE_MS: u64 = 600_000;

/// A restore into a [`PgStore`] as one transaction (see the module's
/// doc). Dropped before `finish_import` returned, it rolls back.
#[derive(Debug)]
pub struct PgImport<'a> {
    store: &'a PgStore,
    /// Empty the world's tables first, instead of refusing a store that
    /// holds a world.
    replace: bool,
    /// The transaction's connection, from `begin_import` on.
    held: Mutex<Option<Held<'a>>>,
    /// `COMMIT` was sent and failed without PostgreSQL's answer: the
    /// restore may or may not have taken.
    commit_unknown: AtomicBool,
}

impl PgStore {
    /// A restore into this store in one transaction; `replace` empties a
    /// world already there (`restore --force`) within it, refused while a
    /// node holds a region's lease.
    pub fn import_in_one_transaction(&self, replace: bool) -> PgImport<'_> {
        PgImport {
            store: self,
            replace,
            held: Mutex::new(None),
            commit_unknown: AtomicBool::new(false),
        }
    }

    /// Why the store counts as holding a world (`None`: it is empty).
    pub fn holds_world(&self) -> Result<Option<String>, StoreError> {
        self.pool.run(
            "checking the store is empty",
            async |c: &mut Conn| match refuse_non_empty(c).await {
                Ok(()) => Ok(None),
                Err(StoreError::InvalidMeta { reason }) => Ok(Some(reason)),
                Err(e) => Err(e),
            },
        )
    }
}

/// Refuses a database that holds a world, chunks, log entries or blobs
/// (an access list alone, from `ban` before any world, counts).
async fn refuse_non_empty(c: &mut Conn) -> Result<(), StoreError> {
    let row = c
        .query_opt(
            "SELECT (SELECT count(*) FROM world), (SELECT count(*) FROM chunks), \
             (SELECT count(*) FROM edit_log), (SELECT count(*) FROM blobs)",
            &[],
        )
        .await?;
    let Some(row) = row else {
        return Ok(());
    };
    for (i, name) in ["world", "chunks", "edit_log", "blobs"].iter().enumerate() {
        if row.get::<_, i64>(i) > 0 {
            return Err(StoreError::InvalidMeta {
                reason: format!("its {name} table is not empty"),
            });
        }
    }
    Ok(())
}

/// Refuses a database a running server holds ([`SERVING_LOCK`]), or
/// whose sessions named [`SERVER_APPLICATION`] use, saying where from; a
/// fresh look each time. Inside a transaction the lock, once taken, is
/// kept to its end; outside one it is let go at once (a look).
async fn refuse_servers(c: &mut Conn) -> Result<(), StoreError> {
    let free: bool = c
        .query_opt("SELECT pg_try_advisory_xact_lock($1)", &[&SERVING_LOCK])
        .await?
        .is_some_and(|r| r.get(0));
    if !free {
        return Err(StoreError::PgSetup {
            reason: "a running server holds this database: stop every node first".into(),
        });
    }
    c.batch("SELECT pg_stat_clear_snapshot()").await?;
    let row = c
        .query_opt(
            "SELECT count(*), coalesce(string_agg(DISTINCT CASE \
                 WHEN client_port = -1 THEN 'a local socket' \
                 WHEN client_addr IS NULL THEN 'an address hidden from this role' \
                 ELSE host(client_addr) END, ', '), '') \
             FROM pg_stat_activity \
             WHERE datname = current_database() AND application_name = $1 \
               AND pid <> pg_backend_pid()",
            &[&SERVER_APPLICATION],
        )
        .await?;
    let (sessions, from): (i64, String) = row.map_or((0, String::new()), |r| (r.get(0), r.get(1)));
    if sessions == 0 {
        return Ok(());
    }
    Err(StoreError::PgSetup {
        reason: format!(
            "{sessions} sessions of a running {SERVER_APPLICATION} (from {from}) use this \
             database: stop every node first"
        ),
    })
}

/// Refuses to empty a world whose regions a node still leases.
async fn refuse_live_leases(c: &mut Conn) -> Result<(), StoreError> {
    let row = c
        .query_opt(
            "SELECT count(*), min(owner), \
             ceil(extract(epoch FROM max(lease_expires) - now()))::int8 \
             FROM regions WHERE owner IS NOT NULL AND lease_expires > now()",
            &[],
        )
        .await?;
    let Some(row) = row else {
        return Ok(());
    };
    let leased: i64 = row.get(0);
    if leased == 0 {
        return Ok(());
    }
    let owner: Option<String> = row.get(1);
    let seconds: Option<i64> = row.get(2);
    Err(StoreError::PgSetup {
        reason: format!(
            "{leased} regions are leased by running nodes (node {:?} among them), for up to {} s more: stop every node first",
            owner.unwrap_or_default(),
            seconds.unwrap_or(0)
        ),
    })
}

impl PgImport<'_> {
    /// After a failure: whether `COMMIT` failed without PostgreSQL's
    /// answer, so the store may hold the restored world rather than
    /// surely the old one.
    pub fn commit_unknown(&self) -> bool {
        self.commit_unknown.load(Ordering::Relaxed)
    }

    /// The open transaction's connection.
    fn with_held<T>(
        &self,
        f: impl FnOnce(&mut Held<'_>) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let mut held = self.held.lock().unwrap_or_else(|p| p.into_inner());
        let held = held.as_mut().ok_or_else(|| StoreError::PgSetup {
            reason: "the restore's transaction is not open (begin_import first)".into(),
        })?;
        f(held)
    }
}

impl ImportTarget for PgImport<'_> {
    /// Replacing a world: waits, holding no lock, up to
    /// [`IMPORT_LOCK_WAIT_MS`] for running servers' sessions to leave the
    /// database, and refuses one whose regions a node leases. Then opens
    /// the transaction and takes the world's tables (waiting at most
    /// [`IMPORT_LOCK_WAIT_MS`] for them), looks again for servers and
    /// leases (or refuses a store that holds a world, when not
    /// replacing), empties the world's tables and frees every region at a
    /// higher epoch.
    fn begin_import(&self) -> Result<(), StoreError> {
        let mut held = self.store.pool.hold()?;
        if self.replace {
            // Outside any transaction: a server stopping meanwhile must
            // be able to let its regions go.
            let deadline = Instant::now() + Duration::from_millis(IMPORT_LOCK_WAIT_MS);
            loop {
                match held.run("looking for running servers", refuse_servers) {
                    Ok(()) => break,
                    Err(StoreError::PgSetup { .. }) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(100));
                    }
                    Err(e) => return Err(e),
                }
            }
            held.run("looking for live leases", refuse_live_leases)?;
        }
        let statement_ms = held.statement_timeout().as_millis();
        held.begin(
            "beginning the restore",
            &format!(
                "BEGIN; SET LOCAL idle_in_transaction_session_timeout = {IMPORT_IDLE_MS}; \
                 SET LOCAL lock_timeout = {IMPORT_LOCK_WAIT_MS}; \
                 SET LOCAL statement_timeout = {IMPORT_LOCK_WAIT_MS}"
            ),
        )?;
        // One bound for every table, whatever the configured timeouts.
        let lock = format!(
            "LOCK TABLE {LOCKED_TABLES} IN ACCESS EXCLUSIVE MODE; \
             SET LOCAL statement_timeout = {statement_ms}"
        );
        let margin = Duration::from_millis(IMPORT_LOCK_WAIT_MS) + Duration::from_secs(2);
        held.run_within(
            margin,
            "locking the world's tables",
            async |c: &mut Conn| {
                c.batch(&lock).await.map_err(|e| match e {
                    StoreError::Postgres(ref pg)
                        if pg.code() == Some(&SqlState::LOCK_NOT_AVAILABLE)
                            || pg.code() == Some(&SqlState::QUERY_CANCELED) =>
                    {
                        StoreError::PgSetup {
                            reason: format!(
                                "the world's tables stayed in use for {IMPORT_LOCK_WAIT_MS} ms \
                             (is a node running?): stop every node first"
                            ),
                        }
                    }
                    e => e,
                })
            },
        )?;
        if self.replace {
            // Under the lock, no server can start or claim meanwhile.
            held.run("looking for running servers", refuse_servers)?;
            held.run("looking for live leases", refuse_live_leases)?;
        } else {
            held.run("checking the store is empty", refuse_non_empty)?;
        }
        held.run("emptying the world", async |c: &mut Conn| {
            c.batch(&format!(
                "TRUNCATE {EMPTIED_TABLES}; \
                 DELETE FROM blobs WHERE name <> '{ACCESS_BLOB}'; \
                 UPDATE regions SET owner = NULL, owner_addr = NULL, epoch = epoch + 1, \
                     last_seq = 0, edits = 0, lease_expires = now(), \
                     wanted_by = NULL, wanted_at = NULL"
            ))
            .await
        })?;
        *self.held.lock().unwrap_or_else(|p| p.into_inner()) = Some(held);
        Ok(())
    }

    /// Writes chunk records as they are, inside the transaction.
    fn import_chunks(&self, chunks: &[RawChunk]) -> Result<(), StoreError> {
        if chunks.is_empty() {
            return Ok(());
        }
        let mut cols = Rows::default();
        for c in chunks {
            if c.version == 0 {
                return Err(StoreError::batch("imported chunk at version 0"));
            }
            let version = to_sql(c.version, "chunk version")?;
            cols.push(self.store, c.pos, version, c.encoded.clone());
        }
        self.with_held(|held| {
            held.run("importing chunks", async |c: &mut Conn| {
                c.execute(
                    "INSERT INTO chunks (x, y, z, region_x, region_z, version, body) \
                     SELECT * FROM unnest($1::int4[], $2::int4[], $3::int4[], $4::int4[], \
                                          $5::int4[], $6::int8[], $7::bytea[])",
                    &[
                        &cols.x,
                        &cols.y,
                        &cols.z,
                        &cols.rx,
                        &cols.rz,
                        &cols.version,
                        &cols.body,
                    ],
                )
                .await
            })
        })?;
        Ok(())
    }

    /// Writes the zones blob and the world row at `meta.last_seq`, then
    /// commits the whole restore (durable when it returns).
    fn finish_import(
        &self,
        meta: &WorldMeta,
        zones_blob: &str,
        zones: &[u8],
    ) -> Result<(), StoreError> {
        check_import_format(meta)?;
        check_blob(zones_blob, zones)?;
        let format = meta.format_version as i32;
        let seed = meta.seed as i64;
        let generator = i64::from(meta.generator_version);
        let last = to_sql(meta.last_seq, "seq")?;
        self.with_held(|held| {
            held.run("finishing the import", async |c: &mut Conn| {
                c.execute(
                    "INSERT INTO blobs (name, body) VALUES ($1, $2)",
                    &[&zones_blob, &zones],
                )
                .await?;
                c.execute(
                    "INSERT INTO world (id, format_version, seed, generator_version, \
                     generator_params, last_seq, log_base) VALUES (1, $1, $2, $3, $4, $5, $5)",
                    &[&format, &seed, &generator, &meta.generator_params, &last],
                )
                .await?;
                Ok(())
            })?;
            held.commit("committing the restore").inspect_err(|e| {
                // An error PostgreSQL sent is a rollback; a lost
                // connection or a timeout says nothing.
                let answered = matches!(e, StoreError::Postgres(pg) if pg.as_db_error().is_some());
                self.commit_unknown.store(!answered, Ordering::Relaxed);
            })
        })?;
        // The connection is clean again: back to the pool.
        drop(self.held.lock().unwrap_or_else(|p| p.into_inner()).take());
        Ok(())
    }
}
