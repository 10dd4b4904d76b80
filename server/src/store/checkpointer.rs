//! The background checkpoint: a thread that folds committed deltas into
//! chunk records every `[store] checkpoint_ms`, off the commit path, and
//! folds everything once more when stopped.
//!
//! A pass is paced: it folds `checkpoint_slice_chunks` chunks (one store
//! call), then pauses [`PAUSE_FACTOR`] times as long as that slice took,
//! so the pass takes at most a quarter of a core. Slices do not flush: on
//! sled the next group commit's flush writes a slice with the commit's own
//! records, so under load a commit carries at most the slice folded since
//! the commit before it, and waits under sled's global lock for at most
//! one checkpoint flush a pass: the pass ends with one
//! [`ChunkStore::sync_folds`]. Once a pass has run half its period it
//! stops pausing, so it finishes before the next is due. Each pass lists
//! chunks from where the last one stopped (wrapping at the end), so a
//! chunk is folded within a few passes however many others keep changing.

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use tracing::{debug, error};

use strata_terrain::ChunkPos;

use super::{CheckpointStats, ChunkStore, StoreError};
use crate::health::{Health, StoreWork};
use crate::metrics as m;

/// A pass pauses this many times each slice's own duration after it.
pub const PAUSE_FACTOR: u32 = 3;

#[derive(Debug, Default)]
struct Stop {
    flag: Mutex<bool>,
    wake: Condvar,
}

impl Stop {
    /// Waits `d`, or less once stopped; true when stopped.
    fn wait(&self, d: Duration) -> bool {
        let stopped = self.flag.lock().unwrap_or_else(|p| p.into_inner());
        let (stopped, _) = self
            .wake
            .wait_timeout_while(stopped, d, |s| !*s)
            .unwrap_or_else(|p| p.into_inner());
        *stopped
    }
}

/// How a pass folds: the period and the sizes from `[store]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckpointPace {
    /// Between passes; zero: no thread, only the fold at stop.
    pub every: Duration,
    /// Chunks one pass folds at most.
    pub max_chunks: usize,
    /// Chunks folded between two pauses.
    pub slice_chunks: usize,
    /// `[store] log_retention`: each pass prunes log entries older.
    pub log_retention: Duration,
}

/// What one paced pass did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PassReport {
    pub folded: CheckpointStats,
    /// Store calls (folds, none flushed).
    pub slices: u32,
    /// The pass's time, pauses left out.
    pub working: Duration,
    /// Time spent pausing.
    pub paused: Duration,
    /// The stop came during the pass; what is left folds at stop.
    pub stopped: bool,
    /// Where the next pass lists from: the last chunk listed when the pass
    /// listed `max_chunks`, else `None` (the start again).
    pub next: Option<ChunkPos>,
}

/// The running checkpoint thread; [`Checkpointer::stop`] ends it.
#[derive(Debug)]
pub struct Checkpointer {
    stop: Arc<Stop>,
    thread: Option<std::thread::JoinHandle<()>>,
    store: Arc<dyn ChunkStore>,
    max_chunks: usize,
}

impl Checkpointer {
    /// Starts a pass every `pace.every` (never, for zero: only at
    /// [`Self::stop`]). A pass or prune that fails is reported to `health`
    /// (`/healthz`: a store failing while nothing edits still shows).
    pub fn spawn(
        store: Arc<dyn ChunkStore>,
        pace: CheckpointPace,
        health: Option<Arc<Health>>,
    ) -> std::io::Result<Self> {
        let stop = Arc::new(Stop::default());
        let thread = if pace.every.is_zero() {
            None
        } else {
            let (stop, store) = (stop.clone(), store.clone());
            Some(
                std::thread::Builder::new()
                    .name("strata-checkpoint".into())
                    .spawn(move || run(&*store, &stop, pace, health.as_deref()))?,
            )
        };
        Ok(Self {
            stop,
            thread,
            store,
            max_chunks: pace.max_chunks,
        })
    }

    /// Ends the thread (a pass under way stops pausing and ends after its
    /// slice), then folds every delta left, unpaced: a clean shutdown
    /// leaves nothing to replay.
    pub fn stop(mut self) -> Result<(), StoreError> {
        *self.stop.flag.lock().unwrap_or_else(|p| p.into_inner()) = true;
        self.stop.wake.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        // Round after round over the chunks with deltas, until a whole
        // round folds nothing (what is left does not read: skipped).
        let mut after = None;
        let mut folded_this_round = 0;
        loop {
            let started = Instant::now();
            let todo = self.store.chunks_with_deltas(after, self.max_chunks)?;
            let stats = self.store.fold_chunks(&todo)?;
            if stats.chunks > 0 {
                self.store.sync_folds()?;
            }
            count(&stats);
            record(&stats, started.elapsed());
            folded_this_round += stats.chunks;
            if todo.len() < self.max_chunks.max(1) {
                if folded_this_round == 0 {
                    return Ok(());
                }
                (after, folded_this_round) = (None, 0);
            } else {
                after = todo.last().copied();
            }
        }
    }
}

/// Counts folded chunks and bytes as each slice ends, so a scrape during
/// a long pass sees its slices so far.
fn count(stats: &CheckpointStats) {
    metrics::counter!(m::CHECKPOINT_CHUNKS_TOTAL).increment(stats.chunks);
    metrics::counter!(m::STORE_BYTES, "kind" => "checkpoint").increment(stats.bytes_written);
}

/// A pass's (or the stop's fold's) time spent folding.
fn record(stats: &CheckpointStats, working: Duration) {
    if stats.chunks > 0 {
        metrics::histogram!(m::CHECKPOINT_SECONDS).record(working.as_secs_f64());
    }
}

/// One paced pass on the calling thread, as the checkpoint thread runs
/// them: the chunks that have deltas when it starts (at most
/// `pace.max_chunks`), folded `pace.slice_chunks` at a time, then made
/// durable once.
pub fn pass_once(
    store: &dyn ChunkStore,
    pace: CheckpointPace,
    after: Option<ChunkPos>,
) -> Result<PassReport, StoreError> {
    paced_pass(store, &Stop::default(), pace, after)
}

/// [`pass_once`], ended early by [`Checkpointer::stop`]. Chunks changed
/// during the pass wait for the next one: a pass never chases commits.
fn paced_pass(
    store: &dyn ChunkStore,
    stop: &Stop,
    pace: CheckpointPace,
    after: Option<ChunkPos>,
) -> Result<PassReport, StoreError> {
    let started = Instant::now();
    let mut report = PassReport::default();
    let todo = store.chunks_with_deltas(after, pace.max_chunks)?;
    if todo.len() >= pace.max_chunks.max(1) {
        report.next = todo.last().copied();
    }
    let mut slices = todo.chunks(pace.slice_chunks.max(1)).peekable();
    while let Some(slice) = slices.next() {
        let t = Instant::now();
        let s = store.fold_chunks(slice)?;
        let took = t.elapsed();
        count(&s);
        report.slices += 1;
        report.folded.chunks += s.chunks;
        report.folded.deltas += s.deltas;
        report.folded.bytes_written += s.bytes_written;
        report.folded.skipped += s.skipped;
        let pause = took * PAUSE_FACTOR;
        if slices.peek().is_none() || started.elapsed() + pause > pace.every / 2 {
            // Done, or late: finish before the next pass is due.
            continue;
        }
        if stop.wait(pause) {
            report.stopped = true;
            break;
        }
        report.paused += pause;
    }
    if report.folded.chunks > 0 {
        // Commits have flushed most slices already; this writes the rest.
        store.sync_folds()?;
    }
    // Listing included; a pause the stop cut short counts as working.
    report.working = started.elapsed().saturating_sub(report.paused);
    record(&report.folded, report.working);
    if report.folded.chunks > 0 {
        debug!(
            chunks = report.folded.chunks,
            deltas = report.folded.deltas,
            bytes = report.folded.bytes_written,
            slices = report.slices,
            working_ms = report.working.as_millis() as u64,
            paused_ms = report.paused.as_millis() as u64,
            "checkpoint"
        );
    }
    Ok(report)
}

fn run(store: &dyn ChunkStore, stop: &Stop, pace: CheckpointPace, health: Option<&Health>) {
    if let Some(h) = health {
        h.expect_every(StoreWork::Checkpoint, pace.every);
        h.expect_every(StoreWork::Prune, pace.every);
    }
    let mut after = None;
    while !stop.wait(pace.every) {
        // A failed pass changes nothing: the deltas stay and reads replay them.
        let pass = paced_pass(store, stop, pace, after);
        if let Some(h) = health {
            h.report(StoreWork::Checkpoint, &pass);
        }
        match pass {
            Ok(r) if r.stopped => return,
            Ok(r) => after = r.next,
            Err(e) => {
                metrics::counter!(crate::metrics::STORE_ERRORS, "op" => "checkpoint").increment(1);
                error!(error = %e, "checkpoint failed; deltas stay until the next pass")
            }
        }
        // A quarter of the period at most, as the folds.
        let pruned = prune_log(store, pace.log_retention, pace.every / 4);
        if let Some(h) = health {
            h.report(StoreWork::Prune, &pruned);
        }
        if let Err(e) = pruned {
            metrics::counter!(crate::metrics::STORE_ERRORS, "op" => "prune").increment(1);
            error!(error = %e, "pruning the edit log failed; it is tried again after the next pass");
        }
    }
}

/// Entries one store call prunes from the edit log at most (a few hundred
/// KiB of log): each call is one short transaction.
pub const LOG_PRUNE_BATCH: usize = 4096;

/// After a pass: removes log entries older than `retention`
/// ([`ChunkStore::prune_log`]), batch after batch until none is left or
/// `budget` is spent (a log years long drains over several passes).
pub fn prune_log(
    store: &dyn ChunkStore,
    retention: Duration,
    budget: Duration,
) -> Result<u64, StoreError> {
    let started = Instant::now();
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64);
    let before = now_ms.saturating_sub(retention.as_millis() as u64);
    let mut total = 0;
    loop {
        let removed = store.prune_log(before, LOG_PRUNE_BATCH)?;
        metrics::counter!(m::LOG_PRUNED_TOTAL).increment(removed);
        total += removed;
        if removed == 0 || started.elapsed() >= budget {
            break;
        }
    }
    if total > 0 {
        debug!(removed = total, "pruned the edit log");
    }
    Ok(total)
}
