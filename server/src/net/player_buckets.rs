//! Token buckets per player that outlive the player's sessions: its
//! requests (`[validation.request_rate]`) and its logins
//! (`[validation.join_rate]`). Reconnecting gives no fresh budget.

use std::collections::HashMap;

use crate::validate::ratelimit::{BucketConfig, TokenBucket};

/// One bucket a player, shared by its sessions and kept after they end
/// until it is full again. Holds at most `max_players` (the session
/// limit: every player with a session fits, and idle ones make room).
#[derive(Debug)]
pub struct PlayerBuckets {
    max_players: usize,
    players: std::sync::Mutex<HashMap<String, PlayerBucket>>,
}

#[derive(Debug)]
struct PlayerBucket {
    bucket: TokenBucket,
    /// Sessions of the player holding the bucket.
    sessions: u32,
}

impl PlayerBuckets {
    pub fn new(max_players: usize) -> Self {
        Self {
            max_players: max_players.max(1),
            players: Default::default(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, PlayerBucket>> {
        self.players.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A session of `player` starts: it draws on the player's bucket (a
    /// new, full one if there is none) until the returned hold drops.
    pub fn hold<'a>(&'a self, player: &str, cfg: BucketConfig, now_ms: u64) -> BucketHold<'a> {
        let mut players = self.lock();
        if !players.contains_key(player) && players.len() >= self.max_players {
            // Forget the buckets nobody holds that have refilled.
            players.retain(|_, p| {
                p.bucket.refill(now_ms);
                p.sessions > 0 || p.bucket.available() < p.bucket.capacity()
            });
            if players.len() >= self.max_players {
                // Still full of recently spent ones: the fullest idle one goes.
                let idle = players
                    .iter()
                    .filter(|(_, p)| p.sessions == 0)
                    .max_by_key(|(_, p)| p.bucket.available())
                    .map(|(name, _)| name.clone());
                if let Some(name) = idle {
                    players.remove(&name);
                }
            }
        }
        players
            .entry(player.to_string())
            .or_insert_with(|| PlayerBucket {
                bucket: TokenBucket::new(cfg, now_ms),
                sessions: 0,
            })
            .sessions += 1;
        BucketHold {
            buckets: self,
            player: player.to_string(),
            cfg,
        }
    }

    /// Players whose buckets are kept.
    pub fn tracked_players(&self) -> usize {
        self.lock().len()
    }
}

/// A session's claim on its player's bucket; released on drop.
#[derive(Debug)]
pub struct BucketHold<'a> {
    buckets: &'a PlayerBuckets,
    player: String,
    cfg: BucketConfig,
}

impl BucketHold<'_> {
    /// Runs `f` on the player's bucket, refilled to `now_ms`.
    fn with<T>(&self, now_ms: u64, f: impl FnOnce(&mut TokenBucket) -> T) -> T {
        let mut players = self.buckets.lock();
        let p = players
            .entry(self.player.clone())
            .or_insert_with(|| PlayerBucket {
                bucket: TokenBucket::new(self.cfg, now_ms),
                sessions: 1,
            });
        p.bucket.refill(now_ms);
        f(&mut p.bucket)
    }

    /// Takes `cost` tokens (at most the capacity) and returns 0, or
    /// returns how many milliseconds until they are there and takes none.
    /// For buckets that refill (`per_second` at least 1).
    pub fn spend(&self, cost: u64, now_ms: u64) -> u64 {
        self.with(now_ms, |b| {
            let cost = cost.min(b.capacity());
            match b.wait_ms(cost) {
                Some(0) | None => {
                    b.take(cost);
                    0
                }
                Some(ms) => ms,
            }
        })
    }

    /// Gives back `cost` tokens taken for something that did not happen
    /// (at most up to the capacity).
    pub fn give_back(&self, cost: u64, now_ms: u64) {
        self.with(now_ms, |b| b.give(cost));
    }

    /// Takes `cost` tokens, or takes none and says in how many
    /// milliseconds they would be there (`None`: never).
    pub fn try_take(&self, cost: u64, now_ms: u64) -> Result<(), Option<u64>> {
        self.with(now_ms, |b| match b.take(cost) {
            true => Ok(()),
            false => Err(b.wait_ms(cost)),
        })
    }
}

impl Drop for BucketHold<'_> {
    fn drop(&mut self) {
        if let Some(p) = self.buckets.lock().get_mut(&self.player) {
            p.sessions = p.sessions.saturating_sub(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_players_bucket_outlives_its_sessions_within_the_bound() {
        // Ten tokens, one every 100 ms.
        let cfg = BucketConfig {
            capacity: 10,
            per_second: 10,
        };
        let buckets = PlayerBuckets::new(2);
        let first = buckets.hold("ann", cfg, 0);
        assert_eq!(first.spend(10, 0), 0);
        drop(first);
        // A reconnect continues from the drained bucket, and a second
        // session of the player shares it.
        let again = buckets.hold("ann", cfg, 0);
        let other = buckets.hold("ann", cfg, 0);
        assert_eq!(again.spend(1, 0), 100);
        assert_eq!(other.spend(1, 50), 50);
        // A cost above the capacity waits for a full bucket, not forever.
        assert_eq!(other.spend(1_000, 100), 900);
        drop((again, other));
        let bob = buckets.hold("bob", cfg, 100);
        assert_eq!(buckets.tracked_players(), 2);
        // At the bound, a new player's bucket replaces a full idle one...
        let carl = buckets.hold("carl", cfg, 1_100);
        assert_eq!(buckets.tracked_players(), 2);
        assert_eq!(bob.spend(10, 1_100), 0);
        assert_eq!(carl.spend(10, 1_100), 0);
        drop(carl);
        // ...or, with none full, the fullest idle one: never a held one.
        let dan = buckets.hold("dan", cfg, 1_100);
        assert_eq!(buckets.tracked_players(), 2);
        assert_eq!(bob.spend(1, 1_100), 100, "bob's bucket was kept");
        assert_eq!(dan.spend(10, 1_100), 0, "dan's is new");
    }

    #[test]
    fn try_take_refuses_without_taking_and_says_when() {
        let cfg = BucketConfig {
            capacity: 2,
            per_second: 1,
        };
        let buckets = PlayerBuckets::new(4);
        let hold = buckets.hold("ann", cfg, 0);
        assert_eq!(hold.try_take(1, 0), Ok(()));
        assert_eq!(hold.try_take(1, 0), Ok(()));
        assert_eq!(hold.try_take(1, 0), Err(Some(1_000)));
        assert_eq!(hold.try_take(1, 400), Err(Some(600)), "nothing taken");
        assert_eq!(hold.try_take(1, 1_000), Ok(()));
        // A bucket that never refills says so.
        let dry = BucketConfig {
            capacity: 1,
            per_second: 0,
        };
        let hold = buckets.hold("bob", dry, 0);
        assert_eq!(hold.try_take(1, 0), Ok(()));
        assert_eq!(hold.try_take(1, 1_000_000), Err(None));
    }
}
