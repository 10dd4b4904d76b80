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
    /// Sessions of this player still connected; the limits are dropped at 0.
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
