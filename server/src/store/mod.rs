//! Durable storage of the authoritative world, behind [`ChunkStore`].
//!
//! The store holds only what generation cannot recreate: the world's
//! generation inputs ([`WorldMeta`]), every chunk an edit has modified (at
//! its version), the edit log in seq order, and small named blobs the
//! server keeps (protected zones). A chunk the store does not hold is the
//! generator's output at version 0.
//!
//! Writes happen once per sequencer tick through [`ChunkStore::commit_batch`]
//! (group commit): log entries, the deltas of the changed chunks (with a
//! generator attached, a chunk's first changes too, after a "generated"
//! record; without one a chunk stored for the first time goes whole) and
//! `last_seq` go in
//! one atomic transaction, then one flush and the fsyncs sled leaves out
//! (`disk_sync`) make them durable, and only then may the server
//! acknowledge the edits. The call blocks on fsync, so the async
//! shell runs it through `tokio::task::spawn_blocking` (the store is `Send +
//! Sync`; share it as `Arc<dyn ChunkStore>`). The key layout is documented
//! in [`keys`]. A background checkpoint ([`ChunkStore::checkpoint`],
//! `deltas.rs`) folds deltas into chunk records; reads replay the rest.

mod batch;
mod check;
mod checkpointer;
mod config;
mod deltas;
mod disk_sync;
mod encode_pool;
mod error;
mod flush_watch;
mod import;
pub mod keys;
mod log_cursor;
mod log_pages;
mod open;
pub mod pg;
mod positions;
mod record;
mod rules;
mod sled_store;
mod types;
mod world_lock;

use std::collections::BTreeSet;
use std::ops::RangeInclusive;

use std::sync::Arc;

use strata_terrain::world::ChunkGenerator;
use strata_terrain::ChunkPos;

use crate::sequencer::regions::RegionId;

pub use batch::{MAX_BATCH_CHUNKS, MAX_BATCH_ENTRIES};
pub use check::{CheckIssue, CheckReport, Checker, MAX_REPORTED_ISSUES};
pub use checkpointer::{
    pass_once, prune_log, CheckpointPace, Checkpointer, PassReport, LOG_PRUNE_BATCH,
};
pub use config::{
    StoreBackend, StoreConfig, DEFAULT_CACHE_CAPACITY_BYTES, DEFAULT_CHECKPOINT_CHUNKS,
    DEFAULT_CHECKPOINT_MS, DEFAULT_FLUSH_EVERY_MS, DEFAULT_SEGMENT_SIZE_BYTES,
    MAX_CHECKPOINT_CHUNKS, MAX_CHECKPOINT_MS, MAX_FLUSH_EVERY_MS, MAX_SEGMENT_SIZE_BYTES,
    MIN_CACHE_CAPACITY_BYTES, MIN_SEGMENT_SIZE_BYTES,
};
pub use disk_sync::MAX_TRACKED_BLOBS;
pub use encode_pool::EncodePool;
pub use error::StoreError;
pub use import::ImportTarget;
pub use log_cursor::{LogCursor, LogSegment, SegmentsAlso, DEAD_SEGMENT_KEPT};
pub use open::open_store;
pub use pg::PgStore;
pub use positions::TREE_PLAYER_TIMES;
pub use record::{encode_chunk_value, MAX_LOG_RECORD_BYTES, MAX_SEQ};
pub use rules::compare_meta;
pub use sled_store::{
    open_raw, open_when_unlocked, persisted_segment_size, read_blob_as_is, SledStore,
    MAX_BLOB_BYTES, MAX_BLOB_NAME_BYTES, MAX_GENERATOR_PARAMS_BYTES, META_LAST_SEQ, META_LOG_BASE,
    META_WORLD, TREE_BLOBS, TREE_CHUNKS, TREE_DELTAS, TREE_LOG, TREE_META, TREE_PLAYERS,
};
pub use types::{
    CheckpointStats, CommitBatch, CommitStats, LogEntry, RawChunk, RegionAccess, RegionHolder,
    RegionMark, StoredChunk, StoredPosition, WorldMeta, STORE_FORMAT_VERSION,
};
pub use world_lock::{with_suffix, WorldLock, LOCK_SUFFIX, REPLACED_SUFFIX, RESTORING_SUFFIX};

/// A fallible iterator over store records.
pub type StoreIter<'a, T> = Box<dyn Iterator<Item = Result<T, StoreError>> + Send + 'a>;

/// Whole chunk states in a batch from which a store encodes them in
/// parallel (on its [`EncodePool`]); below it the committing thread
/// encodes them alone.
pub const PARALLEL_ENCODE_CHUNKS: usize = 4;

/// Durable world storage. Every method that writes returns only once the
/// write is durable; a write that fails changes nothing.
pub trait ChunkStore: Send + Sync + std::fmt::Debug {
    /// The world metadata, or `None` for a new store.
    fn load_meta(&self) -> Result<Option<WorldMeta>, StoreError>;

    /// Writes the metadata of a new world (`last_seq` must be 0). If the
    /// store already has metadata with the same seed, generator version and
    /// parameters it is returned unchanged; any difference is
    /// [`StoreError::MetaMismatch`].
    fn init_meta(&self, meta: &WorldMeta) -> Result<WorldMeta, StoreError>;

    /// Seq of the last committed edit (0 for none).
    fn last_seq(&self) -> Result<u64, StoreError>;

    /// A modified chunk at its newest durable version (its record plus the
    /// deltas committed since), or `None` if it was never modified.
    fn load_chunk(&self, pos: ChunkPos) -> Result<Option<StoredChunk>, StoreError>;

    /// [`Self::load_chunk`] of each of `positions`, in their order. A store
    /// across a network reads them in few round trips (the engine thread
    /// waits on these); embedded ones one by one.
    fn load_chunks(&self, positions: &[ChunkPos]) -> Result<Vec<Option<StoredChunk>>, StoreError> {
        positions.iter().map(|&p| self.load_chunk(p)).collect()
    }

    /// Atomically writes one tick's edits, whole chunk states, deltas and
    /// `last_seq`, then flushes. Refuses (changing nothing) a batch whose seqs do not
    /// follow `last_seq`, whose chunk versions do not rise, or whose chunks
    /// and entries disagree. Blocks on fsync.
    fn commit_batch(&self, batch: &CommitBatch) -> Result<CommitStats, StoreError>;

    /// One log entry.
    fn log_entry(&self, seq: u64) -> Result<Option<LogEntry>, StoreError>;

    /// Log entries with seq in `seqs`, ascending.
    fn edit_log(&self, seqs: RangeInclusive<u64>) -> StoreIter<'_, LogEntry>;

    /// The seq the log starts after: entries at or below it are gone (the
    /// snapshot a world was restored from, or [`Self::prune_log`]).
    fn log_base(&self) -> Result<u64, StoreError> {
        Ok(0)
    }

    /// The parts of the edit log being written now, each in seq order
    /// ([`LogCursor`]), and those `also` names: one for a store one process
    /// writes; on a cluster's PostgreSQL log each node's newest seq block
    /// and the others `also` names. A segment's head counts pruned entries
    /// too.
    fn log_segments(&self, _also: SegmentsAlso) -> Result<Vec<LogSegment>, StoreError> {
        Ok(vec![LogSegment {
            first: 1,
            last: i64::MAX as u64,
            head: self.last_seq()?,
        }])
    }

    /// Whether the entry of `seq`, if there was one, was pruned.
    fn log_pruned_at(&self, seq: u64) -> Result<bool, StoreError> {
        Ok(seq <= self.log_base()?)
    }

    /// Whether the entry of any of `seqs` was pruned.
    fn log_pruned_at_any(&self, seqs: &[u64]) -> Result<bool, StoreError> {
        for &seq in seqs {
            if self.log_pruned_at(seq)? {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Removes the log's oldest entries accepted before `before_ms` (ms
    /// since the Unix epoch): the longest run of them from the log's start,
    /// in seq order (a newer entry ends it; on a cluster's PostgreSQL log,
    /// from the start of each node's seq block), at most about `max`, and
    /// moves the log base (a block's `pruned_to`) to the last one removed.
    /// Returns the entries removed.
    /// Recovery does not read the log (records and deltas hold the world):
    /// it is the world's history, for the console's timeline and
    /// `verify-acks`, and without this it grows with every edit for good.
    fn prune_log(&self, _before_ms: u64, _max: usize) -> Result<u64, StoreError> {
        Ok(0)
    }

    /// A modified chunk's stored bytes, undecoded, or `None` if never modified.
    /// It may show a commit whose fsync is still running: a reader that
    /// shows what it read to anyone calls [`Self::settle_reads`] first.
    fn raw_chunk(&self, pos: ChunkPos) -> Result<Option<RawChunk>, StoreError>;

    /// Returns once every commit this store's reads have shown so far is
    /// durable, or refuses after `within` ([`StoreError::NotDurable`]).
    /// sled shows a transaction's writes before its fsync; PostgreSQL shows
    /// a commit only once its WAL is flushed, so its default returns at once.
    fn settle_reads(&self, within: std::time::Duration) -> Result<(), StoreError> {
        let _ = within;
        Ok(())
    }

    /// `(pos, version)` of every modified chunk, in key ([`ChunkPos`]) order.
    fn modified_chunks(&self) -> StoreIter<'_, (ChunkPos, u64)>;

    /// Every modified chunk with its snapshot bytes, undecoded, in key order.
    fn raw_chunks(&self) -> StoreIter<'_, RawChunk>;

    /// Number of modified chunks (a scan: O(chunks)).
    fn chunk_count(&self) -> Result<u64, StoreError>;

    /// Delta records not yet folded into chunk records.
    fn delta_count(&self) -> Result<u64, StoreError>;

    /// Bytes the store occupies on disk.
    fn size_on_disk(&self) -> Result<u64, StoreError>;

    fn get_blob(&self, name: &str) -> Result<Option<Vec<u8>>, StoreError>;

    /// Stores a named blob durably, replacing any previous one.
    fn put_blob(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError>;

    /// Stores `bytes` as blob `name` only if the blob holds `expected` now
    /// (`None`: there is none), atomically; durable on return. False, with
    /// nothing written, when it holds something else: another writer (a
    /// node of the cluster) changed it since it was read.
    fn swap_blob(
        &self,
        name: &str,
        expected: Option<&[u8]>,
        bytes: &[u8],
    ) -> Result<bool, StoreError>;

    /// Removes a blob durably; returns whether it existed.
    fn delete_blob(&self, name: &str) -> Result<bool, StoreError>;

    /// Stores players' last positions, replacing older ones; durable on
    /// return.
    fn save_positions(&self, positions: &[(String, StoredPosition)]) -> Result<(), StoreError>;

    /// Every stored player position.
    fn player_positions(&self) -> StoreIter<'_, (String, StoredPosition)>;

    /// The `max` positions known most recently (ties by name), newest
    /// first: what a starting server remembers. Embedded stores read them
    /// all, keeping `max` at most in memory; a database reads only these.
    fn recent_player_positions(
        &self,
        max: usize,
    ) -> Result<Vec<(String, StoredPosition)>, StoreError> {
        let mut kept = positions::Newest::new(max);
        for p in self.player_positions() {
            let (name, pos) = p?;
            kept.offer(name, pos);
        }
        Ok(kept.into_sorted())
    }

    /// One player's stored position (a cluster node joining a player reads
    /// what the node that last had it saved).
    fn player_position(&self, player: &str) -> Result<Option<StoredPosition>, StoreError>;

    /// Up to `max_chunks` chunks that have committed deltas, in key order,
    /// after `after` when given (a checkpoint goes on where its last pass
    /// stopped, so no chunk waits behind others edited as often). A cluster
    /// node lists only chunks of the regions it holds: another node's are
    /// that node's to fold.
    fn chunks_with_deltas(
        &self,
        after: Option<ChunkPos>,
        max_chunks: usize,
    ) -> Result<Vec<ChunkPos>, StoreError>;

    /// Folds the committed deltas of `chunks` into their records (a
    /// checkpoint). Runs beside commits; reads see the same states before
    /// and after. A chunk with no deltas left is skipped, uncounted. The
    /// folds need not be durable yet (on sled they reach the disk with the
    /// next commit's flush): a fold lost to a crash leaves the deltas it
    /// would have removed, which reads replay. [`Self::sync_folds`] makes
    /// them durable at once.
    fn fold_chunks(&self, chunks: &[ChunkPos]) -> Result<CheckpointStats, StoreError>;

    /// Makes every fold so far durable. PostgreSQL's already are (the last
    /// fold of each call commits synchronously).
    fn sync_folds(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// Folds the deltas of up to `max_chunks` chunks, durably:
    /// [`Self::chunks_with_deltas`], [`Self::fold_chunks`], then
    /// [`Self::sync_folds`].
    fn checkpoint(&self, max_chunks: usize) -> Result<CheckpointStats, StoreError> {
        let stats = self.fold_chunks(&self.chunks_with_deltas(None, max_chunks)?)?;
        if stats.chunks > 0 {
            self.sync_folds()?;
        }
        Ok(stats)
    }

    /// Verifies every record (see [`Checker`]). Run it while nothing
    /// commits: records are scanned, not snapshotted.
    fn check(&self) -> Result<CheckReport, StoreError>;

    /// Gives the store the world's generator, so that it may keep a chunk's
    /// first changes as deltas from its generated state
    /// ([`CommitBatch::generated`]) and rebuild that state to read it. The
    /// first call counts; a store that never stores chunks that way ignores
    /// it. Without one, every chunk is written whole, and reading a chunk a
    /// store with one wrote is [`StoreError::NeedsGenerator`] until a
    /// checkpoint has folded it.
    fn attach_generator(&self, _generator: Arc<dyn ChunkGenerator>) {}

    /// Reports the failures of the store's own threads (a cluster node's
    /// lease renewals) to `health` from now on.
    fn report_to(&self, _health: Arc<crate::health::Health>) {}

    /// Encodes big batches' chunks on `pool` from now on (the engine's
    /// workers, while it runs; [`EncodePool`]), or on the caller's pool
    /// again (`None`: the engine stopped, its threads may end).
    fn encode_on(&self, _pool: Option<Arc<rayon::ThreadPool>>) {}

    /// Called once at shutdown, after the last commit and checkpoint: a
    /// cluster node gives up its region leases, so another node may take
    /// them over at once instead of after the lease runs out. No commit
    /// follows it.
    fn close(&self) -> Result<(), StoreError> {
        Ok(())
    }

    // ------------------------------------------------- one node of many
    // Alone on its store (sled, or PostgreSQL without `[cluster]`) a node
    // writes everything; these defaults say so.

    /// Whether other nodes may write this store too: the engine then asks
    /// [`Self::acquire_regions`] before it queues an edit.
    fn clustered(&self) -> bool {
        false
    }

    /// Regions whose lease this node holds (0 alone on the store).
    fn regions_held(&self) -> usize {
        0
    }

    /// Lets go of those of `regions` this node holds (claimed for an edit
    /// that was refused after all); they are reported fresh.
    fn release_regions(&self, _regions: &BTreeSet<RegionId>) -> Result<(), StoreError> {
        Ok(())
    }

    /// Most regions this node may hold (`[cluster] max_held_regions`).
    fn max_held_regions(&self) -> usize {
        usize::MAX
    }

    /// The seq the engine continues after, given the store's `last_seq`:
    /// that one, or in a cluster the seq below a new block of seqs reserved
    /// for this process (`store/pg/seqs.rs`). Called before the engine
    /// starts and after a fenced commit. Failing, a cluster node hands out
    /// no seq of its current block past `last_seq` ([`Self::seq_bounds`])
    /// and reserves the next block in the background.
    fn reserve_seqs(&self, last_seq: u64) -> Result<u64, StoreError> {
        Ok(last_seq)
    }

    /// The seqs the engine may hand out: above the first, up to the
    /// second (a cluster node's block; both rise when a claim reserves a
    /// new one). Cheap: read at every tick.
    fn seq_bounds(&self) -> (u64, u64) {
        (0, MAX_SEQ)
    }

    /// The engine numbers its next edit `next` (a cluster node reserves
    /// its next seq block in the background when its block runs low).
    fn note_next_seq(&self, _next: u64) {}

    /// Whether this node may write `regions`; claims those it may take.
    fn acquire_regions(&self, _regions: &BTreeSet<RegionId>) -> Result<RegionAccess, StoreError> {
        Ok(RegionAccess::Granted)
    }

    /// Asks the nodes holding `regions` to hand them over (a cluster node
    /// whose edit reaches into them); they do once their own edits left
    /// them alone for `[cluster] handoff_idle_ms`. Alone: nothing.
    fn want_regions(&self, _regions: &BTreeSet<RegionId>) -> Result<(), StoreError> {
        Ok(())
    }

    /// Marks the store as one a running server uses, for as long as it is
    /// open: on PostgreSQL a forced restore then refuses the database, and
    /// a forced restore in progress refuses the server. The server calls it once,
    /// before reading the world. Embedded stores: nothing.
    fn serve(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// Keeps every server off the store while it is open, or refuses one
    /// a server uses: for a tool that must read one moment of the world
    /// (an offline snapshot). On PostgreSQL it holds the serving lock
    /// alone; an embedded store opened by `open_store` is held already.
    fn hold_alone(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// Whether what [`Self::hold_alone`] took still holds: on PostgreSQL
    /// the lock lives with one connection, and one that ended (a restart,
    /// a terminated backend) let servers in meanwhile. Refuses then.
    fn still_alone(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// The id of the world this store holds, as [`Self::init_meta`] found
    /// it: one per world, new at every restore, and compared in every
    /// commit after. PostgreSQL only (a cluster's tickets are signed for
    /// it); an embedded store: `None`.
    fn world_id(&self) -> Option<String> {
        None
    }

    /// This node's `[cluster] node_id` (`None` alone on its store).
    fn node_id(&self) -> Option<String> {
        None
    }

    /// Claims the cluster node id for this process (a newer incarnation
    /// supersedes any process still running under it). The server calls
    /// it once its ports are bound. Alone on its store: nothing.
    fn register_node(&self) -> Result<(), StoreError> {
        Ok(())
    }

    /// Why this process must stop: another process started under its
    /// cluster node id (`None` alone on its store, or while the id is its
    /// own). Cheap: read at every tick.
    fn superseded(&self) -> Option<String> {
        None
    }

    /// Who writes each of `regions`, claiming nothing. Cached like
    /// [`Self::acquire_regions`]' refusals: at most one query per region
    /// per renewal period. Sorted by region.
    fn region_holders(
        &self,
        regions: &BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, RegionHolder)>, StoreError> {
        Ok(regions.iter().map(|r| (*r, RegionHolder::Here)).collect())
    }

    /// Of `regions`, those no node holds now (no live lease), each with
    /// its mark: the epoch of its last claim and the last seq committed
    /// into it ((0, 0): never claimed). Every write into a region raises
    /// its last seq (a fenced commit, under the region row's lock): a copy
    /// brought current while a region was free at a mark is current for as
    /// long as that mark is the one read here. Uncached: one query.
    fn free_region_marks(
        &self,
        _regions: &BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, RegionMark)>, StoreError> {
        Ok(Vec::new())
    }

    /// [`Self::region_holders`] for a viewer (the console's map): it reads
    /// the cache, but what it looks up is not cached, so looking over many
    /// regions cannot push out the holders the engine routes edits by.
    fn region_holders_read(
        &self,
        regions: &BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, RegionHolder)>, StoreError> {
        self.region_holders(regions)
    }

    /// Regions claimed since the last call (at the engine's request or
    /// adopted in the background), with the epoch held now, and regions
    /// lost or let go (`None`): their chunks may have changed, or may
    /// change, while another node holds them. Cheap: called at every tick.
    fn take_fresh_regions(&self) -> Vec<(RegionId, Option<u64>)> {
        Vec::new()
    }

    /// The stored version of every chunk of `region` that the store holds.
    fn region_versions(&self, _region: RegionId) -> Result<Vec<(ChunkPos, u64)>, StoreError> {
        Ok(Vec::new())
    }

    /// The address clients reach this node at, once it is bound: written
    /// into the region rows it claims, unless `[cluster] advertise` is set.
    fn bound_at(&self, _addr: &str) {}
}
