//! Readiness, for `/healthz` on the metrics listener: ready while the
//! server accepts connections, its engine thread runs and ticks, and its
//! store answers.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// How long the engine may go without finishing a tick before the server
/// says it is not ready: a commit whose fsync never returns, a store that
/// hangs, a deadlock. Far above any tick seen under load (hundreds of ms).
pub const ENGINE_STALL: Duration = Duration::from_secs(10);

/// How long the engine's store operations (chunk reads, region reads,
/// commits) may go on failing, none succeeding, before the server says it
/// is not ready: a store that fails fast (a database gone, a disk
/// refusing reads) leaves the engine ticking and every player's reads
/// refused. Ready again once one succeeds, or once none has failed for
/// this long (nothing tried it since).
pub const STORE_FAILING: Duration = Duration::from_secs(5);

#[derive(Debug, Default)]
pub struct Health {
    accepting: AtomicBool,
    engine_stopped: AtomicBool,
    /// When the engine last finished a tick ([`clock_ms`]); 0 before its
    /// first.
    ticked_ms: AtomicU64,
    /// When the first store failure since the last success came; 0 when
    /// the last operation succeeded (or none failed).
    store_failing_since_ms: AtomicU64,
    /// When the last store failure came; 0 before any.
    store_failed_ms: AtomicU64,
}

/// Milliseconds since this process first asked, at least 1: a monotonic
/// clock for [`Health`].
fn clock_ms() -> u64 {
    static START: OnceLock<Instant> = OnceLock::new();
    let start = *START.get_or_init(Instant::now);
    (start.elapsed().as_millis() as u64).max(1)
}

impl Health {
    /// `Ok` when ready, else why not.
    pub fn check(&self) -> Result<(), &'static str> {
        self.check_at(clock_ms())
    }

    fn check_at(&self, now_ms: u64) -> Result<(), &'static str> {
        let ticked = self.ticked_ms.load(Ordering::Acquire);
        if self.engine_stopped.load(Ordering::Acquire) {
            Err("engine stopped")
        } else if !self.accepting.load(Ordering::Acquire) {
            Err("not accepting connections")
        } else if ticked > 0 && now_ms.saturating_sub(ticked) > ENGINE_STALL.as_millis() as u64 {
            Err("engine stalled: no tick finished lately")
        } else if self.store_failing(now_ms) {
            Err("store failing: its operations fail and none succeeds")
        } else {
            Ok(())
        }
    }

    fn store_failing(&self, now_ms: u64) -> bool {
        let since = self.store_failing_since_ms.load(Ordering::Acquire);
        let last = self.store_failed_ms.load(Ordering::Acquire);
        let window = STORE_FAILING.as_millis() as u64;
        since > 0 && now_ms.saturating_sub(since) >= window && now_ms.saturating_sub(last) < window
    }

    /// A store operation of the engine's failed.
    pub fn store_failed(&self) {
        self.store_failed_at(clock_ms());
    }

    fn store_failed_at(&self, now_ms: u64) {
        let _ = self.store_failing_since_ms.compare_exchange(
            0,
            now_ms,
            Ordering::AcqRel,
            Ordering::Acquire,
        );
        self.store_failed_ms.store(now_ms, Ordering::Release);
    }

    /// A store operation off the engine's path failed (a checkpoint pass, a
    /// log prune, a position save, a lease renewal): counted as
    /// [`Self::store_failed`] unless the error is one chunk's records (the
    /// data's fault, not the store's). Those paths report no successes: a
    /// read that works (a checkpoint listing nothing) says nothing of the
    /// engine's writes, so only the engine's own operations make the
    /// server ready again before `STORE_FAILING` without a failure passes.
    pub fn store_error(&self, error: &crate::store::StoreError) {
        if !error.is_chunk_local() {
            self.store_failed();
        }
    }

    /// A store operation of the engine's succeeded.
    pub fn store_ok(&self) {
        self.store_failing_since_ms.store(0, Ordering::Release);
    }

    pub fn set_accepting(&self, on: bool) {
        self.accepting.store(on, Ordering::Release);
    }

    /// The engine thread ended; the server is not ready again.
    pub fn engine_stopped(&self) {
        self.engine_stopped.store(true, Ordering::Release);
    }

    /// The engine finished a tick.
    pub fn ticked(&self) {
        self.ticked_at(clock_ms());
    }

    fn ticked_at(&self, now_ms: u64) {
        self.ticked_ms.store(now_ms, Ordering::Release);
    }

    /// How long ago the engine last finished a tick; `None` before its
    /// first.
    pub fn since_tick(&self) -> Option<Duration> {
        let ticked = self.ticked_ms.load(Ordering::Acquire);
        (ticked > 0).then(|| Duration::from_millis(clock_ms().saturating_sub(ticked)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_engine_that_stops_ticking_is_not_ready() {
        let h = Health::default();
        h.set_accepting(true);
        assert_eq!(h.check_at(5), Ok(()), "before the first tick");
        h.ticked_at(1_000);
        let stall = ENGINE_STALL.as_millis() as u64;
        assert_eq!(h.check_at(1_000 + stall), Ok(()));
        assert!(h.check_at(1_001 + stall).unwrap_err().contains("stalled"));
        h.ticked_at(1_001 + stall);
        assert_eq!(h.check_at(1_001 + stall), Ok(()));
        h.engine_stopped();
        assert_eq!(h.check_at(1_001 + stall), Err("engine stopped"));
    }

    #[test]
    fn a_store_that_keeps_failing_is_not_ready() {
        let h = Health::default();
        h.set_accepting(true);
        let window = STORE_FAILING.as_millis() as u64;
        h.store_failed_at(1_000);
        assert_eq!(h.check_at(1_000 + window - 1), Ok(()), "a blip");
        h.store_failed_at(1_000 + window - 1);
        assert!(h.check_at(1_000 + window).unwrap_err().contains("store"));
        // One success: ready again, and a later failure starts anew.
        h.store_ok();
        assert_eq!(h.check_at(1_000 + window), Ok(()));
        h.store_failed_at(2_000 + window);
        assert_eq!(h.check_at(2_000 + window), Ok(()));
        // Failures that stop (nothing tries the store): ready after the window.
        h.store_failed_at(2_000 + 2 * window);
        assert!(h.check_at(2_000 + 2 * window).is_err());
        assert_eq!(h.check_at(2_000 + 3 * window), Ok(()));
    }
}
