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

/// Blocks one [`compact`] reads at most.
pub const COMPACT_MOST: i64 = 256;

/// The `node` of a compacted range of blocks (no node's name is empty).
const COMPACTED: &str = "";

/// Merges the lowest blocks into one row of no node's (a handoff or a
/// refill reserves a block each, so the table would grow as long as the
/// world runs): those with no log entry left (pruned, or never used) whose
/// node moved on to a later block more than [`DEAD_SEGMENT_KEPT`] ago (a
/// log reader reads no further back, and the engine has long left them),
/// from the lowest up to the first that is not. The merged row keeps the
/// range's first seq and the highest `pruned_to` (`check`, `prune_log` and
/// the pruned-or-never-logged answers read it as before). A fenced commit
/// numbered in a merged block (its node paused all that while) is refused
/// (`fence.rs`): it holds its block's row, and this waits for it. Returns
/// how many rows went.
///
/// [`DEAD_SEGMENT_KEPT`]: crate::store::DEAD_SEGMENT_KEPT
pub(super) fn compact(pool: &Pool) -> Result<u64, StoreError> {
    let kept = crate::store::DEAD_SEGMENT_KEPT.as_millis() as i64;
    let rows = pool.run("reading seq blocks to compact", async |c: &mut Conn| {
        c.query(
            "SELECT b.first_seq, b.last_seq, \
                 (b.node = $1 OR COALESCE((SELECT s.reserved_at < now() - $2::int8 * interval '1 millisecond' \
                     FROM seq_blocks s WHERE s.node = b.node AND s.first_seq > b.first_seq \
                     ORDER BY s.first_seq LIMIT 1), false)) \
                 AND NOT EXISTS (SELECT 1 FROM edit_log e \
                     WHERE e.seq >= b.first_seq AND e.seq <= b.last_seq) \
             FROM seq_blocks b ORDER BY b.first_seq LIMIT $3",
            &[&COMPACTED, &kept, &COMPACT_MOST],
        )
        .await
    })?;
    let merged: Vec<(i64, i64)> = rows
        .iter()
        .take_while(|r| r.get::<_, bool>(2))
        .map(|r| (r.get(0), r.get(1)))
        .collect();
    let (Some(&(lo, _)), Some(&(_, hi))) = (merged.first(), merged.last()) else {
        return Ok(0);
    };
    if merged.len() < 2 {
        return Ok(0);
    }
    let firsts: Vec<i64> = merged.iter().map(|&(f, _)| f).collect();
    pool.run_tx("compacting seq blocks", "BEGIN", async |c: &mut Conn| {
        // A commit holding one of them (paused, perhaps) is not waited for
        // long: the next pass tries again.
        c.batch("SET LOCAL lock_timeout = '1000ms'").await?;
        let locked = match c
            .query(
                "SELECT first_seq FROM seq_blocks WHERE first_seq = ANY($1) \
                 ORDER BY first_seq FOR UPDATE",
                &[&firsts],
            )
            .await
        {
            Ok(rows) => rows.len(),
            Err(StoreError::Postgres(e))
                if e.code() == Some(&tokio_postgres::error::SqlState::LOCK_NOT_AVAILABLE) =>
            {
                return Err(StoreError::batch(
                    "a commit held a seq block to compact past 1 s".to_string(),
                ));
            }
            Err(e) => return Err(e),
        };
        // Read again under the locks: a commit that held one may have
        // logged there, and another compaction may have run.
        let logged = c
            .query_opt(
                "SELECT 1 FROM edit_log WHERE seq >= $1 AND seq <= $2 LIMIT 1",
                &[&lo, &hi],
            )
            .await?;
        if locked != firsts.len() || logged.is_some() {
            return Ok(0);
        }
        c.execute(
            "WITH gone AS (DELETE FROM seq_blocks WHERE first_seq = ANY($1) AND first_seq <> $2 \
                 RETURNING pruned_to) \
             UPDATE seq_blocks SET node = $4, last_seq = $3, \
                 pruned_to = GREATEST(pruned_to, (SELECT COALESCE(max(pruned_to), 0) FROM gone)) \
             WHERE first_seq = $2",
            &[&firsts, &lo, &hi, &COMPACTED],
        )
        .await?;
        Ok(firsts.len() as u64 - 1)
    })
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
