//! Seq blocks: how the nodes of a cluster number edits without sharing a
//! counter on every edit.
//!
//! A node reserves a block of `[cluster] seq_block` seqs (one `UPDATE` of
//! the world row, above every seq reserved or committed before) when its
//! engine starts, after a fenced commit, when it claims a region whose
//! last edit has a seq above its block (a region written by a node with a
//! newer block), and, on its lease thread, when a quarter of its block is
//! left (`lease.rs` `refill_seqs`; the quarter goes unused). Its engine never hands out a seq outside
//! its block ([`crate::store::ChunkStore::seq_bounds`]): edits past the
//! block's end wait for the next one. So two nodes never use the same
//! seq, and each region's seqs keep rising across owners, which every
//! fenced commit checks (`fence.rs`). The log then has gaps, each ending
//! at a block's first seq; `seq_blocks` records those for `check`, and
//! each block's last seq for readers of the log (`log_cursor.rs`).

use std::collections::BTreeSet;

use super::pool::{Conn, Pool};
use super::{from_sql, to_sql};
use crate::store::StoreError;

/// A node reserves its next block once this part of its block is left (a
/// quarter: at the default 2^24 seqs, 4.2 M seqs, 7 minutes ahead of its
/// end at 10,000 edits a second).
pub const REFILL_PART: u64 = 4;

/// Reserves the next block of `size` seqs for `node`. Returns the seq just
/// below it: the node's edits are numbered from the one after. With
/// `lock_wait`, waits at most that long for the world row (another node
/// reserving, perhaps paused), and fails past it, the transaction rolled
/// back and its connection kept.
pub(super) fn reserve(
    pool: &Pool,
    node: &str,
    size: u64,
    lock_wait: Option<std::time::Duration>,
) -> Result<u64, StoreError> {
    let size_sql = to_sql(size, "seq block")?;
    let end: Option<i64> = pool.run_tx("reserving seqs", "BEGIN", async |c: &mut Conn| {
        if let Some(wait) = lock_wait {
            let ms = wait.as_millis().max(1);
            c.batch(&format!("SET LOCAL lock_timeout = '{ms}ms'"))
                .await?;
        }
        let updated = c
            .query_opt(
                "UPDATE world SET seq_reserved = GREATEST(seq_reserved, last_seq) + $1 \
                 WHERE id = 1 AND GREATEST(seq_reserved, last_seq) <= 9223372036854775807 - $1 \
                 RETURNING seq_reserved",
                &[&size_sql],
            )
            .await;
        let row = match updated {
            Err(StoreError::Postgres(e))
                if e.code() == Some(&tokio_postgres::error::SqlState::LOCK_NOT_AVAILABLE) =>
            {
                return Err(StoreError::batch(format!(
                    "the world row stayed locked past {} ms (another node reserving seqs)",
                    lock_wait.unwrap_or_default().as_millis()
                )));
            }
            other => other?,
        };
        let Some(row) = row else {
            return Ok(None);
        };
        let end: i64 = row.get(0);
        c.execute(
            "INSERT INTO seq_blocks (first_seq, last_seq, node) VALUES ($1, $2, $3)",
            &[&(end - size_sql + 1), &end, &node],
        )
        .await?;
        Ok(Some(end))
    })?;
    let Some(end) = end else {
        return Err(StoreError::batch(
            "no seq block left below 2^63 (or no world row yet)".to_string(),
        ));
    };
    Ok(from_sql(end, "seq_reserved", "world")? - size)
}

/// The first seq of every block ever reserved.
pub(super) fn block_starts(pool: &Pool) -> Result<BTreeSet<u64>, StoreError> {
    let rows = pool.run("reading seq blocks", async |c: &mut Conn| {
        c.query("SELECT first_seq FROM seq_blocks", &[]).await
    })?;
    rows.iter()
        .map(|r| from_sql(r.get(0), "first_seq", "seq_blocks"))
        .collect()
}

/// Where each block's log was pruned to: `pruned_to + 1` of every block
/// whose start was pruned (the log may jump there).
pub(super) fn pruned_starts(pool: &Pool) -> Result<BTreeSet<u64>, StoreError> {
    let rows = pool.run("reading seq blocks", async |c: &mut Conn| {
        c.query(
            "SELECT pruned_to + 1 FROM seq_blocks WHERE pruned_to > 0",
            &[],
        )
        .await
    })?;
    rows.iter()
        .map(|r| from_sql(r.get(0), "pruned_to", "seq_blocks"))
        .collect()
}
