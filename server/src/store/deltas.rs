//! The small durable record: a commit stores the changes of an already
//! stored chunk as one delta across the tick's changes of it (the delta
//! format clients receive, spanning versions), and a checkpoint
//! later folds a chunk's deltas into its record. Every read replays the
//! deltas past the record, so readers always see the newest durable state,
//! and recovery after a crash is just that replay. A chunk first stored
//! with a generator attached has a "generated" record (version 0): its
//! base is the generator's output, and the first fold writes it whole.

use sled::transaction::{ConflictableTransactionError, TransactionError, Transactional};
use strata_terrain::delta::ChunkDelta;
use strata_terrain::{Chunk, ChunkPos};

use super::error::StoreError;
use super::keys::{
    chunk_key, delta_from_key, delta_key, show_pos, show_raw, CHUNK_KEY_LEN, DELTA_KEY_LEN,
};
use super::record::{decode_chunk_value, decode_delta, encode_chunk_value, split_chunk_value};
use super::sled_store::SledStore;
use super::types::CheckpointStats;

/// Reads of a record and its deltas retried when a checkpoint moved the
/// record between the two reads.
const READ_RETRIES: usize = 32;

/// Why a checkpoint left a chunk alone this pass.
pub(super) struct Moved;

impl SledStore {
    /// The attached generator, which "generated" records need.
    pub(super) fn generator(&self) -> Option<&dyn strata_terrain::world::ChunkGenerator> {
        self.generator.get().map(|g| g.as_ref())
    }

    /// `pos`'s deltas, in version order, decoded as the scan yields them:
    /// a replay holds one at a time however long the chain.
    fn deltas_of(
        &self,
        pos: ChunkPos,
    ) -> impl Iterator<Item = Result<ChunkDelta, StoreError>> + '_ {
        self.deltas.scan_prefix(chunk_key(pos)).map(|r| {
            let (k, v) = r?;
            let (p, to) =
                delta_from_key(&k).ok_or_else(|| StoreError::corrupt("delta key", show_raw(&k)))?;
            decode_delta(p, to, &v)
        })
    }

    /// The version of `pos`'s record, `None` when the store lacks it.
    fn record_version(&self, pos: ChunkPos) -> Result<Option<u64>, StoreError> {
        self.chunks
            .get(chunk_key(pos))?
            .map(|v| split_chunk_value(pos, &v).map(|(version, _)| version))
            .transpose()
    }

    /// The newest durable version of `pos` given the version of its record
    /// as read earlier: the last delta's, if any. A scan is no snapshot, so
    /// the record is read again after it; a fold that committed in between
    /// moved the record's version, and the scan runs again.
    pub(super) fn head_version(&self, pos: ChunkPos, record: u64) -> Result<u64, StoreError> {
        let mut record = record;
        for _ in 0..READ_RETRIES {
            let last = match self.deltas.scan_prefix(chunk_key(pos)).keys().next_back() {
                Some(k) => {
                    let k = k?;
                    let (_, to) = delta_from_key(&k)
                        .ok_or_else(|| StoreError::corrupt("delta key", show_raw(&k)))?;
                    to
                }
                None => 0,
            };
            let now = self.record_version(pos)?.unwrap_or(record);
            if now == record {
                return Ok(last.max(record));
            }
            record = now;
        }
        Err(StoreError::corrupt(
            "chunk record kept moving under a read",
            show_pos(pos),
        ))
    }

    /// `pos`'s newest durable state: its record with the deltas past it
    /// applied (each checked against its base and target hashes). `None`
    /// for a chunk the store does not hold. Safe beside folds: a fold that
    /// commits during the deltas' scan (which is no snapshot) moves the
    /// record, and the read starts again.
    pub(super) fn latest(&self, pos: ChunkPos) -> Result<Option<(u64, Chunk)>, StoreError> {
        for _ in 0..READ_RETRIES {
            let record = self.chunks.get(chunk_key(pos))?;
            let Some(record) = record else {
                if self.deltas_of(pos).next().is_none() {
                    return Ok(None);
                }
                return Err(StoreError::corrupt(
                    "deltas without a chunk record",
                    show_pos(pos),
                ));
            };
            let (version, chunk) = decode_chunk_value(pos, &record, self.generator())?;
            let replayed = replay(pos, version, chunk, self.deltas_of(pos), usize::MAX);
            let moved = self.record_version(pos)? != Some(version);
            if let Some(r) = settle(replayed, moved)? {
                return Ok(Some((r.version, r.chunk)));
            }
        }
        Err(StoreError::corrupt(
            "delta chain does not start at the chunk record's version",
            show_pos(pos),
        ))
    }

    /// Refuses a batch whose changes do not start at each chunk's newest
    /// stored version: a delta from `from` while a stored delta goes past
    /// it, or a chunk written whole at `lowest` while a stored delta
    /// reaches it. The transaction checks the record and the delta ending
    /// at `from` (it cannot scan); only a scan finds newer deltas. Run
    /// before the transaction: the engine's one commit thread is the only
    /// writer of deltas (a fold only removes those a record holds).
    pub(super) fn check_heads(
        &self,
        whole: impl Iterator<Item = (ChunkPos, u64)>,
        deltas: impl Iterator<Item = (ChunkPos, u64)>,
    ) -> Result<(), StoreError> {
        let past = |pos: ChunkPos, version: u64| -> Result<Option<u64>, StoreError> {
            let from = delta_key(pos, version.saturating_add(1));
            let to = delta_key(pos, u64::MAX);
            match self.deltas.range(from..=to).keys().next_back() {
                Some(k) => {
                    let k = k?;
                    let (_, v) = delta_from_key(&k)
                        .ok_or_else(|| StoreError::corrupt("delta key", show_raw(&k)))?;
                    Ok(Some(v))
                }
                None => Ok(None),
            }
        };
        for (pos, lowest) in whole {
            if let Some(v) = past(pos, lowest.saturating_sub(1))? {
                return Err(StoreError::batch(format!(
                    "{} is stored at version {v}, the batch moves it to {lowest}",
                    show_pos(pos)
                )));
            }
        }
        for (pos, from) in deltas {
            if let Some(v) = past(pos, from)? {
                return Err(StoreError::batch(format!(
                    "{} is stored at version {v}, the batch's delta starts at {from}",
                    show_pos(pos)
                )));
            }
        }
        Ok(())
    }

    /// Up to `max_chunks` chunks with deltas, in key order, after `after`.
    pub(super) fn chunks_with_deltas(
        &self,
        after: Option<ChunkPos>,
        max_chunks: usize,
    ) -> Result<Vec<ChunkPos>, StoreError> {
        let mut last: Option<[u8; CHUNK_KEY_LEN]> = None;
        let mut todo = Vec::new();
        // Past every delta of `after`.
        let start = match after {
            Some(pos) => std::ops::Bound::Excluded(delta_key(pos, u64::MAX)),
            None => std::ops::Bound::Unbounded,
        };
        let keys = self
            .deltas
            .range::<[u8; DELTA_KEY_LEN], _>((start, std::ops::Bound::Unbounded))
            .keys();
        for k in keys {
            let k = k?;
            let (pos, _) =
                delta_from_key(&k).ok_or_else(|| StoreError::corrupt("delta key", show_raw(&k)))?;
            if last != Some(chunk_key(pos)) {
                if todo.len() >= max_chunks {
                    break;
                }
                last = Some(chunk_key(pos));
                todo.push(pos);
            }
        }
        Ok(todo)
    }

    /// Folds the deltas of `chunks` into their records. Safe beside
    /// commits: each chunk's record and the deltas folded into it change in
    /// one transaction, and a commit's deltas past them stay.
    ///
    /// No flush: sled's flush holds its global lock, which every commit's
    /// transaction must take, while it waits for the disk. The next group
    /// commit's flush and fsync write the folds with the commit's own
    /// records; until then a crash keeps the unfolded deltas, which reads
    /// replay to the same states.
    pub(super) fn fold_chunks(&self, chunks: &[ChunkPos]) -> Result<CheckpointStats, StoreError> {
        let mut stats = CheckpointStats::default();
        for &pos in chunks {
            match self.fold_one(pos) {
                Ok(Some((folded, bytes))) => {
                    stats.chunks += 1;
                    stats.deltas += folded;
                    stats.bytes_written += bytes;
                }
                Ok(None) => {}
                // One unreadable chunk must not stop every later pass.
                Err(e) if e.is_chunk_local() => {
                    tracing::error!(error = %e, "checkpoint left a chunk unfolded");
                    stats.skipped += 1;
                }
                Err(e) => return Err(e),
            }
        }
        Ok(stats)
    }

    /// Folds `pos`'s deltas into its record: (deltas removed, bytes written),
    /// or `None` when it has none or a concurrent fold got there first.
    fn fold_one(&self, pos: ChunkPos) -> Result<Option<(u64, u64)>, StoreError> {
        let key = chunk_key(pos);
        let Some(record) = self.chunks.get(key)? else {
            return Err(StoreError::corrupt(
                "deltas without a chunk record",
                show_pos(pos),
            ));
        };
        let (base, chunk) = decode_chunk_value(pos, &record, self.generator())?;
        let replayed = replay(pos, base, chunk, self.deltas_of(pos), MAX_FOLD_DELTAS);
        let moved = self.chunks.get(key)?.as_ref() != Some(&record);
        let Some(Replayed {
            version: head,
            chunk: state,
            read,
            ..
        }) = settle(replayed, moved)?
        else {
            // Folded meanwhile (the record moved), or a chain that does not
            // start at the record: damage, reported and counted as skipped.
            if !moved {
                return Err(StoreError::corrupt(
                    format!("deltas do not start at the record's version {base}"),
                    show_pos(pos),
                ));
            }
            return Ok(None);
        };
        if read.is_empty() {
            // Folded since it was listed.
            return Ok(None);
        }
        let value = encode_chunk_value(head, &state);
        let folded: Vec<_> = read.iter().map(|&to| delta_key(pos, to)).collect();
        let result = (&self.chunks, &self.deltas).transaction(|(tchunks, tdeltas)| {
            // Only over the record this fold started from.
            let now = tchunks.get(key)?;
            let same = now
                .as_ref()
                .and_then(|v| split_chunk_value(pos, v).ok())
                .is_some_and(|(v, _)| v == base);
            if !same {
                return Err(ConflictableTransactionError::Abort(()));
            }
            tchunks.insert(&key[..], value.as_slice())?;
            for k in &folded {
                tdeltas.remove(&k[..])?;
            }
            Ok(())
        });
        match result {
            Ok(()) => Ok(Some((folded.len() as u64, value.len() as u64))),
            Err(TransactionError::Abort(())) => Ok(None),
            Err(TransactionError::Storage(e)) => Err(e.into()),
        }
    }
}

/// Deltas one fold writes into a record at most: a chunk whose deltas
/// piled up (checkpoints off, a crash before the shutdown's fold) is folded
/// over several passes, each transaction and its list of keys bounded.
pub(super) const MAX_FOLD_DELTAS: usize = 4096;

/// A chunk's state after [`replay`].
#[derive(Debug)]
pub(super) struct Replayed {
    pub version: u64,
    pub chunk: Chunk,
    /// The versions of the deltas read, all at or below `version`: those a
    /// fold to `version` removes (stale ones below the record included).
    pub read: Vec<u64>,
}

/// Applies the deltas past `version` to `chunk` in order, as `deltas`
/// yields them (the store's scan, in version order), as far as the first
/// `limit` of them (stale ones below `version` included). `Err(Moved)` when they do not start at `version` (a fold ran
/// between the reads). A chain that breaks further on is damage, unless
/// the reads were torn ([`settle`]). Only a fold (a bounded `limit`) keeps
/// the versions read.
pub(super) fn replay(
    pos: ChunkPos,
    version: u64,
    chunk: Chunk,
    deltas: impl Iterator<Item = Result<ChunkDelta, StoreError>>,
    limit: usize,
) -> Result<Result<Replayed, Moved>, StoreError> {
    let keep = limit != usize::MAX;
    let mut out = Replayed {
        version,
        chunk,
        read: Vec::new(),
    };
    // The last applied delta's target version and hash.
    let mut prev: Option<(u64, u64)> = None;
    // Stale ones count too: a fold's keys and transaction stay bounded.
    for d in deltas.take(limit) {
        let d = d?;
        if d.to_version <= version {
            // Left behind by a whole-chunk write: a fold removes it.
            if keep {
                out.read.push(d.to_version);
            }
            continue;
        }
        let next = match prev {
            None if d.from_version != version => return Ok(Err(Moved)),
            None => d.apply(&out.chunk),
            // The previous delta's target hash was checked: the chain must
            // continue from it.
            Some((to, hash)) if to == d.from_version && hash == d.base_hash => {
                d.apply_to_checked_base(&out.chunk)
            }
            Some((to, _)) => {
                return Err(StoreError::corrupt(
                    format!(
                        "delta chain breaks after version {to} (next goes from {})",
                        d.from_version
                    ),
                    show_pos(pos),
                ))
            }
        };
        out.chunk = next.map_err(|e| {
            StoreError::corrupt(
                format!("delta to version {} does not apply ({e})", d.to_version),
                show_pos(pos),
            )
        })?;
        out.version = d.to_version;
        prev = Some((d.to_version, d.target_hash));
        if keep {
            out.read.push(d.to_version);
        }
    }
    Ok(Ok(out))
}

/// What a read made of [`replay`]'s answer (`None`: read again), given
/// whether the record `moved` since it was read. The deltas' scan is no
/// snapshot: a fold that commits during it, and a commit after that, can
/// show it deltas from both sides (the record's next delta, then one the
/// fold's record continues from), a chain that seems to break. So any
/// answer from a moved record is read again, and only a chain read
/// around a record that stayed put is damage.
pub(super) fn settle(
    replayed: Result<Result<Replayed, Moved>, StoreError>,
    moved: bool,
) -> Result<Option<Replayed>, StoreError> {
    match replayed {
        _ if moved => Ok(None),
        Ok(Ok(state)) => Ok(Some(state)),
        Ok(Err(Moved)) => Ok(None),
        Err(e) => Err(e),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::material::ids;
    use strata_terrain::Voxel;

    fn chunk(density: u8) -> Chunk {
        Chunk::uniform(Voxel::new(density, ids::STONE))
    }

    #[test]
    fn a_chain_torn_by_a_fold_is_read_again_and_one_around_a_still_record_is_damage() {
        let pos = ChunkPos::new(1, 2, 3);
        let (v5, v6, v7, v8) = (chunk(10), chunk(20), chunk(30), chunk(40));
        // The scan saw 5 -> 6 before a fold moved the record to 7 and
        // removed it, then the 7 -> 8 a commit added after the fold.
        let torn = [
            ChunkDelta::encode(pos, 5, 6, &v5, &v6).unwrap(),
            ChunkDelta::encode(pos, 7, 8, &v7, &v8).unwrap(),
        ];
        fn scan(d: &[ChunkDelta]) -> impl Iterator<Item = Result<ChunkDelta, StoreError>> + '_ {
            d.iter().cloned().map(Ok)
        }
        assert!(
            settle(replay(pos, 5, v5.clone(), scan(&torn), usize::MAX), true)
                .unwrap()
                .is_none()
        );
        let err = settle(replay(pos, 5, v5.clone(), scan(&torn), usize::MAX), false).unwrap_err();
        assert!(err.to_string().contains("delta chain breaks"), "{err}");
        // A whole chain from a record that stayed put is the state.
        let whole = [ChunkDelta::encode(pos, 5, 6, &v5, &v6).unwrap()];
        let r = settle(replay(pos, 5, v5, scan(&whole), usize::MAX), false)
            .unwrap()
            .unwrap();
        assert_eq!((r.version, r.chunk), (6, v6));
    }

    #[test]
    fn a_bounded_replay_stops_after_its_limit_and_lists_what_it_read() {
        let pos = ChunkPos::new(1, 2, 3);
        let states: Vec<Chunk> = (0..6).map(|i| chunk(10 * i + 10)).collect();
        // A stale delta (to 2, below the record at 3), then 3 -> 4 -> 5 -> 6.
        let mut deltas = vec![ChunkDelta::encode(pos, 1, 2, &states[0], &states[1]).unwrap()];
        for v in 3..6 {
            let (a, b) = (&states[v - 3], &states[v - 2]);
            deltas.push(ChunkDelta::encode(pos, v as u64, v as u64 + 1, a, b).unwrap());
        }
        let scan = || deltas.clone().into_iter().map(Ok);
        let r = settle(replay(pos, 3, states[0].clone(), scan(), 3), false)
            .unwrap()
            .unwrap();
        assert_eq!(
            (r.version, &r.chunk, r.read),
            (5, &states[2], vec![2, 4, 5])
        );
        // The stale one counts: a limit of 1 reads only it.
        let r = settle(replay(pos, 3, states[0].clone(), scan(), 1), false)
            .unwrap()
            .unwrap();
        assert_eq!((r.version, r.read), (3, vec![2]));
        let r = settle(replay(pos, 3, states[0].clone(), scan(), usize::MAX), false)
            .unwrap()
            .unwrap();
        assert_eq!((r.version, &r.chunk), (6, &states[3]));
        assert!(r.read.is_empty(), "a read keeps no list");
    }
}
