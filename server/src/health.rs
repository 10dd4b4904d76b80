//! Readiness, for `/healthz` on the metrics listener: ready while the
//! server accepts connections and its engine thread runs.

use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Debug, Default)]
pub struct Health {
    accepting: AtomicBool,
    engine_stopped: AtomicBool,
}

impl Health {
    /// `Ok` when ready, else why not.
    pub fn check(&self) -> Result<(), &'static str> {
        if self.engine_stopped.load(Ordering::Acquire) {
            Err("engine stopped")
        } else if !self.accepting.load(Ordering::Acquire) {
            Err("not accepting connections")
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
}
