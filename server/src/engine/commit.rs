//! Group commit without stalling sessions: the tick's batch is written and
//! flushed on the engine's commit thread while the engine keeps taking
//! commands.
//!
//! While the commit runs, the world is one batch ahead of the store (two,
//! once the next tick was due and applied meanwhile: `Engine::tick`
//! chains its commit right after), so
//! only commands that cannot observe the difference are served: positions,
//! edit submissions (they queue for a later tick), subscriptions, resyncs
//! (the snapshot itself is built after the commit) and joins and leaves.
//! Admin requests, which read the store, and `Stop` wait until it is done.
//!
//! The commit thread lives as long as the engine. It hands each result
//! back on a channel and then wakes the engine through its inbox
//! ([`super::inbox::Waker`]), so the engine sleeps until a command or the
//! result arrives instead of polling.
//!
//! It also stores the players' positions (a flush and an fsync each
//! second), between two commits: the engine thread never waits on the
//! disk for them, and they never flush beside a commit.

use std::collections::VecDeque;
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::Arc;
use std::time::{Duration, Instant};

use tracing::error;

use super::inbox::Waker;
use super::{Applied, Command, Engine, Inbox};
use crate::metrics as m;
use crate::store::{ChunkStore, CommitBatch, CommitStats, StoreError};

/// Longest the engine sleeps between looks at a running commit, should a
/// wake be lost (a full player queue skips it; draining that queue looks
/// anyway).
pub const COMMIT_LOOK: Duration = Duration::from_millis(5);

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

type Done = (CommitBatch, Result<CommitStats, StoreError>);

/// Players and where they are.
pub type Positions = Vec<(String, crate::store::StoredPosition)>;

/// What the commit thread does, in the order it was handed.
#[derive(Debug)]
enum Job {
    /// Written, flushed and fsynced; the result goes back to the engine.
    /// Boxed: a job moves through a channel, and a batch is large.
    Commit(Box<CommitBatch>),
    /// Stored (flushed and fsynced); on a failure the players' names go
    /// back ([`Committer::take_unsaved`]) to be saved again. The engine
    /// hands one only while no commit runs, at most once per
    /// `POSITION_SAVE_EVERY`, so at most two jobs wait.
    Positions(Positions),
}

/// The engine's commit thread: one job at a time, in order.
#[derive(Debug)]
pub struct Committer {
    jobs: Option<mpsc::Sender<Job>>,
    done: mpsc::Receiver<Done>,
    /// Players whose positions a failed save left unsaved (one message a
    /// failed job: at most the jobs handed).
    unsaved: mpsc::Receiver<Vec<String>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Committer {
    /// Starts the thread; `waker` wakes the engine after each result. How
    /// each position save went is reported to `health` (a commit's result
    /// goes back to the engine, which reports it).
    pub fn spawn(
        store: Arc<dyn ChunkStore>,
        waker: Waker,
        health: Option<Arc<crate::health::Health>>,
    ) -> std::io::Result<Self> {
        let (jobs, todo) = mpsc::channel::<Job>();
        let (finished, done) = mpsc::channel::<Done>();
        let (failed, unsaved) = mpsc::channel::<Vec<String>>();
        let thread = std::thread::Builder::new()
            .name("strata-commit".into())
            .spawn(move || {
                for job in todo {
                    let batch = match job {
                        Job::Commit(batch) => *batch,
                        Job::Positions(moved) => {
                            let saved = store.save_positions(&moved);
                            if let Some(h) = &health {
                                h.report(crate::health::StoreWork::PositionSaves, &saved);
                            }
                            if let Err(e) = saved {
                                error!(error = %e, players = moved.len(), "saving player positions failed; they are saved again next time");
                                let _ = failed.send(moved.into_iter().map(|(p, _)| p).collect());
                            }
                            continue;
                        }
                    };
                    // Here, fsync included; a big batch's chunks are
                    // encoded on the workers (`ChunkStore::encode_on`).
                    let result = store.commit_batch(&batch);
                    if finished.send((batch, result)).is_err() {
                        return;
                    }
                    waker.wake();
                }
            })?;
        Ok(Self {
            jobs: Some(jobs),
            done,
            unsaved,
            thread: Some(thread),
        })
    }

    /// Hands `batch` to the thread; gives it back if the thread is gone.
    fn start(&self, batch: CommitBatch) -> Result<(), Box<CommitBatch>> {
        match self.send(Job::Commit(Box::new(batch))) {
            Err(Job::Commit(batch)) => Err(batch),
            _ => Ok(()),
        }
    }

    /// Hands `moved` to the thread to store; gives it back if the thread is
    /// gone.
    pub fn save_positions(&self, moved: Positions) -> Result<(), Positions> {
        match self.send(Job::Positions(moved)) {
            Err(Job::Positions(moved)) => Err(moved),
            _ => Ok(()),
        }
    }

    /// The players whose positions failed to save since the last call.
    pub fn take_unsaved(&self) -> Vec<String> {
        self.unsaved.try_iter().flatten().collect()
    }

    fn send(&self, job: Job) -> Result<(), Job> {
        match &self.jobs {
            Some(jobs) => jobs.send(job).map_err(|e| e.0),
            None => Err(job),
        }
    }
}

impl Committer {
    /// Ends the thread once it has done every job queued; returns the
    /// players whose positions a failed save left, none read yet.
    pub fn finish(mut self) -> Vec<String> {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.take_unsaved()
    }
}

impl Drop for Committer {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Engine {
    /// Commits `batch` on the commit thread, serving safe commands from
    /// `rx` until it is durable; returns the batch with the result. Once
    /// `due` has passed, the next tick's edits are applied meanwhile and
    /// returned too (they are not committed).
    pub(super) fn commit_serving(
        &mut self,
        batch: CommitBatch,
        rx: Option<&Inbox>,
        due: Option<Instant>,
    ) -> (
        CommitBatch,
        Result<CommitStats, StoreError>,
        Option<Applied>,
    ) {
        let Some(committer) = self.committer.take() else {
            let result = self.store.commit_batch(&batch);
            return (batch, result, None);
        };
        let (done, next) = match committer.start(batch) {
            Ok(()) => self.serve_until_done(&committer, rx, due),
            // No thread: commit here, serving nothing meanwhile.
            Err(batch) => {
                let result = self.store.commit_batch(&batch);
                ((*batch, result), None)
            }
        };
        self.committer = Some(committer);
        (done.0, done.1, next)
    }

    fn serve_until_done(
        &mut self,
        committer: &Committer,
        rx: Option<&Inbox>,
        mut due: Option<Instant>,
    ) -> (Done, Option<Applied>) {
        let lost = || {
            let err = std::io::Error::other("commit thread panicked");
            (CommitBatch::default(), Err(err.into()))
        };
        let Some(rx) = rx else {
            return (committer.done.recv().unwrap_or_else(|_| lost()), None);
        };
        let mut next = None;
        loop {
            match committer.done.try_recv() {
                Ok(done) => return (done, next),
                Err(mpsc::TryRecvError::Disconnected) => return (lost(), next),
                Err(mpsc::TryRecvError::Empty) => {}
            }
            let now = Instant::now();
            if let Some(at) = due.filter(|&at| now >= at) {
                // The next tick is due and this commit still runs: apply it
                // now, on the workers the fsync leaves idle. Applied once;
                // with nothing queued yet, the tick after is due a period
                // later, as it would be without a commit running.
                if self.seq.queued() + self.seq.sighting() == 0 {
                    due = Some(next_due(at, now, self.tick_period()));
                    continue;
                }
                due = None;
                next = Some(self.apply_tick());
                metrics::histogram!(m::TICK_PHASE_SECONDS, "phase" => "apply_ahead")
                    .record(now.elapsed().as_secs_f64());
                continue;
            }
            let wait = due.map_or(COMMIT_LOOK, |at| {
                at.saturating_duration_since(now).min(COMMIT_LOOK)
            });
            match rx.recv_or_wake(wait) {
                Ok(Some(cmd)) if safe_during_commit(&cmd) => self.handle(cmd),
                Ok(Some(cmd)) => self.deferred.0.push_back(cmd),
                Ok(None) => {}
                Err(RecvTimeoutError::Disconnected | RecvTimeoutError::Timeout) => {
                    return (committer.done.recv().unwrap_or_else(|_| lost()), next);
                }
            }
        }
    }
}

/// The first tick boundary after `now` of ticks due every `period` from
/// `at`: when the next tick is due at `at` but finds nothing queued, the
/// one after it.
fn next_due(at: Instant, now: Instant, period: Duration) -> Instant {
    let period = period.max(Duration::from_nanos(1));
    let behind = now.saturating_duration_since(at).as_nanos();
    let periods = behind / period.as_nanos() + 1;
    at + period.saturating_mul(u32::try_from(periods).unwrap_or(u32::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_due_tick_is_followed_by_the_next_boundary_after_now() {
        let at = Instant::now();
        let p = Duration::from_millis(10);
        assert_eq!(next_due(at, at, p), at + p);
        assert_eq!(next_due(at, at + p / 2, p), at + p);
        assert_eq!(next_due(at, at + p, p), at + 2 * p, "a boundary is passed");
        assert_eq!(next_due(at, at + p * 5 / 2, p), at + 3 * p);
        // A zero period still moves on.
        assert!(next_due(at, at, Duration::ZERO) > at);
    }
}
