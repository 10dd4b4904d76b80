//! Per-session and per-player validation state.

use strata_protocol::Role;

use crate::validate::ratelimit::TokenBucket;
use crate::validate::{ValidatedPosition, ValidationConfig};

/// A connected session as the sequencer sees it.
#[derive(Debug, Clone)]
pub struct Session {
    pub player: String,
    pub role: Role,
    /// Last position that passed every rule; `None` until the first one.
    pub position: Option<ValidatedPosition>,
}

/// A player's rate limits, shared by all of the player's sessions so
/// reconnecting or opening a second session gives no extra budget.
#[derive(Debug, Clone)]
pub struct PlayerLimits {
    pub edits: TokenBucket,
    pub volume: TokenBucket,
    /// Sessions of this player still connected.
    pub sessions: u32,
}

impl PlayerLimits {
    pub fn new(cfg: &ValidationConfig, now_ms: u64) -> Self {
        Self {
            edits: TokenBucket::new(cfg.edit_rate, now_ms),
            volume: TokenBucket::new(cfg.volume_rate, now_ms),
            sessions: 0,
        }
    }
}

impl PlayerLimits {
    /// Whether both buckets are full at `now_ms` (refilling them).
    pub fn is_full(&mut self, now_ms: u64) -> bool {
        self.edits.refill(now_ms);
        self.volume.refill(now_ms);
        self.edits.available() == self.edits.capacity()
            && self.volume.available() == self.volume.capacity()
    }
}
