//! `check` on PostgreSQL: every row goes through the sled store's
//! [`Checker`] in the byte form it checks (sled keys, record values), so
//! both backends answer to the same invariants. Tables the store does not
//! know are reported with their row counts.

use strata_terrain::ChunkPos;

use super::pool::Conn;
use super::{from_sql, PgStore, MIGRATIONS_TABLE, PAGE_ROWS};
use crate::store::check::{CheckReport, Checker};
use crate::store::keys::{chunk_key, delta_key, seq_key};
use crate::store::StoreError;

/// Tables of this layout.
const TABLES: &[&str] = &[
    MIGRATIONS_TABLE,
    "world",
    "layout",
    "chunks",
    "chunk_deltas",
    "edit_log",
    "blobs",
    "players",
    "regions",
    "seq_blocks",
    "nodes",
];

impl PgStore {
    /// [`crate::store::ChunkStore::check`], calling `tick` once per row scanned.
    pub fn check_with_progress(&self, tick: &dyn Fn()) -> Result<CheckReport, StoreError> {
        let world = self.pool.run("reading the world", async |c: &mut Conn| {
            // A store never clustered keeps its row's last seq exact.
            c.query_opt(
                concat!(
                    "SELECT CASE WHEN EXISTS (SELECT 1 FROM seq_blocks) THEN ",
                    super::last_seq_sql!(),
                    " ELSE last_seq END, log_base FROM world WHERE id = 1"
                ),
                &[],
            )
            .await
        })?;
        let mut checker = Checker::new();
        let mut last_seq = None;
        if let Some(w) = &world {
            match from_sql(w.get(1), "log_base", "world") {
                Ok(0) => {}
                Ok(base) => checker = Checker::with_log_base(base),
                Err(e) => checker.meta_issue(e.to_string()),
            }
            match from_sql(w.get(0), "last_seq", "world") {
                Ok(s) => last_seq = Some(s),
                Err(e) => {
                    checker.meta_issue(e.to_string());
                    last_seq = Some(0);
                }
            }
        }
        checker.allow_jumps_to(super::seqs::block_starts(&self.pool)?);
        checker.allow_pruned(super::seqs::pruned_starts(&self.pool)?);
        self.check_tables(&mut checker)?;
        let mut seq = 0i64;
        loop {
            let rows = self.pool.run("checking the log", async |c: &mut Conn| {
                c.query(
                    "SELECT seq, entry FROM edit_log WHERE seq > $1 ORDER BY seq LIMIT $2",
                    &[&seq, &PAGE_ROWS],
                )
                .await
            })?;
            for r in &rows {
                seq = r.get(0);
                checker.log_record(&seq_key(seq as u64), r.get(1));
                tick();
            }
            if (rows.len() as i64) < PAGE_ROWS {
                break;
            }
        }
        self.scan_keyed(
            "SELECT x, y, z, version, body FROM chunks WHERE (x, y, z) >= ($1, $2, $3) \
             ORDER BY x, y, z LIMIT $4",
            |pos, version, body| {
                let mut value = (version as u64).to_be_bytes().to_vec();
                value.extend_from_slice(body);
                checker.chunk_record(&chunk_key(pos), &value);
                tick();
            },
        )?;
        self.scan_keyed(
            "SELECT x, y, z, to_version, body FROM chunk_deltas \
             WHERE (x, y, z, to_version) >= ($1, $2, $3, $5) \
             ORDER BY x, y, z, to_version LIMIT $4",
            |pos, to, body| {
                checker.delta_record(&delta_key(pos, to as u64), body);
                tick();
            },
        )?;
        Ok(checker.finish(last_seq))
    }

    /// Reports every table of the schema this layout does not have.
    fn check_tables(&self, checker: &mut Checker) -> Result<(), StoreError> {
        let names: Vec<String> = self
            .pool
            .run("listing tables", async |c: &mut Conn| {
                c.query(
                    "SELECT table_name::text FROM information_schema.tables \
                     WHERE table_schema = current_schema() ORDER BY table_name",
                    &[],
                )
                .await
            })?
            .iter()
            .map(|r| r.get(0))
            .filter(|n: &String| !TABLES.contains(&n.as_str()))
            .collect();
        for name in names {
            let quoted = format!("\"{}\"", name.replace('"', "\"\""));
            let count = self.pool.run("counting rows", async |c: &mut Conn| {
                // The name came from the catalog and is quoted as an identifier.
                let sql = format!("SELECT count(*)::text FROM {quoted}");
                let n = c.simple_value(&sql).await?;
                Ok(n.and_then(|n| n.parse::<u64>().ok()).unwrap_or(0))
            })?;
            if count > 0 {
                checker.unknown_tree(name.as_bytes(), count);
            }
        }
        Ok(())
    }

    /// Pages through a table keyed by (x, y, z[, version]) whose rows are
    /// (x, y, z, version, body), in key order. Each page starts at the
    /// last key seen (`>=`, skipped here), so the lowest key is not lost.
    fn scan_keyed(
        &self,
        sql: &'static str,
        mut each: impl FnMut(ChunkPos, i64, &[u8]),
    ) -> Result<(), StoreError> {
        let needs_version = sql.contains("$5");
        let mut at = (i32::MIN, i32::MIN, i32::MIN, i64::MIN);
        let mut first = true;
        loop {
            let rows = self.pool.run("checking chunks", async |c: &mut Conn| {
                if needs_version {
                    c.query(sql, &[&at.0, &at.1, &at.2, &PAGE_ROWS, &at.3])
                        .await
                } else {
                    c.query(sql, &[&at.0, &at.1, &at.2, &PAGE_ROWS]).await
                }
            })?;
            for r in &rows {
                let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
                let v: i64 = r.get(3);
                if first || (pos.x, pos.y, pos.z, v) > at {
                    each(pos, v, r.get(4));
                }
                at = (pos.x, pos.y, pos.z, v);
                first = false;
            }
            if (rows.len() as i64) < PAGE_ROWS {
                return Ok(());
            }
        }
    }
}
