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

impl PgStore {
    /// `pos`'s record and deltas, or `None` when the store lacks it.
    pub(super) fn stored(&self, pos: ChunkPos) -> Result<Option<Stored>, StoreError> {
        let rows = self.pool.run("reading a chunk", async |c: &mut Conn| {
            c.query(SELECT_CHUNK, &[&pos.x, &pos.y, &pos.z]).await
        })?;
        let mut rows = rows.into_iter();
        let Some(first) = rows.next() else {
            return Ok(None);
        };
        if !first.get::<_, bool>(0) {
            return Err(StoreError::corrupt(
                "deltas without a chunk record",
                show_pos(pos),
            ));
        }
        let version = from_sql(first.get(1), "chunk version", show_pos(pos))?;
        let deltas = rows
            .map(|r| {
                let to = from_sql(r.get(1), "delta version", show_pos(pos))?;
                decode_delta(pos, to, r.get(2))
            })
            .collect::<Result<_, _>>()?;
        Ok(Some(Stored {
            version,
            body: first.get(2),
            deltas,
        }))
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

impl Stored {
    /// The record decoded (a "generated" one through `generator`) and the
    /// deltas applied, each hash-checked.
    pub fn replayed(
        self,
        pos: ChunkPos,
        generator: Option<&dyn ChunkGenerator>,
    ) -> Result<(u64, Chunk), StoreError> {
        let chunk = decode_record(pos, self.version, &self.body, generator)?;
        replay(pos, self.version, chunk, &self.deltas)?.map_err(|_| {
            StoreError::corrupt(
                "delta chain does not start at the chunk record's version",
                show_pos(pos),
            )
        })
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
