//! Waiting on a future from plain threads, with a deadline.
//!
//! The store's callers are synchronous (the commit thread, the checkpoint
//! thread) and sometimes tokio tasks that call it directly (`app::start`).
//! `tokio-postgres` client futures need no reactor (they talk to the
//! connection task over channels), so this tiny executor can poll them on
//! any thread, inside a runtime or not, where `Runtime::block_on` would
//! panic. The connection tasks run on the store's own runtime.

use std::future::Future;
use std::sync::Arc;
use std::task::{Context, Poll, Wake, Waker};
use std::thread::Thread;
use std::time::{Duration, Instant};

/// Wakes the thread that waits.
struct Unpark(Thread);

impl Wake for Unpark {
    fn wake(self: Arc<Self>) {
        self.0.unpark();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        self.0.unpark();
    }
}

/// The deadline passed before the future finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Elapsed;

/// Polls `f` on this thread until it finishes or `limit` passes (the
/// future is then dropped unfinished).
pub fn wait<F: Future>(f: F, limit: Duration) -> Result<F::Output, Elapsed> {
    let deadline = Instant::now() + limit;
    let mut f = std::pin::pin!(f);
    let waker = Waker::from(Arc::new(Unpark(std::thread::current())));
    let mut cx = Context::from_waker(&waker);
    loop {
        if let Poll::Ready(out) = f.as_mut().poll(&mut cx) {
            return Ok(out);
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(Elapsed);
        }
        // A wake before the park makes it return at once; a spurious
        // return only polls again.
        std::thread::park_timeout(left);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finishes_woken_futures_and_gives_up_on_silent_ones() {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let sender = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(30));
            tx.send(7).unwrap();
        });
        assert_eq!(wait(rx, Duration::from_secs(5)), Ok(Ok(7)));
        sender.join().unwrap();
        let started = Instant::now();
        assert_eq!(
            wait(std::future::pending::<()>(), Duration::from_millis(50)),
            Err(Elapsed)
        );
        assert!(started.elapsed() >= Duration::from_millis(50));
    }
}
