//! Filling a PostgreSQL store from a snapshot (`strata-admin snapshot
//! restore --config` naming `[store] backend = "postgres"`) in one
//! transaction on one connection ([`PgImport`]): the check that the store
//! is empty (or, replacing a world, its tables emptied), every chunk row,
//! the zones blob and the world row commit together. A restore cut short
//! anywhere, by an error, Ctrl-C or a kill, leaves the store as it was.
//! The world row names the snapshot's seq as both `last_seq` and
//! `log_base`.

use std::sync::Mutex;

use super::commit::Rows;
use super::pool::{Conn, Held};
use super::{to_sql, PgStore};
use crate::store::import::check_import_format;
use crate::store::rules::check_blob;
use crate::store::types::{RawChunk, WorldMeta};
use crate::store::{ImportTarget, StoreError};

/// The world's tables, emptied by a replacing import (`schema_migrations`,
/// `layout` and `nodes` stay). `seq_blocks` goes too: a restored world
/// reserves its blocks from its own `last_seq` again.
const WORLD_TABLES: &str =
    "world, chunks, chunk_deltas, edit_log, blobs, players, regions, seq_blocks";

/// How long a restore waits for the world's tables: a running node holds
/// them only for moments, so a longer wait means one is running.
pub const IMPORT_LOCK_WAIT_MS: u64 = 5_000;

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
        }
    }

    /// Whether the store holds a world, chunks, log entries or blobs.
    pub fn holds_world(&self) -> Result<bool, StoreError> {
        self.pool.run(
            "checking the store is empty",
            async |c: &mut Conn| match refuse_non_empty(c).await {
                Ok(()) => Ok(false),
                Err(StoreError::InvalidMeta { .. }) => Ok(true),
                Err(e) => Err(e),
            },
        )
    }
}

/// Refuses a database that holds a world, chunks, log entries or blobs.
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
                reason: format!("cannot import into a store whose {name} table is not empty"),
            });
        }
    }
    Ok(())
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
    /// Opens the transaction, takes the world's tables (waiting at most
    /// [`IMPORT_LOCK_WAIT_MS`] for them) and refuses a store that holds a
    /// world, or, replacing, one whose regions a node leases, then empties
    /// them.
    fn begin_import(&self) -> Result<(), StoreError> {
        let mut held = self.store.pool.hold()?;
        held.begin("beginning the restore", "BEGIN")?;
        let lock = format!(
            "SET LOCAL lock_timeout = {IMPORT_LOCK_WAIT_MS}; \
             LOCK TABLE {WORLD_TABLES} IN ACCESS EXCLUSIVE MODE"
        );
        held.run("locking the world's tables", async |c: &mut Conn| {
            c.batch(&lock).await.map_err(|e| match e {
                StoreError::Postgres(ref pg)
                    if pg.code() == Some(&tokio_postgres::error::SqlState::LOCK_NOT_AVAILABLE) =>
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
        })?;
        let replace = self.replace;
        held.run("emptying the world", async |c: &mut Conn| {
            if replace {
                refuse_live_leases(c).await?;
                c.batch(&format!("TRUNCATE {WORLD_TABLES}")).await
            } else {
                refuse_non_empty(c).await
            }
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
            held.commit("committing the restore")
        })?;
        // The connection is clean again: back to the pool.
        drop(self.held.lock().unwrap_or_else(|p| p.into_inner()).take());
        Ok(())
    }
}
