//! A session's share of the engine's player queue: at most `[engine]
//! session_commands` of its commands wait there at once, so no client's
//! burst of cheap requests fills the queue every player shares.
//!
//! A counted command carries a [`QueueSlot`] from when the session queues
//! it until the engine takes it off the queue (`inbox.rs` drops the slot
//! there). A session at its share waits for one of its own commands to be
//! taken, or answers an edit `Busy`; other sessions are not held up.
//! Position notices are not counted: [`super::LatestPosition`] keeps at
//! most one per session queued.

use std::sync::Arc;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Default commands one session may have waiting in the player queue:
/// 256 sessions at their share fill half of the default queue (8192).
pub const DEFAULT_SESSION_COMMANDS: usize = 16;

/// One session's share of the player queue.
#[derive(Debug, Clone)]
pub struct SessionShare {
    slots: Arc<Semaphore>,
    limit: usize,
}

/// A place in a session's share, held by one queued command; given back
/// when dropped.
#[derive(Debug)]
pub struct QueueSlot(#[allow(dead_code)] OwnedSemaphorePermit);

impl SessionShare {
    /// A share of `limit` commands (at least one).
    pub fn new(limit: usize) -> Self {
        let limit = limit.clamp(1, Semaphore::MAX_PERMITS);
        Self {
            slots: Arc::new(Semaphore::new(limit)),
            limit,
        }
    }

    /// A slot if the session has one free.
    pub fn try_take(&self) -> Option<QueueSlot> {
        self.slots.clone().try_acquire_owned().ok().map(QueueSlot)
    }

    /// A slot, waiting until the engine takes one of the session's
    /// commands if all are in use (`None` only if the share was closed,
    /// which nothing does).
    pub async fn take(&self) -> Option<QueueSlot> {
        self.slots.clone().acquire_owned().await.ok().map(QueueSlot)
    }

    /// The session's commands now in the queue.
    pub fn in_use(&self) -> usize {
        self.limit - self.slots.available_permits()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn a_session_at_its_share_waits_until_one_of_its_slots_comes_back() {
        let share = SessionShare::new(2);
        let a = share.try_take().expect("first slot");
        let _b = share.try_take().expect("second slot");
        assert!(share.try_take().is_none(), "the share is used up");
        assert_eq!(share.in_use(), 2);
        // Another session's share is its own.
        let other = SessionShare::new(2);
        assert!(other.try_take().is_some());
        let waiting = tokio::time::timeout(Duration::from_millis(50), share.take()).await;
        assert!(waiting.is_err(), "no slot until one is given back");
        // The engine takes a command (on its own thread): the slot returns.
        std::thread::spawn(move || drop(a)).join().unwrap();
        let c = tokio::time::timeout(Duration::from_secs(5), share.take()).await;
        assert!(matches!(c, Ok(Some(_))), "woken by the slot given back");
        assert_eq!(share.in_use(), 2);
    }

    #[test]
    fn a_share_has_at_least_one_slot() {
        let share = SessionShare::new(0);
        let _held = share.try_take().expect("one slot");
        assert!(share.try_take().is_none());
    }
}
