//! A server alone on its database rides out a PostgreSQL outage (a
//! restart, a failover, a network blip): a commit that wrote nothing is
//! tried again, and one whose outcome went unanswered is asked about
//! again, for `[store.postgres] commit_retry_ms`. Nothing is acknowledged
//! meanwhile; the engine waits. Past it, the commit fails and the server
//! stops as before. A cluster's nodes do not wait: a batch that wrote
//! nothing is abandoned (its edits refused) and the node goes on.

use std::time::{Duration, Instant};

use crate::log_every::{LogEvery, LOG_EVERY};
use crate::store::StoreError;

/// The first pause between tries; each doubles it, up to [`LONGEST_PAUSE`].
const FIRST_PAUSE: Duration = Duration::from_millis(50);
const LONGEST_PAUSE: Duration = Duration::from_secs(1);

/// Tries again are logged at most once per [`LOG_EVERY`], with a count.
static TRIES: LogEvery = LogEvery::new(LOG_EVERY);

/// How long one commit may still wait, and its next pause.
#[derive(Debug)]
pub(super) struct Patience {
    window: Duration,
    /// The window's end, from the first failure: a try that hung until
    /// its statement timeout (a failover without a reset) still leaves the
    /// whole window to the tries after it.
    until: Option<Instant>,
    pause: Duration,
}

impl Patience {
    /// Waits for `window` at most (zero: never) after the first failure.
    pub fn new(window: Duration) -> Self {
        Self {
            window,
            until: None,
            pause: FIRST_PAUSE,
        }
    }

    /// After `e` (`what` says what failed): pauses and says to try again,
    /// or, the window spent, says to give up without pausing.
    pub fn again(&mut self, what: &'static str, e: &StoreError) -> bool {
        if self.window.is_zero() {
            return false;
        }
        let until = *self
            .until
            .get_or_insert_with(|| Instant::now() + self.window);
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            tracing::error!(error = %e, "{what}; PostgreSQL did not come back within [store.postgres] commit_retry_ms");
            return false;
        }
        let pause = self.pause.min(left);
        if let Some(tries) = TRIES.event() {
            tracing::warn!(error = %e, tries, left_ms = left.as_millis() as u64, "{what}; trying again (nothing is acknowledged meanwhile)");
        }
        metrics::counter!(crate::metrics::STORE_COMMIT_RETRIES).increment(1);
        std::thread::sleep(pause);
        self.pause = (self.pause * 2).min(LONGEST_PAUSE);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn failure() -> StoreError {
        StoreError::Uncommitted {
            reason: "test".into(),
        }
    }

    #[test]
    fn it_waits_out_its_window_and_no_longer() {
        let mut none = Patience::new(Duration::ZERO);
        assert!(!none.again("x", &failure()), "no window: no retry");
        let started = Instant::now();
        let mut some = Patience::new(Duration::from_millis(300));
        let mut tries = 0;
        while some.again("x", &failure()) {
            tries += 1;
        }
        let took = started.elapsed();
        assert!(took >= Duration::from_millis(300), "{took:?}");
        // 50 + 100 + the 150 left: the pauses double, the last is cut short.
        assert_eq!(tries, 3);
    }
}
