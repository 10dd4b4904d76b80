//! Player session slots, by player. At a full server, a login takes the
//! slot of its own player's oldest session when its Join would end that
//! session anyway (`[engine] sessions_per_player`): a session its client
//! left behind, its connection not yet timed out, never keeps its player
//! out. Another player's slot is never taken.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};

/// The players' pool of session slots and who holds them. Its map holds
/// only players with a slot: at most `[server] max_connections` entries.
#[derive(Debug)]
pub struct PlayerSlots {
    pool: Arc<Semaphore>,
    /// Live sessions one player may have; a login past it ends the oldest.
    per_player: usize,
    /// Each player's slots.
    held: Mutex<HashMap<String, Vec<Arc<Held>>>>,
}

#[derive(Debug)]
struct Held {
    /// Its session's id: the order connections came in, which the engine
    /// ends a player's sessions by.
    session: u64,
    permit: Mutex<Option<OwnedSemaphorePermit>>,
    replaced: AtomicBool,
    wake: Notify,
}

impl PlayerSlots {
    pub fn new(pool: Arc<Semaphore>, per_player: usize) -> Arc<Self> {
        Arc::new(Self {
            pool,
            per_player: per_player.max(1),
            held: Mutex::new(HashMap::new()),
        })
    }

    /// A slot for session `session` of `player`: a free one, or, with
    /// none free, the one of `player`'s oldest session (lowest id) when
    /// `player` has all its sessions already (that session is told,
    /// [`PlayerSlot::replaced`]). `None`: the server is full.
    pub fn take(self: &Arc<Self>, player: &str, session: u64) -> Option<PlayerSlot> {
        let mut held = lock(&self.held);
        let permit = match self.pool.clone().try_acquire_owned() {
            Ok(p) => p,
            Err(_) => {
                let mine = held.get_mut(player)?;
                if mine.len() < self.per_player {
                    return None;
                }
                let at = (0..mine.len()).min_by_key(|&i| mine[i].session)?;
                let oldest = mine.remove(at);
                let permit = lock(&oldest.permit).take()?;
                oldest.replaced.store(true, Ordering::Release);
                oldest.wake.notify_one();
                permit
            }
        };
        let slot = Arc::new(Held {
            session,
            permit: Mutex::new(Some(permit)),
            replaced: AtomicBool::new(false),
            wake: Notify::new(),
        });
        held.entry(player.to_string())
            .or_default()
            .push(slot.clone());
        Some(PlayerSlot {
            slots: self.clone(),
            player: player.to_string(),
            held: slot,
        })
    }
}

/// A player session's slot, held for the session's life. Dropping it
/// frees the slot (unless a newer login of the player took it).
#[derive(Debug)]
pub struct PlayerSlot {
    slots: Arc<PlayerSlots>,
    player: String,
    held: Arc<Held>,
}

impl PlayerSlot {
    /// Resolves once a newer login of the same player took this slot: the
    /// session should end.
    pub async fn replaced(&self) {
        while !self.is_replaced() {
            self.held.wake.notified().await;
        }
    }

    pub fn is_replaced(&self) -> bool {
        self.held.replaced.load(Ordering::Acquire)
    }
}

impl Drop for PlayerSlot {
    fn drop(&mut self) {
        let mut held = lock(&self.slots.held);
        if let Some(mine) = held.get_mut(&self.player) {
            mine.retain(|h| !Arc::ptr_eq(h, &self.held));
            if mine.is_empty() {
                held.remove(&self.player);
            }
        }
        drop(lock(&self.held.permit).take());
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn slots(sessions: usize, per_player: usize) -> Arc<PlayerSlots> {
        PlayerSlots::new(Arc::new(Semaphore::new(sessions)), per_player)
    }

    #[tokio::test]
    async fn a_full_server_lets_a_player_in_on_its_own_oldest_slot_only() {
        let s = slots(2, 1);
        let ana = s.take("ana", 1).unwrap();
        let _bo = s.take("bo", 2).unwrap();
        assert!(s.take("cy", 3).is_none(), "full, and cy holds nothing");
        let ana_again = s.take("ana", 4).expect("ana's own slot");
        tokio::time::timeout(Duration::from_secs(1), ana.replaced())
            .await
            .expect("the older session is told");
        assert!(!ana_again.is_replaced());
        assert_eq!(s.pool.available_permits(), 0, "still two in all");
        // The replaced session's end frees nothing: its slot is ana's now.
        drop(ana);
        assert!(s.take("cy", 5).is_none());
        drop(ana_again);
        assert!(s.take("cy", 6).is_some(), "a slot freed");
        assert_eq!(lock(&s.held).len(), 1, "only bo's left");
    }

    #[tokio::test]
    async fn a_player_below_its_sessions_takes_no_slot_of_its_own() {
        let s = slots(3, 2);
        // Admitted out of their connections' order: 7 before 5.
        let seventh = s.take("ana", 7).unwrap();
        let fifth = s.take("ana", 5).unwrap();
        let bo = s.take("bo", 6).unwrap();
        assert!(
            s.take("bo", 8).is_none(),
            "a second bo would end none: full"
        );
        let ninth = s.take("ana", 9).expect("past its two: the oldest's");
        assert!(
            fifth.is_replaced(),
            "the lowest id, as the engine ends them"
        );
        assert!(!seventh.is_replaced() && !ninth.is_replaced() && !bo.is_replaced());
        drop((fifth, seventh, ninth, bo));
        assert_eq!(s.pool.available_permits(), 3, "no slot leaked");
        assert!(lock(&s.held).is_empty());
    }
}
