//! The checkpoint: folds each chunk's deltas into its record, one
//! transaction per chunk beside commits.
//!
//! A fold locks the chunk's record row first and reads its deltas after
//! the lock, so it never overwrites a record a commit moved meanwhile, and
//! a commit that wants the row waits for the fold. Folds commit without
//! waiting for the WAL flush (a lost fold only leaves the deltas to
//! replay, and the WAL is flushed in order, so any later durable commit
//! carries it) except the pass's last, which makes the pass durable.

use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::world::ChunkGenerator;
use strata_terrain::ChunkPos;

use super::pool::Conn;
use super::read::Stored;
use super::{from_sql, PgStore};
use crate::store::keys::show_pos;
use crate::store::record::decode_delta;
use crate::store::types::CheckpointStats;
use crate::store::StoreError;

const BEGIN_LAZY: &str = "BEGIN; SET LOCAL synchronous_commit = off";

impl PgStore {
    /// Up to `max_chunks` chunks with deltas, in key order, after `after`;
    /// on a cluster node, only those of the regions it holds.
    pub(super) fn chunks_with_deltas(
        &self,
        after: Option<ChunkPos>,
        max_chunks: usize,
    ) -> Result<Vec<ChunkPos>, StoreError> {
        let limit = i64::try_from(max_chunks).unwrap_or(i64::MAX);
        let from_start = after.is_none();
        let a = after.unwrap_or(ChunkPos::new(0, 0, 0));
        let (every_region, xs, zs): (bool, Vec<i32>, Vec<i32>) = match &self.leases {
            None => (true, Vec::new(), Vec::new()),
            Some(l) => {
                let (xs, zs) = l.held().keys().map(|r| (r.x, r.z)).unzip();
                (false, xs, zs)
            }
        };
        if !every_region && xs.is_empty() {
            return Ok(Vec::new());
        }
        Ok(self
            .pool
            .run("listing deltas to fold", async |c: &mut Conn| {
                c.query(
                    "SELECT DISTINCT x, y, z FROM chunk_deltas \
                     WHERE ($2::bool OR (x, y, z) > ($3::int4, $4::int4, $5::int4)) \
                       AND ($6::bool OR (region_x, region_z) IN \
                            (SELECT * FROM unnest($7::int4[], $8::int4[]))) \
                     ORDER BY x, y, z LIMIT $1",
                    &[
                        &limit,
                        &from_start,
                        &a.x,
                        &a.y,
                        &a.z,
                        &every_region,
                        &xs,
                        &zs,
                    ],
                )
                .await
            })?
            .iter()
            .map(|r| ChunkPos::new(r.get(0), r.get(1), r.get(2)))
            .collect())
    }

    /// Folds the deltas of `chunks`, the last fold durably.
    pub(super) fn fold_chunks(&self, chunks: &[ChunkPos]) -> Result<CheckpointStats, StoreError> {
        let mut stats = CheckpointStats::default();
        for (i, &pos) in chunks.iter().enumerate() {
            let begin = if i + 1 == chunks.len() {
                "BEGIN"
            } else {
                BEGIN_LAZY
            };
            let folded = self
                .pool
                .run_tx("folding a chunk", begin, async |c: &mut Conn| {
                    fold_one(c, pos, self.generator()).await
                });
            let (deltas, bytes) = match folded {
                Ok(f) => f,
                // One unreadable chunk must not stop every later pass.
                Err(e) if e.is_chunk_local() => {
                    tracing::error!(error = %e, "checkpoint left a chunk unfolded");
                    stats.skipped += 1;
                    continue;
                }
                Err(e) => return Err(e),
            };
            if deltas > 0 {
                stats.chunks += 1;
                stats.deltas += deltas;
                stats.bytes_written += bytes;
            }
        }
        Ok(stats)
    }
}

/// Deltas one fold reads and folds at most (`deltas::MAX_FOLD_DELTAS`): a
/// longer backlog folds over several passes.
const FOLD_LIMIT: i64 = crate::store::deltas::MAX_FOLD_DELTAS as i64;

/// Folds `pos`'s deltas into its record, the first [`FOLD_LIMIT`] of
/// them: (deltas removed, bytes written).
async fn fold_one(
    c: &mut Conn,
    pos: ChunkPos,
    generator: Option<&dyn ChunkGenerator>,
) -> Result<(u64, u64), StoreError> {
    let Some(record) = c
        .query_opt(
            "SELECT version, body FROM chunks WHERE x = $1 AND y = $2 AND z = $3 FOR UPDATE",
            &[&pos.x, &pos.y, &pos.z],
        )
        .await?
    else {
        return Err(StoreError::corrupt(
            "deltas without a chunk record",
            show_pos(pos),
        ));
    };
    let version = from_sql(record.get(0), "chunk version", show_pos(pos))?;
    let mut deltas = Vec::new();
    for r in c
        .query(
            "SELECT to_version, body FROM chunk_deltas \
             WHERE x = $1 AND y = $2 AND z = $3 ORDER BY to_version LIMIT $4",
            &[&pos.x, &pos.y, &pos.z, &FOLD_LIMIT],
        )
        .await?
    {
        let to = from_sql(r.get(0), "delta version", show_pos(pos))?;
        deltas.push(decode_delta(pos, to, r.get(1))?);
    }
    let removed = deltas.len() as u64;
    if removed == 0 {
        // Folded since it was listed.
        return Ok((0, 0));
    }
    let (head, state) = Stored {
        version,
        body: record.get(1),
        deltas,
    }
    .replayed(pos, generator)?;
    let body = encode_chunk(&state);
    let head_sql = super::to_sql(head, "chunk version")?;
    c.execute(
        "UPDATE chunks SET version = $4, body = $5 WHERE x = $1 AND y = $2 AND z = $3",
        &[&pos.x, &pos.y, &pos.z, &head_sql, &body],
    )
    .await?;
    c.execute(
        "DELETE FROM chunk_deltas WHERE x = $1 AND y = $2 AND z = $3 AND to_version <= $4",
        &[&pos.x, &pos.y, &pos.z, &head_sql],
    )
    .await?;
    Ok((removed, body.len() as u64))
}
