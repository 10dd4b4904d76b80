//! Group commit without stalling sessions: the tick's batch is written and
//! flushed on a helper thread while the engine keeps taking commands.
//!
//! While the commit runs, the world is one batch ahead of the store, so
//! only commands that cannot observe the difference are served: positions,
//! edit submissions (they queue for a later tick), subscriptions, resyncs
//! (the snapshot itself is built after the commit) and joins and leaves.
//! Admin requests, which read the store, and `Stop` wait until it is done.

use std::collections::VecDeque;
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

use super::{Command, Engine, Inbox};
use crate::store::{CommitBatch, CommitStats, StoreError};

/// How often the engine checks whether a running commit has finished.
pub const COMMIT_POLL: Duration = Duration::from_micros(250);

/// Commands held back while a commit runs.
#[derive(Debug, Default)]
pub struct Deferred(VecDeque<Command>);

impl Deferred {
    pub fn pop(&mut self) -> Option<Command> {
        self.0.pop_front()
    }
}

/// Whether `cmd` may run while the world is ahead of the store.
fn safe_during_commit(cmd: &Command) -> bool {
    !matches!(cmd, Command::Admin(_) | Command::Stop)
}

impl Engine {
    /// Commits `batch`, serving safe commands from `rx` until it is durable.
    pub(super) fn commit_serving(
        &mut self,
        batch: &CommitBatch,
        rx: Option<&Inbox>,
    ) -> Result<CommitStats, StoreError> {
        let store = self.store.clone();
        let pool = self.pool.clone();
        std::thread::scope(|s| {
            // Its chunk encoding runs on the engine's workers.
            let commit = std::thread::Builder::new()
                .name("strata-commit".into())
                .spawn_scoped(s, move || pool.install(|| store.commit_batch(batch)));
            let commit = match commit {
                Ok(h) => h,
                // No thread to spare: commit here, serving nothing meanwhile.
                Err(_) => return self.store.commit_batch(batch),
            };
            while let Some(rx) = rx.filter(|_| !commit.is_finished()) {
                match rx.recv_timeout(COMMIT_POLL) {
                    Ok(cmd) if safe_during_commit(&cmd) => self.handle(cmd),
                    Ok(cmd) => self.deferred.0.push_back(cmd),
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
            }
            commit
                .join()
                .unwrap_or_else(|_| Err(std::io::Error::other("commit thread panicked").into()))
        })
    }
}
