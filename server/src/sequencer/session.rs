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
    /// Of those, the last this node judged whole: its feet in a region it
    /// sweeps, its own or one it read as free (alone on its store: every
    /// one), or a resume or arrival. A cluster node treats other regions
    /// as air, so only this one leaves it, in a ticket or a stored
    /// position: the node holding the region sweeps the way on from there
    /// through its walls.
    pub judged: Option<ValidatedPosition>,
    /// When the player was last seen anywhere, as its resume found it
    /// (another session's report, this node's memory, the store's row, not
    /// lessened for tickets' age); 0 when unknown. An arrival's grace
    /// covers the walk seen since its ticket, not the ticket's whole age.
    pub seen_ms: u64,
    /// Where the player was seen at `seen_ms` (the same record).
    pub seen_feet: Option<strata_terrain::edit::FixedVec3>,
}

/// A player's rate limits, shared by all of the player's sessions so
/// reconnecting or opening a second session gives no extra budget.
#[derive(Debug, Clone)]
pub struct PlayerLimits {
    pub edits: TokenBucket,
    pub volume: TokenBucket,
    /// Refused edits; when it runs dry the player's session is disconnected.
    pub rejections: TokenBucket,
    /// Reports of sessions with no position yet (`[validation.placement_rate]`).
    pub placements: TokenBucket,
    /// Sessions of this player still connected.
    pub sessions: u32,
}

impl PlayerLimits {
    pub fn new(cfg: &ValidationConfig, now_ms: u64) -> Self {
        Self {
            edits: TokenBucket::new(cfg.edit_rate, now_ms),
            volume: TokenBucket::new(cfg.volume_rate, now_ms),
            rejections: TokenBucket::new(cfg.reject_rate, now_ms),
            placements: TokenBucket::new(cfg.placement_rate, now_ms),
            sessions: 0,
        }
    }
}

impl PlayerLimits {
    /// Adds what every bucket earned since the last refill.
    pub fn refill(&mut self, now_ms: u64) {
        self.edits.refill(now_ms);
        self.volume.refill(now_ms);
        self.rejections.refill(now_ms);
        self.placements.refill(now_ms);
    }

    /// Whether every bucket is full at `now_ms` (refilling them).
    pub fn is_full(&mut self, now_ms: u64) -> bool {
        self.refill(now_ms);
        [
            &self.edits,
            &self.volume,
            &self.rejections,
            &self.placements,
        ]
        .iter()
        .all(|b| b.available() == b.capacity())
    }
}
