//! Warnings that hostile input can trigger at will (refused tokens,
//! refused connections) are logged at most once per period, with how many
//! were folded into each line, so a flood cannot fill the disk or drown
//! the log.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The default period: one line a second at most.
pub const LOG_EVERY: Duration = Duration::from_secs(1);

/// One kind of warning's last line and the events since.
#[derive(Debug)]
pub struct LogEvery {
    period: Duration,
    state: Mutex<(Option<Instant>, u64)>,
}

impl LogEvery {
    pub const fn new(period: Duration) -> Self {
        Self {
            period,
            state: Mutex::new((None, 0)),
        }
    }

    /// Counts one event; `Some(n)` when a line is due, `n` the events it
    /// stands for (this one included).
    pub fn event(&self) -> Option<u64> {
        self.event_at(Instant::now())
    }

    fn event_at(&self, now: Instant) -> Option<u64> {
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        s.1 += 1;
        if s.0.is_some_and(|t| now.duration_since(t) < self.period) {
            return None;
        }
        let n = s.1;
        *s = (Some(now), 0);
        Some(n)
    }
}

/// Store failures outside a commit, one limiter per op: a store that
/// stopped answering fails every player's read, so one line a second
/// stands for them all, without hiding another op's failure.
static STORE_ERRORS: [LogEvery; 4] = [
    LogEvery::new(LOG_EVERY),
    LogEvery::new(LOG_EVERY),
    LogEvery::new(LOG_EVERY),
    LogEvery::new(LOG_EVERY),
];

/// Counts a failed store operation (`op`: `read`, `regions`, `checkpoint`,
/// `prune`, `seqs`; `strata_store_errors_total`) and logs `what` with
/// `error`, at most one line a second for each of `read`, `regions`,
/// `seqs` and the rest.
pub fn store_error(op: &'static str, what: &str, error: &dyn std::fmt::Display) {
    metrics::counter!(crate::metrics::STORE_ERRORS, "op" => op).increment(1);
    let limiter = match op {
        "read" => &STORE_ERRORS[0],
        "regions" => &STORE_ERRORS[1],
        "seqs" => &STORE_ERRORS[3],
        _ => &STORE_ERRORS[2],
    };
    if let Some(folded) = limiter.event() {
        tracing::error!(%error, folded, "{what}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logs_once_per_period_with_the_count() {
        let log = LogEvery::new(Duration::from_secs(1));
        let t = Instant::now();
        assert_eq!(log.event_at(t), Some(1));
        for ms in 1..=999 {
            assert_eq!(log.event_at(t + Duration::from_millis(ms)), None);
        }
        assert_eq!(log.event_at(t + Duration::from_secs(1)), Some(1000));
        assert_eq!(log.event_at(t + Duration::from_millis(1500)), None);
    }
}
