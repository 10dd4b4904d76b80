//! The engine's view of one connected session: what it sees, what it has,
//! and what it still needs to be sent.

use std::collections::{HashSet, VecDeque};
use std::sync::Arc;

use rustc_hash::FxHashMap;

use strata_terrain::ChunkPos;

use strata_protocol::ErrorCode;
use tokio::sync::oneshot;

use super::command::Kick;
use super::LatestPosition;
use crate::interest::{Interest, InterestChange};
use crate::net::writer::FrameSender;

#[derive(Debug)]
pub struct Peer {
    pub control: FrameSender,
    pub updates: FrameSender,
    pub interest: Interest,
    /// Chunk versions the client holds (sent to it, in order). Fx-hashed:
    /// fanout looks up every change in every nearby session's map.
    pub known: FxHashMap<ChunkPos, u64>,
    /// Chunks to send as snapshots, nearest first.
    pub pending: VecDeque<ChunkPos>,
    /// Chunks the client asked to receive as full data even at version 0.
    pub full_data: HashSet<ChunkPos>,
    /// Set when a queue overflowed and the connection should be closed.
    pub failed: bool,
    /// The chunk around which collision meshes were last queued.
    pub premeshed: Option<ChunkPos>,
    /// The newest position report not yet handled.
    pub position: Arc<LatestPosition>,
    /// `Hello::capabilities` bits this server knows (the rest dropped).
    pub capabilities: u32,
    kick: Option<oneshot::Sender<Kick>>,
}

impl Peer {
    pub fn new(
        control: FrameSender,
        updates: FrameSender,
        interest: Interest,
        kick: oneshot::Sender<Kick>,
        position: Arc<LatestPosition>,
    ) -> Self {
        Self {
            control,
            updates,
            interest,
            known: FxHashMap::default(),
            pending: VecDeque::new(),
            full_data: HashSet::new(),
            failed: false,
            premeshed: None,
            position,
            capabilities: 0,
            kick: Some(kick),
        }
    }

    /// Tells the session to close its connection with `code`.
    pub fn kick(&mut self, code: ErrorCode, message: &str) {
        if let Some(k) = self.kick.take() {
            let _ = k.send((code, message.to_string()));
        }
    }

    /// Queues new chunks (already nearest first) and forgets dropped ones.
    /// Returns the chunks the client should be told to unload.
    pub fn apply_interest(&mut self, change: InterestChange) -> Vec<ChunkPos> {
        for pos in &change.unsubscribe {
            self.known.remove(pos);
            self.full_data.remove(pos);
        }
        self.pending.retain(|p| !change.unsubscribe.contains(p));
        // Re-queue the whole subscription so it stays sorted nearest first.
        let mut queued: HashSet<ChunkPos> = self.pending.iter().copied().collect();
        for pos in change.subscribe {
            if !self.known.contains_key(&pos) && queued.insert(pos) {
                self.pending.push_back(pos);
            }
        }
        change.unsubscribe
    }

    /// Whether the client asked for `cap` (`strata_protocol::capabilities`).
    pub fn has(&self, cap: u32) -> bool {
        strata_protocol::capabilities::has(self.capabilities, cap)
    }

    /// Forgets the client's copy of `pos` and sends it again first.
    pub fn resend(&mut self, pos: ChunkPos) {
        self.known.remove(&pos);
        if !self.pending.contains(&pos) {
            self.pending.push_front(pos);
        }
    }
}
