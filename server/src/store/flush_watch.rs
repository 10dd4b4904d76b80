//! A watch on sled's flushes, so a failed disk ends a flush with an error.
//!
//! sled 0.34 can leave `Db::flush` waiting forever after a write error. A
//! log buffer written from `exit_reservation` (`pagecache/logger.rs`)
//! records the error but wakes no thread waiting in `make_stable`; only a
//! later `make_stable` call sees the error and wakes them. Its periodic
//! flusher never makes that call. So a commit could wait on a dead disk
//! forever, acknowledging nothing but never failing either.
//!
//! [`FlushWatch::flush`] marks a flush as running. A thread looks every
//! [`WATCH_POLL`], and once a flush has run past [`NUDGE_AFTER`] it flushes
//! too. With the error recorded, that call wakes the waiters, which return
//! it. With a slow disk it waits as they do.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::metrics as m;

/// How long a flush runs before the watch flushes too.
pub const NUDGE_AFTER: Duration = Duration::from_millis(250);
/// How often the watch looks.
pub const WATCH_POLL: Duration = Duration::from_millis(100);

#[derive(Debug)]
struct Shared {
    /// Flushes running now.
    running: AtomicUsize,
    /// When the oldest running flush began, in ms since `epoch`.
    since_ms: AtomicU64,
    epoch: Instant,
    stop: Mutex<bool>,
    wake: Condvar,
}

impl Shared {
    fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64
    }
}

/// The watching thread; dropping this stops it (and lets go of the `Db`).
#[derive(Debug)]
pub(super) struct FlushWatch {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl FlushWatch {
    pub(super) fn spawn(db: sled::Db) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            running: AtomicUsize::new(0),
            since_ms: AtomicU64::new(0),
            epoch: Instant::now(),
            stop: Mutex::new(false),
            wake: Condvar::new(),
        });
        let thread = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("strata-flush-watch".into())
                .spawn(move || watch(&shared, &db))?
        };
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// `db.flush()`, watched.
    pub(super) fn flush(&self, db: &sled::Db) -> sled::Result<usize> {
        let s = &self.shared;
        if s.running.fetch_add(1, Ordering::SeqCst) == 0 {
            s.since_ms.store(s.now_ms(), Ordering::SeqCst);
        }
        let result = db.flush();
        s.running.fetch_sub(1, Ordering::SeqCst);
        result
    }
}

fn watch(s: &Shared, db: &sled::Db) {
    let mut stop = s.stop.lock().unwrap_or_else(|p| p.into_inner());
    loop {
        stop = s
            .wake
            .wait_timeout(stop, WATCH_POLL)
            .unwrap_or_else(|p| p.into_inner())
            .0;
        if *stop {
            return;
        }
        let since = s.since_ms.load(Ordering::SeqCst);
        let late = s.now_ms().saturating_sub(since) >= NUDGE_AFTER.as_millis() as u64;
        if s.running.load(Ordering::SeqCst) > 0 && late {
            metrics::counter!(m::STORE_FLUSH_NUDGES).increment(1);
            drop(stop);
            // The error, if any, is the waiting flush's to return.
            let _ = db.flush();
            stop = s.stop.lock().unwrap_or_else(|p| p.into_inner());
        }
    }
}

/// How long dropping the watch waits for its thread. A thread still in a
/// flush past it (one the failed disk never ends: sled 0.34 wakes no one)
/// is left running, holding its `Db`, rather than hanging the drop, and
/// with it a failed restore or a shutdown, forever.
pub const STOP_WAIT: Duration = Duration::from_secs(5);

impl Drop for FlushWatch {
    fn drop(&mut self) {
        *self.shared.stop.lock().unwrap_or_else(|p| p.into_inner()) = true;
        self.shared.wake.notify_all();
        if let Some(t) = self.thread.take() {
            if !join_within(t, STOP_WAIT) {
                tracing::error!(
                    waited_ms = STOP_WAIT.as_millis() as u64,
                    "the store's flush watch is stuck in a flush (a failed disk?): left running"
                );
            }
        }
    }
}

/// Joins `thread` if it ends within `limit`; else leaves it running and
/// says so (`false`).
fn join_within(thread: JoinHandle<()>, limit: Duration) -> bool {
    let deadline = Instant::now() + limit;
    while !thread.is_finished() {
        if Instant::now() >= deadline {
            return false;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let _ = thread.join();
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thread_that_does_not_end_in_time_is_left_running() {
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let stuck = std::thread::spawn(move || {
            let _ = rx.recv();
        });
        let started = Instant::now();
        assert!(!join_within(stuck, Duration::from_millis(50)));
        assert!(started.elapsed() < STOP_WAIT);
        drop(tx);
        let quick = std::thread::spawn(|| ());
        assert!(join_within(quick, STOP_WAIT));
    }

    #[test]
    fn watched_flushes_write_and_a_dropped_watch_lets_go_of_the_db() {
        let dir = tempfile::tempdir().unwrap();
        let db = sled::Config::new().path(dir.path()).open().unwrap();
        let watch = FlushWatch::spawn(db.clone()).unwrap();
        for i in 0..20u32 {
            db.insert(i.to_be_bytes(), &b"v"[..]).unwrap();
            watch.flush(&db).unwrap();
        }
        assert_eq!(watch.shared.running.load(Ordering::SeqCst), 0);
        drop(watch);
        drop(db);
        // No handle is left (sled locks its file): it opens again, whole.
        // sled's own IO threads may hold the file a moment longer under
        // load, so the open gets a few tries.
        let mut tries = 0;
        let db = loop {
            match sled::Config::new().path(dir.path()).open() {
                Ok(db) => break db,
                Err(e) if tries < 100 => {
                    tries += 1;
                    eprintln!("reopen, try {tries}: {e}");
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => panic!("the store stayed locked: {e}"),
            }
        };
        assert_eq!(db.len(), 20);
    }
}
