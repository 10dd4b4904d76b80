//! Reads of one chunk: its record and the deltas past it, in one statement
//! (one snapshot, so a concurrent fold can never split them), replayed
//! with the sled store's hash-checked `replay`.

use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::world::ChunkGenerator;
use strata_terrain::{Chunk, ChunkPos};

use super::pool::Conn;
use super::{from_sql, PgStore};
use crate::sequencer::regions::RegionId;
use crate::store::deltas::replay;
use crate::store::keys::show_pos;
use crate::store::record::{decode_delta, decode_record, is_generated};
use crate::store::types::RawChunk;
use crate::store::StoreError;

/// A chunk's record (version and codec bytes) and its deltas past it.
pub(super) struct Stored {
    pub version: u64,
    pub body: Vec<u8>,
    pub deltas: Vec<ChunkDelta>,
}

/// The record first (`is_record`), then its deltas past it by version.
const SELECT_CHUNK: &str = "\
    SELECT true AS is_record, version, body FROM chunks WHERE x = $1 AND y = $2 AND z = $3 \
    UNION ALL \
    SELECT false, d.to_version, d.body FROM chunk_deltas d \
    WHERE d.x = $1 AND d.y = $2 AND d.z = $3 AND d.to_version > \
          coalesce((SELECT version FROM chunks WHERE x = $1 AND y = $2 AND z = $3), 0) \
    ORDER BY is_record DESC, version";

/// [`SELECT_CHUNK`] for many chunks (`$1`, `$2`, `$3`: their x, y, z) in
/// one statement, each chunk's rows together.
const SELECT_CHUNKS: &str = "\
    WITH want AS (SELECT DISTINCT * FROM unnest($1::int4[], $2::int4[], $3::int4[]) AS u(x, y, z)) \
    SELECT c.x, c.y, c.z, true AS is_record, c.version, c.body FROM chunks c \
    JOIN want w ON c.x = w.x AND c.y = w.y AND c.z = w.z \
    UNION ALL \
    SELECT d.x, d.y, d.z, false, d.to_version, d.body FROM chunk_deltas d \
    JOIN want w ON d.x = w.x AND d.y = w.y AND d.z = w.z \
    WHERE d.to_version > coalesce( \
        (SELECT version FROM chunks c WHERE c.x = d.x AND c.y = d.y AND c.z = d.z), 0) \
    ORDER BY 1, 2, 3, 4 DESC, 5";

/// Chunks one [`SELECT_CHUNKS`] reads at most (their bodies come back
/// together).
const CHUNKS_PER_READ: usize = 256;

impl PgStore {
    /// Each of `positions`' newest durable state, in their order, in one
    /// statement per [`CHUNKS_PER_READ`].
    pub(super) fn latest_many(
        &self,
        positions: &[ChunkPos],
    ) -> Result<Vec<Option<(u64, Chunk)>>, StoreError> {
        let mut out = Vec::with_capacity(positions.len());
        for part in positions.chunks(CHUNKS_PER_READ) {
            let (xs, ys, zs): (Vec<i32>, Vec<i32>, Vec<i32>) =
                part.iter().map(|p| (p.x, p.y, p.z)).collect();
            let rows = self.pool.run("reading chunks", async |c: &mut Conn| {
                c.query(SELECT_CHUNKS, &[&xs, &ys, &zs]).await
            })?;
            let mut found: std::collections::HashMap<ChunkPos, Vec<tokio_postgres::Row>> =
                std::collections::HashMap::new();
            for r in rows {
                let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
                found.entry(pos).or_default().push(r);
            }
            for &pos in part {
                let stored = match found.get(&pos) {
                    Some(rows) => Some(stored_from(pos, rows, 3)?),
                    None => None,
                };
                out.push(
                    stored
                        .map(|s| s.replayed(pos, self.generator()))
                        .transpose()?,
                );
            }
        }
        Ok(out)
    }

    /// `pos`'s record and deltas, or `None` when the store lacks it.
    pub(super) fn stored(&self, pos: ChunkPos) -> Result<Option<Stored>, StoreError> {
        let rows = self.pool.run("reading a chunk", async |c: &mut Conn| {
            c.query(SELECT_CHUNK, &[&pos.x, &pos.y, &pos.z]).await
        })?;
        if rows.is_empty() {
            return Ok(None);
        }
        stored_from(pos, &rows, 0).map(Some)
    }

    /// `pos`'s newest durable state: its record with the deltas past it.
    pub(super) fn latest(&self, pos: ChunkPos) -> Result<Option<(u64, Chunk)>, StoreError> {
        self.stored(pos)?
            .map(|s| s.replayed(pos, self.generator()))
            .transpose()
    }

    /// `pos`'s newest durable state as codec bytes: the record's own
    /// bytes when no delta follows it, else replayed and encoded again.
    pub(super) fn raw_latest(&self, pos: ChunkPos) -> Result<Option<RawChunk>, StoreError> {
        let Some(s) = self.stored(pos)? else {
            return Ok(None);
        };
        if s.deltas.is_empty() && !is_generated(&s.body) {
            return Ok(Some(RawChunk {
                pos,
                version: s.version,
                encoded: s.body,
            }));
        }
        let (version, chunk) = s.replayed(pos, self.generator())?;
        Ok(Some(RawChunk {
            pos,
            version,
            encoded: encode_chunk(&chunk),
        }))
    }
}

/// A chunk's rows (its record, then its deltas past it by version; the
/// columns `is_record, version, body` from `at` on) as a [`Stored`].
fn stored_from(
    pos: ChunkPos,
    rows: &[tokio_postgres::Row],
    at: usize,
) -> Result<Stored, StoreError> {
    let Some((first, deltas)) = rows.split_first() else {
        return Err(StoreError::corrupt("no chunk rows", show_pos(pos)));
    };
    if !first.get::<_, bool>(at) {
        return Err(StoreError::corrupt(
            "deltas without a chunk record",
            show_pos(pos),
        ));
    }
    let version = from_sql(first.get(at + 1), "chunk version", show_pos(pos))?;
    let deltas = deltas
        .iter()
        .map(|r| {
            let to = from_sql(r.get(at + 1), "delta version", show_pos(pos))?;
            decode_delta(pos, to, r.get(at + 2))
        })
        .collect::<Result<_, _>>()?;
    Ok(Stored {
        version,
        body: first.get(at + 2),
        deltas,
    })
}

impl Stored {
    /// The record decoded (a "generated" one through `generator`) and the
    /// deltas applied, each hash-checked.
    pub fn replayed(
        self,
        pos: ChunkPos,
        generator: Option<&dyn ChunkGenerator>,
    ) -> Result<(u64, Chunk), StoreError> {
        let chunk = decode_record(pos, self.version, &self.body, generator)?;
        let deltas = self.deltas.into_iter().map(Ok);
        match replay(pos, self.version, chunk, deltas, usize::MAX)? {
            Ok(r) => Ok((r.version, r.chunk)),
            Err(_) => Err(StoreError::corrupt(
                "delta chain does not start at the chunk record's version",
                show_pos(pos),
            )),
        }
    }
}

impl PgStore {
    /// Every stored chunk of `region` with its newest version (its record's
    /// or its last delta's), for a node that just claimed the region.
    pub(super) fn stored_versions(
        &self,
        region: RegionId,
    ) -> Result<Vec<(ChunkPos, u64)>, StoreError> {
        let rows = self
            .pool
            .run("reading a region's versions", async |c: &mut Conn| {
                c.query(
                    "SELECT x, y, z, max(v) FROM ( \
                     SELECT x, y, z, version AS v FROM chunks \
                     WHERE region_x = $1 AND region_z = $2 \
                     UNION ALL \
                     SELECT x, y, z, to_version FROM chunk_deltas \
                     WHERE region_x = $1 AND region_z = $2) AS s \
                 GROUP BY x, y, z",
                    &[&region.x, &region.z],
                )
                .await
            })?;
        rows.iter()
            .map(|r| {
                let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
                Ok((pos, from_sql(r.get(3), "chunk version", show_pos(pos))?))
            })
            .collect()
    }
}
