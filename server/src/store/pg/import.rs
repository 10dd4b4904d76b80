//! Filling an empty PostgreSQL store from a snapshot (`strata-admin
//! snapshot restore --config` naming `[store] backend = "postgres"`), as
//! `store/import.rs` fills sled: chunk rows first, the world row last in
//! one transaction with the zones blob, so a restore cut short leaves no
//! world row and no node mistakes it for a world. The world row names the
//! snapshot's seq as both `last_seq` and `log_base`.

use super::commit::Rows;
use super::pool::Conn;
use super::{to_sql, PgStore};
use crate::store::import::check_import_format;
use crate::store::rules::check_blob;
use crate::store::types::{RawChunk, WorldMeta};
use crate::store::{ImportTarget, StoreError};

/// The world's tables, emptied by [`PgStore::clear_world`]
/// (`schema_migrations` and `layout` stay). `seq_blocks` goes too: a
/// restored world reserves its blocks from its own `last_seq` again.
const WORLD_TABLES: &str =
    "world, chunks, chunk_deltas, edit_log, blobs, players, regions, seq_blocks";

impl PgStore {
    /// Empties every table of the world, leases included, in one
    /// transaction (`restore --force`): every node must be stopped.
    pub fn clear_world(&self) -> Result<(), StoreError> {
        self.pool
            .run_tx("clearing the world", "BEGIN", async |c: &mut Conn| {
                c.batch(&format!("TRUNCATE {WORLD_TABLES}")).await
            })
    }
}

impl ImportTarget for PgStore {
    /// Refuses a database that holds a world, chunks, log entries or blobs.
    fn begin_import(&self) -> Result<(), StoreError> {
        let row = self
            .pool
            .run("checking the store is empty", async |c: &mut Conn| {
                c.query_opt(
                    "SELECT (SELECT count(*) FROM world), (SELECT count(*) FROM chunks), \
                 (SELECT count(*) FROM edit_log), (SELECT count(*) FROM blobs)",
                    &[],
                )
                .await
            })?;
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

    /// Writes chunk records as they are; `finish_import` commits the world
    /// row that makes them a world.
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
            cols.push(self, c.pos, version, c.encoded.clone());
        }
        self.pool
            .run_tx("importing chunks", "BEGIN", async |c: &mut Conn| {
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
            })?;
        Ok(())
    }

    /// Writes the zones blob and the world row at `meta.last_seq`, in one
    /// transaction (durable at its `COMMIT`).
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
        self.pool
            .run_tx("finishing the import", "BEGIN", async |c: &mut Conn| {
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
            })
    }
}
