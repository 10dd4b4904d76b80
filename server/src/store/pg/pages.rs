//! Scans in pages: keyset pagination over the primary key, so a scan of a
//! large world holds one page at a time and no cursor (or transaction)
//! stays open between pages. Like sled's iterators, a scan is no snapshot.

use std::collections::VecDeque;
use std::ops::RangeInclusive;

use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::ChunkPos;

use super::pool::Conn;
use super::{from_sql, PgStore, PAGE_ROWS};
use crate::store::keys::show_pos;
use crate::store::record::{decode_log_entry, is_generated};
use crate::store::types::{LogEntry, RawChunk};
use crate::store::{StoreError, StoreIter};

/// One page: its items and where the next page starts (`None`: last page).
type Page<K, T> = Result<(Vec<T>, Option<K>), StoreError>;

/// Fetches the page that starts at a key.
type Fetch<'a, K, T> = Box<dyn FnMut(&K) -> Page<K, T> + Send + 'a>;

/// An iterator that fetches the next page when the current one runs out.
struct Pages<'a, K, T> {
    next: Option<K>,
    buffer: VecDeque<T>,
    fetch: Fetch<'a, K, T>,
}

impl<K, T> Iterator for Pages<'_, K, T> {
    type Item = Result<T, StoreError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(item) = self.buffer.pop_front() {
                return Some(Ok(item));
            }
            let from = self.next.take()?;
            match (self.fetch)(&from) {
                Ok((items, next)) => {
                    self.buffer.extend(items);
                    self.next = next;
                }
                // The scan ends at its first error.
                Err(e) => return Some(Err(e)),
            }
        }
    }
}

fn pages<'a, K: Send + 'a, T: Send + 'a>(
    start: K,
    fetch: impl FnMut(&K) -> Page<K, T> + Send + 'a,
) -> StoreIter<'a, T> {
    Box::new(Pages {
        next: Some(start),
        buffer: VecDeque::new(),
        fetch: Box::new(fetch),
    })
}

/// The position right after `p` in key (x, y, z) order; `None` after the last.
fn successor(p: ChunkPos) -> Option<ChunkPos> {
    if let Some(z) = p.z.checked_add(1) {
        return Some(ChunkPos::new(p.x, p.y, z));
    }
    if let Some(y) = p.y.checked_add(1) {
        return Some(ChunkPos::new(p.x, y, i32::MIN));
    }
    Some(ChunkPos::new(p.x.checked_add(1)?, i32::MIN, i32::MIN))
}

/// Where the page after one of `n` rows ending at `last` starts.
fn after(n: usize, last: Option<ChunkPos>) -> Option<ChunkPos> {
    if (n as i64) < PAGE_ROWS {
        return None;
    }
    last.and_then(successor)
}

const FIRST_POS: ChunkPos = ChunkPos::new(i32::MIN, i32::MIN, i32::MIN);

impl PgStore {
    /// `(pos, newest version)` of every stored chunk, in key order.
    pub(super) fn version_pages(&self) -> StoreIter<'_, (ChunkPos, u64)> {
        pages(FIRST_POS, move |from: &ChunkPos| {
            let rows = self.pool.run("listing chunks", async |c: &mut Conn| {
                c.query(
                    "SELECT c.x, c.y, c.z, greatest(c.version, \
                       (SELECT max(d.to_version) FROM chunk_deltas d \
                        WHERE d.x = c.x AND d.y = c.y AND d.z = c.z)) \
                     FROM chunks c WHERE (c.x, c.y, c.z) >= ($1, $2, $3) \
                     ORDER BY c.x, c.y, c.z LIMIT $4",
                    &[&from.x, &from.y, &from.z, &PAGE_ROWS],
                )
                .await
            })?;
            let items = rows
                .iter()
                .map(|r| {
                    let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
                    Ok((pos, from_sql(r.get(3), "chunk version", show_pos(pos))?))
                })
                .collect::<Result<Vec<_>, StoreError>>()?;
            let next = after(items.len(), items.last().map(|i| i.0));
            Ok((items, next))
        })
    }

    /// Every stored chunk at its newest version, as codec bytes, in key order.
    pub(super) fn raw_pages(&self) -> StoreIter<'_, RawChunk> {
        pages(FIRST_POS, move |from: &ChunkPos| {
            let rows = self.pool.run("reading chunks", async |c: &mut Conn| {
                c.query(
                    "SELECT c.x, c.y, c.z, c.version, c.body, EXISTS (\
                       SELECT 1 FROM chunk_deltas d WHERE d.x = c.x AND d.y = c.y \
                       AND d.z = c.z AND d.to_version > c.version) \
                     FROM chunks c WHERE (c.x, c.y, c.z) >= ($1, $2, $3) \
                     ORDER BY c.x, c.y, c.z LIMIT $4",
                    &[&from.x, &from.y, &from.z, &PAGE_ROWS],
                )
                .await
            })?;
            let mut items = Vec::with_capacity(rows.len());
            for r in &rows {
                let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
                // Deltas follow the record (a "generated" one has some):
                // read the two together again.
                let body: Vec<u8> = r.get(4);
                let item = if r.get::<_, bool>(5) || is_generated(&body) {
                    let (version, chunk) = self.latest(pos)?.ok_or_else(|| {
                        StoreError::corrupt("chunk record vanished", show_pos(pos))
                    })?;
                    RawChunk {
                        pos,
                        version,
                        encoded: encode_chunk(&chunk),
                    }
                } else {
                    RawChunk {
                        pos,
                        version: from_sql(r.get(3), "chunk version", show_pos(pos))?,
                        encoded: body,
                    }
                };
                items.push(item);
            }
            let next = after(items.len(), items.last().map(|i| i.pos));
            Ok((items, next))
        })
    }

    /// Log entries with seq in `seqs`, ascending.
    pub(super) fn log_pages(&self, seqs: RangeInclusive<u64>) -> StoreIter<'_, LogEntry> {
        // Seqs past i64::MAX are never stored.
        let end = i64::try_from(*seqs.end()).unwrap_or(i64::MAX);
        let Ok(start) = i64::try_from(*seqs.start()) else {
            return Box::new(std::iter::empty());
        };
        if start > end {
            return Box::new(std::iter::empty());
        }
        pages(start, move |&from: &i64| {
            let rows = self
                .pool
                .run("reading the edit log", async |c: &mut Conn| {
                    c.query(
                        "SELECT seq, entry FROM edit_log WHERE seq >= $1 AND seq <= $2 \
                     ORDER BY seq LIMIT $3",
                        &[&from, &end, &PAGE_ROWS],
                    )
                    .await
                })?;
            let items = rows
                .iter()
                .map(|r| decode_log_entry(from_sql(r.get(0), "seq", "edit_log")?, r.get(1)))
                .collect::<Result<Vec<_>, StoreError>>()?;
            let last: Option<i64> = rows.last().map(|r| r.get(0));
            let next = match last {
                Some(s) if (rows.len() as i64) == PAGE_ROWS => s.checked_add(1),
                _ => None,
            };
            Ok((items, next))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn successors_carry_across_axes_and_end_after_the_last_key() {
        let p = |x, y, z| ChunkPos::new(x, y, z);
        assert_eq!(successor(p(1, 2, 3)), Some(p(1, 2, 4)));
        assert_eq!(successor(p(1, 2, i32::MAX)), Some(p(1, 3, i32::MIN)));
        assert_eq!(
            successor(p(1, i32::MAX, i32::MAX)),
            Some(p(2, i32::MIN, i32::MIN))
        );
        assert_eq!(successor(p(i32::MAX, i32::MAX, i32::MAX)), None);
    }
}
