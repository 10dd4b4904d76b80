//! Seq blocks: how the nodes of a cluster number edits without sharing a
//! counter on every edit.
//!
//! A node reserves a block of [`SEQ_BLOCK`] seqs (one `UPDATE` of the
//! world row, above every seq reserved or committed before) when its
//! engine starts, and again when it claims a region whose last edit has a
//! seq above the start of its block (a region written by a node with a
//! newer block). Its engine never hands out a seq below its block
//! ([`crate::store::ChunkStore::seq_floor`]). So two nodes never use the
//! same seq, and each region's seqs keep rising across owners, which
//! every fenced commit checks (`fence.rs`). The log then has gaps, each
//! ending at a block's first seq; `seq_blocks` records those for `check`.

use std::collections::BTreeSet;

use super::pool::{Conn, Pool};
use super::{from_sql, to_sql};
use crate::store::StoreError;

/// Seqs in one block: at 1,000 edits a second a node takes 35 years to
/// use one up, and 2^23 blocks fit below 2^63.
pub const SEQ_BLOCK: u64 = 1 << 40;

/// Reserves the next block for `node`. Returns the seq just below it:
/// the node's edits are numbered from the one after.
pub(super) fn reserve(pool: &Pool, node: &str) -> Result<u64, StoreError> {
    let size = to_sql(SEQ_BLOCK, "seq block")?;
    let end: Option<i64> = pool.run_tx("reserving seqs", "BEGIN", async |c: &mut Conn| {
        let Some(row) = c
            .query_opt(
                "UPDATE world SET seq_reserved = GREATEST(seq_reserved, last_seq) + $1 \
                 WHERE id = 1 AND GREATEST(seq_reserved, last_seq) <= 9223372036854775807 - $1 \
                 RETURNING seq_reserved",
                &[&size],
            )
            .await?
        else {
            return Ok(None);
        };
        let end: i64 = row.get(0);
        c.execute(
            "INSERT INTO seq_blocks (first_seq, node) VALUES ($1, $2)",
            &[&(end - size + 1), &node],
        )
        .await?;
        Ok(Some(end))
    })?;
    let Some(end) = end else {
        return Err(StoreError::batch(
            "no seq block left below 2^63 (or no world row yet)".to_string(),
        ));
    };
    Ok(from_sql(end, "seq_reserved", "world")? - SEQ_BLOCK)
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
