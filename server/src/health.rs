//! Readiness, for `/healthz` on the metrics listener: ready while the
//! server accepts connections and its engine thread runs and ticks.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// How long the engine may go without finishing a tick before the server
/// says it is not ready: a commit whose fsync never returns, a store that
/// hangs, a deadlock. Far above any tick seen under load (hundreds of ms).
pub const ENGINE_STALL: Duration = Duration::from_secs(10);

#[derive(Debug, Default)]
pub struct Health {
    accepting: AtomicBool,
    engine_stopped: AtomicBool,
    /// When the engine last finished a tick ([`clock_ms`]); 0 before its
    /// first.
    ticked_ms: AtomicU64,
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
        } else {
            Ok(())
        }
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
}
