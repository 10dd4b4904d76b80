//! [`ChunkStore`] on sled 0.34.
//!
//! Crash safety: a commit is one sled transaction across the `meta`,
//! `chunks`, `log` and `deltas` trees. sled writes a transaction's updates to its log
//! as one batch and on recovery replays all of it or none of it, so after a
//! crash the store holds exactly the batches before some point: never a log
//! entry beyond `last_seq`, never a chunk without its log entry. sled's
//! `flush` is not a durability barrier on Linux (`sync_file_range`), and
//! its own `sync_all` runs only every `flush_every_ms`; so every write
//! method flushes and then fsyncs through [`DiskSync`] before returning:
//! data from a completed write survives a power cut, and the caller
//! acknowledges nothing before that.

use std::collections::BTreeSet;
use std::ops::RangeInclusive;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use sled::transaction::{ConflictableTransactionError, TransactionError, Transactional};
use strata_terrain::delta::ChunkDelta;
use strata_terrain::world::ChunkGenerator;
use strata_terrain::{Chunk, ChunkPos};

use super::batch;
use super::check::{CheckReport, Checker};
use super::config::StoreConfig;
use super::disk_sync::DiskSync;
use super::error::StoreError;
use super::flush_watch::FlushWatch;
use super::keys::{chunk_key, chunk_pos_from_key, delta_key, seq_key, show_pos, show_raw};
use super::log_pages::{encode_page, page_key, record_entries, search_key, BadRecord};
use super::positions::{decode_position, encode_feet, TREE_PLAYER_TIMES};
use super::record::{
    decode_last_seq, decode_log_entry, decode_meta, encode_chunk_value, encode_delta,
    encode_log_record, encode_meta, generated_chunk_value, is_generated, split_chunk_value,
};
use super::rules::{check_blob, check_blob_name, check_new_meta, compare_meta};
use super::types::{
    CheckpointStats, CommitBatch, CommitStats, LogEntry, RawChunk, StoredChunk, StoredPosition,
    WorldMeta, STORE_FORMAT_VERSION,
};
use super::{ChunkStore, StoreIter};

/// Tree of world metadata.
pub const TREE_META: &str = "meta";
/// Tree of modified chunks.
pub const TREE_CHUNKS: &str = "chunks";
/// Tree of the edit log.
pub const TREE_LOG: &str = "log";
/// Tree of named blobs.
pub const TREE_BLOBS: &str = "blobs";
/// Tree of chunk deltas committed since each chunk's record was written.
pub const TREE_DELTAS: &str = "deltas";
/// Older store formats a build opens and upgrades in place, their records
/// being valid as they are: 1 had no `deltas` tree, 2 stored one delta per
/// change (a special case of 3's deltas across several changes), 3 had no
/// "generated" chunk records.
const UPGRADABLE_FORMATS: [u32; 3] = [1, 2, 3];

/// How often [`ChunkStore::settle_reads`] looks whether a commit's fsync
/// finished (a group commit takes about a millisecond).
const SETTLE_POLL: std::time::Duration = std::time::Duration::from_millis(1);
/// Tree of players' last positions: name → x, y, z (fixed point, i32 BE).
pub const TREE_PLAYERS: &str = "players";
/// Key of the metadata record in [`TREE_META`].
pub const META_WORLD: &[u8] = b"world";
/// Key of `last_seq` in [`TREE_META`].
pub const META_LAST_SEQ: &[u8] = b"last_seq";
/// Key of the log base in [`TREE_META`] (only in stores restored from a
/// snapshot): the snapshot's seq. The log starts after it, and chunks
/// stored at restore have no log entry.
pub const META_LOG_BASE: &[u8] = b"log_base";
/// Longest generator parameter text accepted.
pub const MAX_GENERATOR_PARAMS_BYTES: usize = 64 * 1024;
/// Longest blob name.
pub const MAX_BLOB_NAME_BYTES: usize = 256;
/// Largest blob.
pub const MAX_BLOB_BYTES: usize = 16 * 1024 * 1024;

/// The sled-backed store. Cheap to share by reference across threads.
#[derive(Debug)]
pub struct SledStore {
    pub(super) db: sled::Db,
    pub(super) meta: sled::Tree,
    pub(super) chunks: sled::Tree,
    pub(super) log: sled::Tree,
    pub(super) blobs: sled::Tree,
    pub(super) deltas: sled::Tree,
    players: sled::Tree,
    player_times: sled::Tree,
    disk: DiskSync,
    /// Dropped after `db`: its thread holds the last handle.
    watch: FlushWatch,
    /// The world's generator, once attached: chunks are then first stored
    /// as a "generated" record and deltas (`CommitBatch::generated`).
    pub(super) generator: std::sync::OnceLock<Arc<dyn ChunkGenerator>>,
    /// Where big batches' chunks are encoded.
    encode: super::EncodePool,
    /// The highest `last_seq` known on disk: sled shows a transaction's
    /// writes before its flush, and `last_seq` reads no further than this,
    /// so no reader (the console) sees an edit that is not durable yet.
    durable_seq: std::sync::atomic::AtomicU64,
    /// The world's lock, when opened through `open_store`: let go last.
    held: Option<super::WorldLock>,
}

impl SledStore {
    /// Makes a blob change durable (`written`: the bytes this call wrote,
    /// `None` for a delete); when that fails, undoes it ([`Self::undo_blob`]).
    fn flush_or_undo(
        &self,
        name: &str,
        written: Option<&[u8]>,
        old: Option<sled::IVec>,
    ) -> Result<(), StoreError> {
        let Err(e) = self.flush() else {
            return Ok(());
        };
        match self.undo_blob(name, written, old) {
            // The undo made durable too: sled's own flusher may have
            // written the failed write by now, and a restart would find it.
            Ok(()) => {
                if let Err(f) = self.flush() {
                    tracing::error!(error = %f, blob = name, "flushing a blob put back after a failed flush failed: after a restart the failed write may be found");
                }
            }
            Err(u) => {
                tracing::error!(error = %u, blob = name, "putting a blob back after a failed flush failed");
            }
        }
        Err(e)
    }

    /// Puts `old` back (the blob as it was: `None`, none) where the blob
    /// still holds what the failed write put there (`written`), so a write
    /// reported failed is not read afterwards. A write of another caller
    /// since (which read this one's, and may have been made durable and
    /// answered meanwhile) is left alone: undoing over it would lose it.
    fn undo_blob(
        &self,
        name: &str,
        written: Option<&[u8]>,
        old: Option<sled::IVec>,
    ) -> Result<(), StoreError> {
        let swapped = self.blobs.compare_and_swap(name.as_bytes(), written, old)?;
        if swapped.is_err() {
            tracing::warn!(
                blob = name,
                "a blob write whose flush failed was overwritten since; the newer write stays"
            );
        }
        Ok(())
    }

    /// Opens (or creates) the store in `dir` with the default config.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        Self::open_with(dir, &StoreConfig::default())
    }

    /// This store, keeping `lock` until it is dropped.
    pub fn holding(mut self, lock: super::WorldLock) -> Self {
        self.held = Some(lock);
        self
    }

    /// Opens (or creates) the store in `dir`. Refuses a store written by an
    /// unknown format version.
    pub fn open_with(dir: &Path, config: &StoreConfig) -> Result<Self, StoreError> {
        let segment = persisted_segment_size(dir).unwrap_or(config.segment_size_bytes);
        let cfg = sled::Config::new()
            .path(dir)
            .cache_capacity(config.cache_capacity_bytes)
            .flush_every_ms(config.flush_period())
            .segment_size(segment);
        let db = open_when_unlocked(|| cfg.open())?;
        let store = Self {
            meta: db.open_tree(TREE_META)?,
            chunks: db.open_tree(TREE_CHUNKS)?,
            log: db.open_tree(TREE_LOG)?,
            blobs: db.open_tree(TREE_BLOBS)?,
            deltas: db.open_tree(TREE_DELTAS)?,
            players: db.open_tree(TREE_PLAYERS)?,
            player_times: db.open_tree(TREE_PLAYER_TIMES)?,
            disk: DiskSync::open(dir)?,
            watch: FlushWatch::spawn(db.clone())?,
            db,
            generator: std::sync::OnceLock::new(),
            encode: Default::default(),
            durable_seq: std::sync::atomic::AtomicU64::new(u64::MAX),
            held: None,
        };
        // `DiskSync::open` synced what sled recovered: it is on disk. An
        // unreadable seq clamps nothing (`last_seq` reports it).
        if let Ok(seq) = store.stored_last_seq() {
            store.durable_seq.store(seq, Ordering::Relaxed);
        }
        // Only a readable record of another format stops the open: a
        // corrupt one must still open so `check` can report it (and
        // `load_meta` returns the error to anyone else).
        let world = store.meta.get(META_WORLD)?;
        if let Some(Ok(mut m)) = world.map(|w| decode_meta(&w, 0)) {
            if UPGRADABLE_FORMATS.contains(&m.format_version) {
                // Nothing to convert; an older build now refuses the store.
                m.format_version = STORE_FORMAT_VERSION;
                store.meta.insert(META_WORLD, encode_meta(&m)?)?;
                store.flush()?;
            } else if m.format_version != STORE_FORMAT_VERSION {
                return Err(StoreError::UnsupportedFormat {
                    found: m.format_version,
                    supported: STORE_FORMAT_VERSION,
                });
            }
        }
        Ok(store)
    }

    /// Makes every write so far durable: sled's flush, then the fsyncs it
    /// leaves out.
    pub(super) fn flush(&self) -> Result<(), StoreError> {
        let seq = self.stored_last_seq();
        self.watch.flush(&self.db)?;
        self.disk.sync()?;
        if let Ok(seq) = seq {
            self.durable_seq.fetch_max(seq, Ordering::Relaxed);
        }
        Ok(())
    }

    /// `last_seq` as sled shows it, durable or not.
    fn stored_last_seq(&self) -> Result<u64, StoreError> {
        match self.meta.get(META_LAST_SEQ)? {
            Some(v) => decode_last_seq(&v),
            None => Ok(0),
        }
    }
}

/// [`record_entries`] of a log record, or why the store is corrupt.
fn log_record_entries<'a>(key: &[u8], value: &'a [u8]) -> Result<Vec<(u64, &'a [u8])>, StoreError> {
    record_entries(key, value).map_err(|e| match e {
        BadRecord::Key => StoreError::corrupt("log key", show_raw(key)),
        BadRecord::Page { first, reason } => {
            StoreError::corrupt(format!("log page ({reason})"), format!("seq {first}"))
        }
    })
}

/// A batch chunk ready to write.
struct EncodedChunk {
    key: [u8; 12],
    pos: ChunkPos,
    /// The lowest version the batch gives it: the stored one must be below.
    lowest: u64,
    value: Vec<u8>,
}

/// A chunk record's position, version and undecoded body.
fn split_chunk_entry<'v>(
    key: &[u8],
    value: &'v [u8],
) -> Result<(ChunkPos, u64, &'v [u8]), StoreError> {
    let pos =
        chunk_pos_from_key(key).ok_or_else(|| StoreError::corrupt("chunk key", show_raw(key)))?;
    let (version, body) = split_chunk_value(pos, value)?;
    Ok((pos, version, body))
}

fn abort(e: StoreError) -> ConflictableTransactionError<StoreError> {
    ConflictableTransactionError::Abort(e)
}

impl ChunkStore for SledStore {
    fn load_meta(&self) -> Result<Option<WorldMeta>, StoreError> {
        let Some(world) = self.meta.get(META_WORLD)? else {
            return Ok(None);
        };
        let last_seq = self.last_seq()?;
        decode_meta(&world, last_seq).map(Some)
    }

    fn init_meta(&self, meta: &WorldMeta) -> Result<WorldMeta, StoreError> {
        check_new_meta(meta)?;
        if let Some(stored) = self.load_meta()? {
            compare_meta(&stored, meta)?;
            return Ok(stored);
        }
        // Records without metadata: a restore cut short, not a new world.
        for (name, tree) in [
            ("chunks", &self.chunks),
            ("deltas", &self.deltas),
            ("log", &self.log),
        ] {
            if !tree.is_empty() {
                return Err(StoreError::InvalidMeta {
                    reason: format!(
                        "the store has no world metadata but its {name} tree is not empty \
                         (an interrupted restore?); restore it again with --force"
                    ),
                });
            }
        }
        let record = encode_meta(meta)?;
        // Both keys in one batch: a crash leaves both or neither.
        let mut b = sled::Batch::default();
        b.insert(META_WORLD, record);
        b.insert(META_LAST_SEQ, &0u64.to_be_bytes()[..]);
        self.meta.apply_batch(b)?;
        self.flush()?;
        Ok(meta.clone())
    }

    fn last_seq(&self) -> Result<u64, StoreError> {
        let stored = self.stored_last_seq()?;
        Ok(stored.min(self.durable_seq.load(Ordering::Relaxed)))
    }

    /// Every commit's writes and its `last_seq` become visible together
    /// (one transaction), so `last_seq` as sled shows it after the reads
    /// covers all they saw; a commit's fsync raises `durable_seq` to it.
    fn settle_reads(&self, within: std::time::Duration) -> Result<(), StoreError> {
        let seen = self.stored_last_seq()?;
        let started = Instant::now();
        while self.durable_seq.load(Ordering::Relaxed) < seen {
            if started.elapsed() >= within {
                return Err(StoreError::NotDurable {
                    seq: seen,
                    waited_ms: within.as_millis() as u64,
                });
            }
            std::thread::sleep(SETTLE_POLL);
        }
        Ok(())
    }

    fn load_chunk(&self, pos: ChunkPos) -> Result<Option<StoredChunk>, StoreError> {
        Ok(self
            .latest(pos)?
            .map(|(version, chunk)| StoredChunk { chunk, version }))
    }

    fn commit_batch(&self, b: &CommitBatch) -> Result<CommitStats, StoreError> {
        let lowest = batch::validate(b)?;
        let Some(first_seq) = b.entries.first().map(|e| e.seq) else {
            return Ok(CommitStats::default());
        };
        let started = Instant::now();
        // Encode outside the transaction: its closure may run again on conflict.
        let mut records = Vec::with_capacity(b.entries.len());
        for e in &b.entries {
            records.push(encode_log_record(e)?);
        }
        // One log record a commit, whatever its edits (`log_pages.rs`).
        let page = (page_key(first_seq, b.last_seq), encode_page(&records));
        // With a generator, a new chunk is a "generated" record and the
        // delta of its first changes; its whole state waits for a fold.
        let from_generated: Vec<&ChunkDelta> = match self.generator.get() {
            Some(_) => b.generated.iter().collect(),
            None => Vec::new(),
        };
        let as_delta: BTreeSet<ChunkPos> = from_generated.iter().map(|d| d.pos).collect();
        let mut firsts = Vec::with_capacity(from_generated.len());
        for d in &from_generated {
            firsts.push((
                chunk_key(d.pos),
                delta_key(d.pos, d.to_version),
                encode_delta(d)?,
            ));
        }
        // zstd dominates a big batch's cost; chunks compress independently.
        let encode = |(pos, version, chunk): &(ChunkPos, u64, Arc<Chunk>)| EncodedChunk {
            key: chunk_key(*pos),
            pos: *pos,
            lowest: lowest.get(pos).copied().unwrap_or(*version),
            value: encode_chunk_value(*version, chunk),
        };
        let whole: Vec<_> = b
            .chunks
            .iter()
            .filter(|c| !as_delta.contains(&c.0))
            .collect();
        let chunks: Vec<EncodedChunk> = self.encode.map(&whole, |c| encode(c));
        let mut deltas = Vec::with_capacity(b.deltas.len());
        for d in &b.deltas {
            deltas.push((
                d.pos,
                d.from_version,
                delta_key(d.pos, d.to_version),
                encode_delta(d)?,
            ));
        }
        let bytes_written = page.1.len() as u64
            + chunks.iter().map(|c| c.value.len() as u64).sum::<u64>()
            + firsts
                .iter()
                .map(|f| (f.2.len() + generated_chunk_value().len()) as u64)
                .sum::<u64>()
            + deltas.iter().map(|d| d.3.len() as u64).sum::<u64>();

        // Past the transaction, which cannot scan: one committer a store.
        self.check_heads(
            chunks.iter().map(|c| (c.pos, c.lowest)),
            deltas.iter().map(|d| (d.0, d.1)),
        )?;
        let encode = started.elapsed();
        let trees = (&self.meta, &self.chunks, &self.log, &self.deltas);
        let result = trees.transaction(|(meta, tchunks, log, tdeltas)| {
            if meta.get(META_WORLD)?.is_none() {
                return Err(abort(StoreError::NoMeta));
            }
            let last = match meta.get(META_LAST_SEQ)? {
                Some(v) => decode_last_seq(&v).map_err(abort)?,
                None => 0,
            };
            if Some(first_seq) != last.checked_add(1) {
                return Err(abort(StoreError::batch(format!(
                    "first seq {first_seq} does not follow the stored last_seq {last}"
                ))));
            }
            for c in &chunks {
                if let Some(old) = tchunks.insert(&c.key[..], c.value.as_slice())? {
                    let (old_version, _) = split_chunk_value(c.pos, &old).map_err(abort)?;
                    if old_version >= c.lowest {
                        return Err(abort(StoreError::batch(format!(
                            "{} is stored at version {old_version}, the batch moves it to {}",
                            show_pos(c.pos),
                            c.lowest
                        ))));
                    }
                }
            }
            for (key, dkey, value) in &firsts {
                if tchunks.insert(&key[..], generated_chunk_value())?.is_some()
                    || tdeltas.insert(&dkey[..], value.as_slice())?.is_some()
                {
                    return Err(abort(StoreError::batch(format!(
                        "{} is stored already, the batch stores it from generated",
                        show_raw(key)
                    ))));
                }
            }
            for (pos, from, key, value) in &deltas {
                // The chain goes on from the newest stored version: the
                // previous delta's, or else the record's.
                let follows = tdeltas.get(delta_key(*pos, *from))?.is_some()
                    || match tchunks.get(chunk_key(*pos))? {
                        Some(v) => split_chunk_value(*pos, &v).map_err(abort)?.0 == *from,
                        None => false,
                    };
                if !follows || tdeltas.insert(&key[..], value.as_slice())?.is_some() {
                    return Err(abort(StoreError::batch(format!(
                        "{} is not stored at version {from}, the batch's delta starts there",
                        show_pos(*pos)
                    ))));
                }
            }
            if log.insert(&page.0[..], page.1.as_slice())?.is_some() {
                return Err(abort(StoreError::corrupt(
                    "log record beyond last_seq",
                    show_raw(&page.0),
                )));
            }
            meta.insert(META_LAST_SEQ, &b.last_seq.to_be_bytes()[..])?;
            Ok(())
        });
        result.map_err(|e| match e {
            TransactionError::Abort(e) => e,
            TransactionError::Storage(e) => StoreError::Sled(e),
        })?;
        let apply = started.elapsed() - encode;
        let flushing = Instant::now();
        self.watch.flush(&self.db)?;
        let syncing = Instant::now();
        self.disk.sync()?;
        self.durable_seq.fetch_max(b.last_seq, Ordering::Relaxed);
        Ok(CommitStats {
            bytes_written,
            encode,
            apply,
            flush: syncing - flushing,
            fsync: syncing.elapsed(),
        })
    }

    fn log_entry(&self, seq: u64) -> Result<Option<LogEntry>, StoreError> {
        let Some((k, v)) = self.log.range(..=search_key(seq)).next_back().transpose()? else {
            return Ok(None);
        };
        for (s, record) in log_record_entries(&k, &v)? {
            if s == seq {
                return decode_log_entry(seq, record).map(Some);
            }
        }
        Ok(None)
    }

    fn log_base(&self) -> Result<u64, StoreError> {
        self.meta
            .get(META_LOG_BASE)?
            .map_or(Ok(0), |v| decode_last_seq(&v))
    }

    fn prune_log(&self, before_ms: u64, max: usize) -> Result<u64, StoreError> {
        // Whole pages (a commit's entries), from the first: a page with an
        // entry too new, or one past `max`, ends the run.
        let mut pages = Vec::new();
        let (mut removed, mut base) = (0u64, 0u64);
        for r in self.log.iter() {
            let (k, v) = r?;
            let entries = log_record_entries(&k, &v)?;
            let n = entries.len() as u64;
            if removed > 0 && removed + n > max as u64 {
                break;
            }
            let mut old = true;
            for (seq, record) in &entries {
                old &= decode_log_entry(*seq, record)?.time_ms < before_ms;
            }
            let Some(&(last, _)) = entries.last().filter(|_| old) else {
                break;
            };
            pages.push(k);
            (removed, base) = (removed + n, last);
        }
        if pages.is_empty() {
            return Ok(0);
        }
        (&self.log, &self.meta)
            .transaction(|(log, meta)| {
                for k in &pages {
                    log.remove(k)?;
                }
                let was = match meta.get(META_LOG_BASE)? {
                    Some(v) => decode_last_seq(&v).map_err(ConflictableTransactionError::Abort)?,
                    None => 0,
                };
                meta.insert(META_LOG_BASE, &base.max(was).to_be_bytes()[..])?;
                Ok(())
            })
            .map_err(|e| match e {
                TransactionError::Abort(e) => e,
                TransactionError::Storage(e) => e.into(),
            })?;
        Ok(removed)
    }

    fn edit_log(&self, seqs: RangeInclusive<u64>) -> StoreIter<'_, LogEntry> {
        if seqs.is_empty() {
            return Box::new(std::iter::empty());
        }
        let (lo, hi) = (*seqs.start(), *seqs.end());
        // From the record holding `lo` (a page may start below it).
        let start = match self.log.range(..=search_key(lo)).keys().next_back() {
            Some(Ok(k)) => k.to_vec(),
            Some(Err(e)) => return Box::new(std::iter::once(Err(e.into()))),
            None => seq_key(lo).to_vec(),
        };
        let records = self.log.range(start..=search_key(hi).to_vec());
        Box::new(records.flat_map(move |r| {
            let entries = r.map_err(StoreError::from).and_then(|(k, v)| {
                log_record_entries(&k, &v)?
                    .into_iter()
                    .filter(|(s, _)| (lo..=hi).contains(s))
                    .map(|(s, record)| decode_log_entry(s, record))
                    .collect::<Result<Vec<_>, _>>()
            });
            match entries {
                Ok(v) => v.into_iter().map(Ok).collect::<Vec<_>>(),
                Err(e) => vec![Err(e)],
            }
        }))
    }

    fn raw_chunk(&self, pos: ChunkPos) -> Result<Option<RawChunk>, StoreError> {
        let Some(v) = self.chunks.get(chunk_key(pos))? else {
            return Ok(None);
        };
        self.raw_latest(pos, &v).map(Some)
    }

    fn modified_chunks(&self) -> StoreIter<'_, (ChunkPos, u64)> {
        // Key and version prefix only: bodies are neither copied nor decoded.
        Box::new(self.chunks.iter().map(|r| {
            let (k, v) = r?;
            let (pos, version, _) = split_chunk_entry(&k, &v)?;
            Ok((pos, self.head_version(pos, version)?))
        }))
    }

    fn raw_chunks(&self) -> StoreIter<'_, RawChunk> {
        Box::new(self.chunks.iter().map(|r| {
            let (k, v) = r?;
            let (pos, _, _) = split_chunk_entry(&k, &v)?;
            self.raw_latest(pos, &v)
        }))
    }

    fn chunk_count(&self) -> Result<u64, StoreError> {
        Ok(self.chunks.len() as u64)
    }

    fn delta_count(&self) -> Result<u64, StoreError> {
        Ok(self.deltas.len() as u64)
    }

    fn size_on_disk(&self) -> Result<u64, StoreError> {
        Ok(self.db.size_on_disk()?)
    }

    fn get_blob(&self, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        check_blob_name(name)?;
        Ok(self.blobs.get(name.as_bytes())?.map(|v| v.to_vec()))
    }

    fn put_blob(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        check_blob(name, bytes)?;
        let old = self.blobs.insert(name.as_bytes(), bytes)?;
        self.flush_or_undo(name, Some(bytes), old)
    }

    fn swap_blob(
        &self,
        name: &str,
        expected: Option<&[u8]>,
        bytes: &[u8],
    ) -> Result<bool, StoreError> {
        check_blob(name, bytes)?;
        let swapped = self
            .blobs
            .compare_and_swap(name.as_bytes(), expected, Some(bytes))?
            .is_ok();
        if swapped {
            self.flush_or_undo(name, Some(bytes), expected.map(sled::IVec::from))?;
        }
        Ok(swapped)
    }

    fn delete_blob(&self, name: &str) -> Result<bool, StoreError> {
        check_blob_name(name)?;
        let old = self.blobs.remove(name.as_bytes())?;
        let existed = old.is_some();
        self.flush_or_undo(name, None, old)?;
        Ok(existed)
    }

    fn save_positions(&self, positions: &[(String, StoredPosition)]) -> Result<(), StoreError> {
        // The feet and the time together: a time never belongs to other feet.
        let trees = (&self.players, &self.player_times);
        let saved = trees.transaction(|(feet, times)| {
            for (player, p) in positions {
                feet.insert(player.as_bytes(), &encode_feet(p)[..])?;
                times.insert(player.as_bytes(), &p.known_ms.to_be_bytes()[..])?;
            }
            Ok::<(), ConflictableTransactionError<StoreError>>(())
        });
        saved.map_err(|e| match e {
            TransactionError::Abort(e) => e,
            TransactionError::Storage(e) => StoreError::Sled(e),
        })?;
        self.flush()
    }

    fn player_positions(&self) -> StoreIter<'_, (String, StoredPosition)> {
        Box::new(self.players.iter().keys().filter_map(|k| {
            let read = || {
                let k = k?;
                let name = std::str::from_utf8(&k)
                    .map_err(|_| StoreError::corrupt("player name", show_raw(&k)))?;
                // Gone since the walk passed it: nothing to report.
                Ok(self.position_at(&k)?.map(|p| (name.to_string(), p)))
            };
            read().transpose()
        }))
    }

    fn player_position(&self, player: &str) -> Result<Option<StoredPosition>, StoreError> {
        self.position_at(player.as_bytes())
    }

    fn chunks_with_deltas(
        &self,
        after: Option<ChunkPos>,
        max_chunks: usize,
    ) -> Result<Vec<ChunkPos>, StoreError> {
        SledStore::chunks_with_deltas(self, after, max_chunks)
    }

    fn fold_chunks(&self, chunks: &[ChunkPos]) -> Result<CheckpointStats, StoreError> {
        SledStore::fold_chunks(self, chunks)
    }

    fn sync_folds(&self) -> Result<(), StoreError> {
        self.flush()
    }

    fn check(&self) -> Result<CheckReport, StoreError> {
        self.check_with_progress(&|| {})
    }

    fn attach_generator(&self, generator: Arc<dyn ChunkGenerator>) {
        // The first one stays: the world has one generator.
        let _ = self.generator.set(generator);
    }

    fn encode_on(&self, pool: Option<Arc<rayon::ThreadPool>>) {
        self.encode.set(pool);
    }
}

impl SledStore {
    /// A player's feet and time, read together: a save between two plain
    /// gets would pair one save's feet with another's time.
    fn position_at(&self, key: &[u8]) -> Result<Option<StoredPosition>, StoreError> {
        let trees = (&self.players, &self.player_times);
        let read = trees.transaction(|(feet, times)| Ok((feet.get(key)?, times.get(key)?)));
        let (feet, time) = read.map_err(|e: TransactionError<StoreError>| match e {
            TransactionError::Abort(e) => e,
            TransactionError::Storage(e) => StoreError::Sled(e),
        })?;
        let Some(feet) = feet else {
            return Ok(None);
        };
        decode_position(&feet, time.as_deref())
            .map(Some)
            .ok_or_else(|| StoreError::corrupt("player position", show_raw(key)))
    }
}

/// sled's own default tree, present in every database.
const SLED_DEFAULT_TREE: &[u8] = b"__sled__default";

impl SledStore {
    /// A chunk's newest durable state, undecoded when it has no deltas
    /// past its record `value`, else replayed and encoded again.
    fn raw_latest(&self, pos: ChunkPos, value: &[u8]) -> Result<RawChunk, StoreError> {
        let (version, body) = split_chunk_value(pos, value)?;
        if !is_generated(body) && self.head_version(pos, version)? == version {
            return Ok(RawChunk {
                pos,
                version,
                encoded: body.to_vec(),
            });
        }
        let (version, chunk) = self
            .latest(pos)?
            .ok_or_else(|| StoreError::corrupt("chunk record vanished", show_pos(pos)))?;
        Ok(RawChunk {
            pos,
            version,
            encoded: strata_terrain::chunk_codec::encode_chunk(&chunk),
        })
    }

    /// Number of named blobs.
    pub fn blob_count(&self) -> Result<u64, StoreError> {
        Ok(self.blobs.len() as u64)
    }

    /// [`ChunkStore::check`], calling `tick` once per record scanned.
    pub fn check_with_progress(&self, tick: &dyn Fn()) -> Result<CheckReport, StoreError> {
        let mut checker = Checker::new();
        if let Some(v) = self.meta.get(META_LOG_BASE)? {
            match decode_last_seq(&v) {
                Ok(base) => checker = Checker::with_log_base(base),
                Err(e) => checker.meta_issue(format!("log_base: {e}")),
            }
        }
        let world = self.meta.get(META_WORLD)?;
        let last_seq = match self.meta.get(META_LAST_SEQ)? {
            Some(v) => match decode_last_seq(&v) {
                Ok(s) => s,
                Err(e) => {
                    checker.meta_issue(e.to_string());
                    0
                }
            },
            None => 0,
        };
        if let Some(w) = &world {
            if let Err(e) = decode_meta(w, last_seq) {
                checker.meta_issue(e.to_string());
            }
        }
        for k in self.meta.iter().keys() {
            let k = k?;
            if ![META_WORLD, META_LAST_SEQ, META_LOG_BASE].contains(&&*k) {
                checker.unknown_meta_key(&k);
            }
        }
        let known = [
            TREE_META,
            TREE_CHUNKS,
            TREE_LOG,
            TREE_BLOBS,
            TREE_PLAYERS,
            TREE_PLAYER_TIMES,
            TREE_DELTAS,
        ]
        .map(str::as_bytes);
        for name in self.db.tree_names() {
            if name == SLED_DEFAULT_TREE || known.contains(&&name[..]) {
                continue;
            }
            // An empty tree holds no orphan; sled keeps names it was asked for.
            let records = self.db.open_tree(&name)?.len() as u64;
            if records > 0 {
                checker.unknown_tree(&name, records);
            }
        }
        for r in self.log.iter() {
            let (k, v) = r?;
            match record_entries(&k, &v) {
                Ok(entries) => {
                    for (seq, record) in entries {
                        checker.log_record(&seq_key(seq), record);
                    }
                }
                Err(BadRecord::Key) => checker.log_record(&k, &v),
                Err(BadRecord::Page { first, reason }) => checker.bad_log_page(first, reason),
            }
            tick();
        }
        for r in self.chunks.iter() {
            let (k, v) = r?;
            checker.chunk_record(&k, &v);
            tick();
        }
        for r in self.deltas.iter() {
            let (k, v) = r?;
            checker.delta_record(&k, &v);
            tick();
        }
        Ok(checker.finish(world.map(|_| last_seq)))
    }
}

/// How long an open waits for a just-closed handle's lock to go away: sled
/// releases its file lock from background threads shortly after a drop.
pub const LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Runs `open` until it stops failing on the database's file lock, for at
/// most [`LOCK_WAIT`]. A lock held by a live process fails after that.
/// The segment size an existing store was created with: sled refuses to
/// open it with another. Read from sled's `conf` file ("segment_size: N").
pub fn persisted_segment_size(dir: &Path) -> Option<usize> {
    let conf = std::fs::read(dir.join("conf")).ok()?;
    String::from_utf8_lossy(&conf)
        .lines()
        .find_map(|l| l.strip_prefix("segment_size: ")?.trim().parse().ok())
}

/// The blob `name` of the store in `dir`, read without opening it as a
/// store: its format record is left as it is (an open would upgrade an
/// older one, which the build that wrote it then refuses).
pub fn read_blob_as_is(dir: &Path, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
    check_blob_name(name)?;
    let db = open_raw(dir)?;
    // A store of a format this build does not know is refused, as by an
    // open: its blobs may not read as this build's.
    let world = db.open_tree(TREE_META)?.get(META_WORLD)?;
    if let Some(Ok(m)) = world.map(|w| decode_meta(&w, 0)) {
        let known = UPGRADABLE_FORMATS.contains(&m.format_version)
            || m.format_version == STORE_FORMAT_VERSION;
        if !known {
            return Err(StoreError::UnsupportedFormat {
                found: m.format_version,
                supported: STORE_FORMAT_VERSION,
            });
        }
    }
    let blobs = db.open_tree(TREE_BLOBS)?;
    Ok(blobs.get(name.as_bytes())?.map(|v| v.to_vec()))
}

/// The raw sled database under a store, for tools and tests that look
/// below [`ChunkStore`]: opened with the store's persisted segment size
/// (sled refuses any other), waiting briefly for a released lock.
pub fn open_raw(dir: &Path) -> sled::Result<sled::Db> {
    let segment = persisted_segment_size(dir).unwrap_or(StoreConfig::default().segment_size_bytes);
    open_when_unlocked(|| sled::Config::new().path(dir).segment_size(segment).open())
}

pub fn open_when_unlocked<T>(mut open: impl FnMut() -> sled::Result<T>) -> sled::Result<T> {
    let start = std::time::Instant::now();
    loop {
        match open() {
            Err(sled::Error::Io(e))
                if e.to_string().contains("could not acquire lock")
                    && start.elapsed() < LOCK_WAIT =>
            {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            other => return other,
        }
    }
}

#[cfg(test)]
mod lock_tests {
    use super::*;

    #[test]
    fn waits_for_a_released_lock_but_not_a_held_one() {
        let dir = tempfile::tempdir().unwrap();
        let held = sled::open(dir.path()).unwrap();
        // Still held for the whole wait: the open fails with the lock error.
        let err = open_when_unlocked(|| sled::open(dir.path())).unwrap_err();
        assert!(err.to_string().contains("could not acquire lock"), "{err}");
        // Released shortly after: the open waits and succeeds.
        let releaser = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(200));
            drop(held);
        });
        assert!(open_when_unlocked(|| sled::open(dir.path())).is_ok());
        releaser.join().unwrap();
    }

    /// The vendored sled writes a new store's `conf` through a temporary
    /// file renamed into place (vendor/sled/STRATA.md): none is left, and
    /// the store opens again with the segment size it recorded.
    #[test]
    fn a_new_stores_conf_is_renamed_into_place_whole() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = StoreConfig {
            segment_size_bytes: 1 << 20,
            ..StoreConfig::default()
        };
        drop(SledStore::open_with(dir.path(), &cfg).unwrap());
        assert!(dir.path().join("conf").is_file());
        assert!(!dir.path().join("conf.tmp").exists());
        assert_eq!(persisted_segment_size(dir.path()), Some(1 << 20));
        drop(SledStore::open(dir.path()).unwrap());
    }
}

#[cfg(test)]
mod durable_seq_tests {
    use super::*;

    #[test]
    fn last_seq_shows_only_what_a_flush_made_durable() {
        let dir = tempfile::tempdir().unwrap();
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
        // Written into sled, not yet flushed: readers do not see it.
        store
            .meta
            .insert(META_LAST_SEQ, &5u64.to_be_bytes()[..])
            .unwrap();
        assert_eq!(store.last_seq().unwrap(), 0);
        store.flush().unwrap();
        assert_eq!(store.last_seq().unwrap(), 5);
        // Reopened, what sled recovered is durable.
        drop(store);
        let store = SledStore::open(dir.path()).unwrap();
        assert_eq!(store.last_seq().unwrap(), 5);
    }

    #[test]
    fn reads_settle_only_once_what_they_saw_is_durable() {
        let dir = tempfile::tempdir().unwrap();
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
        let short = std::time::Duration::from_millis(30);
        store.settle_reads(short).unwrap();
        // A commit shown (its `last_seq` with it), its fsync not run yet.
        store
            .meta
            .insert(META_LAST_SEQ, &5u64.to_be_bytes()[..])
            .unwrap();
        let err = store.settle_reads(short).unwrap_err();
        assert!(
            matches!(err, StoreError::NotDurable { seq: 5, .. }),
            "{err}"
        );
        // A reader waiting while the fsync runs returns once it is done.
        std::thread::scope(|s| {
            let waiter = s.spawn(|| store.settle_reads(std::time::Duration::from_secs(30)));
            store.flush().unwrap();
            waiter.join().unwrap().unwrap();
        });
        store.settle_reads(short).unwrap();
    }
}

#[cfg(test)]
mod blob_undo_tests {
    use super::*;

    #[test]
    fn undoing_a_failed_blob_write_keeps_a_newer_write_over_it() {
        let dir = tempfile::tempdir().unwrap();
        let store = SledStore::open(dir.path()).unwrap();
        store.put_blob("zones", b"x").unwrap();
        // A writes a; B reads a and swaps it for b; A's flush fails.
        let old = store.blobs.insert(b"zones", &b"a"[..]).unwrap();
        assert!(store.swap_blob("zones", Some(b"a"), b"b").unwrap());
        store.undo_blob("zones", Some(b"a"), old.clone()).unwrap();
        assert_eq!(store.get_blob("zones").unwrap().unwrap(), b"b");
        // With no write since, the undo puts the old bytes back; a failed
        // delete puts the blob back too.
        store.blobs.insert(b"zones", &b"c"[..]).unwrap();
        store.undo_blob("zones", Some(b"c"), old).unwrap();
        assert_eq!(store.get_blob("zones").unwrap().unwrap(), b"x");
        let old = store.blobs.remove(b"zones").unwrap();
        store.undo_blob("zones", None, old).unwrap();
        assert_eq!(store.get_blob("zones").unwrap().unwrap(), b"x");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::{ChunkStore, WorldMeta};

    /// What a restore keeps of the world it replaces is read without the
    /// open's upgrade: a world of an older format stays one its build
    /// opens (a failed restore leaves it as it was).
    #[test]
    fn a_blob_read_as_is_leaves_an_older_format_as_it_was() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("world.sled");
        {
            let store = SledStore::open(&path).unwrap();
            store.init_meta(&WorldMeta::new(1, 1, "p")).unwrap();
            store.put_blob("access", b"bans").unwrap();
            let mut m = store.load_meta().unwrap().unwrap();
            m.format_version = 3;
            store
                .meta
                .insert(META_WORLD, encode_meta(&m).unwrap())
                .unwrap();
            store.flush().unwrap();
        }
        let got = read_blob_as_is(&path, "access").unwrap();
        assert_eq!(got.as_deref(), Some(&b"bans"[..]));
        let db = open_raw(&path).unwrap();
        let meta = db.open_tree(TREE_META).unwrap().get(META_WORLD).unwrap();
        let format = decode_meta(&meta.unwrap(), 0).unwrap().format_version;
        assert_eq!(format, 3, "not upgraded");
        // One of a format this build does not know is refused.
        let mut m = decode_meta(
            &db.open_tree(TREE_META)
                .unwrap()
                .get(META_WORLD)
                .unwrap()
                .unwrap(),
            0,
        )
        .unwrap();
        m.format_version = STORE_FORMAT_VERSION + 1;
        db.open_tree(TREE_META)
            .unwrap()
            .insert(META_WORLD, encode_meta(&m).unwrap())
            .unwrap();
        db.flush().unwrap();
        drop(db);
        assert!(matches!(
            read_blob_as_is(&path, "access"),
            Err(StoreError::UnsupportedFormat { .. })
        ));
    }
}
