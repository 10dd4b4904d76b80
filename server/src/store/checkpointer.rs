//! The background checkpoint: a thread that folds committed deltas into
//! chunk records every `[store] checkpoint_ms`, off the commit path, and
//! folds everything once more when stopped.

use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use tracing::{debug, error};

use super::{ChunkStore, StoreError};
use crate::metrics as m;

#[derive(Debug, Default)]
struct Stop {
    flag: Mutex<bool>,
    wake: Condvar,
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
    /// Starts folding every `every` (never, for zero: only at [`Self::stop`]).
    pub fn spawn(
        store: Arc<dyn ChunkStore>,
        every: Duration,
        max_chunks: usize,
    ) -> std::io::Result<Self> {
        let stop = Arc::new(Stop::default());
        let thread = if every.is_zero() {
            None
        } else {
            let (stop, store) = (stop.clone(), store.clone());
            Some(
                std::thread::Builder::new()
                    .name("strata-checkpoint".into())
                    .spawn(move || run(&*store, &stop, every, max_chunks))?,
            )
        };
        Ok(Self {
            stop,
            thread,
            store,
            max_chunks,
        })
    }

    /// Ends the thread, then folds every delta left (a clean shutdown
    /// leaves nothing to replay).
    pub fn stop(mut self) -> Result<(), StoreError> {
        *self.stop.flag.lock().unwrap_or_else(|p| p.into_inner()) = true;
        self.stop.wake.notify_all();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        while pass(&*self.store, self.max_chunks)? > 0 {}
        Ok(())
    }
}

/// One pass; returns the chunks folded.
fn pass(store: &dyn ChunkStore, max_chunks: usize) -> Result<u64, StoreError> {
    let started = std::time::Instant::now();
    let stats = store.checkpoint(max_chunks)?;
    if stats.chunks > 0 {
        metrics::histogram!(m::CHECKPOINT_SECONDS).record(started.elapsed().as_secs_f64());
        metrics::counter!(m::CHECKPOINT_CHUNKS_TOTAL).increment(stats.chunks);
        metrics::counter!(m::STORE_BYTES, "kind" => "checkpoint").increment(stats.bytes_written);
        debug!(
            chunks = stats.chunks,
            deltas = stats.deltas,
            bytes = stats.bytes_written,
            "checkpoint"
        );
    }
    Ok(stats.chunks)
}

fn run(store: &dyn ChunkStore, stop: &Stop, every: Duration, max_chunks: usize) {
    let mut stopped = stop.flag.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        let (guard, _) = stop
            .wake
            .wait_timeout(stopped, every)
            .unwrap_or_else(|p| p.into_inner());
        stopped = guard;
        if *stopped {
            return;
        }
        drop(stopped);
        // A failed pass changes nothing: the deltas stay and reads replay them.
        if let Err(e) = pass(store, max_chunks) {
            error!(error = %e, "checkpoint failed; deltas stay until the next pass");
        }
        stopped = stop.flag.lock().unwrap_or_else(|p| p.into_inner());
    }
}
