//! The engine's view of one connected session: what it sees, what it has,
//! and what it still needs to be sent.

use std::collections::HashSet;
use std::sync::Arc;

use bytes::{Bytes, BytesMut};
use rustc_hash::FxHashMap;

use strata_terrain::ChunkPos;

use strata_protocol::{ErrorCode, Start, WorldUpdate};
use tokio::sync::oneshot;

use super::command::Kick;
use super::holders::Holders;
use super::pending::Pending;
use super::LatestPosition;
use crate::interest::{nearest_first, Anchor, Interest, InterestChange};
use crate::net::writer::{FrameSender, Handed, SendRefused};

/// Most bytes one chunk position takes in an `UnsubscribedMany`: three
/// varints of at most 5 bytes.
const WITHDRAWN_POS_BYTES: usize = 15;
/// Most bytes of an `UnsubscribedMany` frame besides its positions: the
/// frame's header, the message's tags and the list's length.
const WITHDRAWAL_FRAME_BYTES: usize = 32;

#[derive(Debug)]
pub struct Peer {
    pub control: FrameSender,
    pub updates: FrameSender,
    pub interest: Interest,
    /// Chunk versions the client holds (sent to it, in order). Private:
    /// a chunk becomes held only through [`Self::receive`], which lists it
    /// in the engine's [`Holders`] too.
    known: FxHashMap<ChunkPos, u64>,
    /// Chunks the client was sent that `known` no longer lists because
    /// they are to be sent again ([`Self::resend`]: a resync, a
    /// full-snapshot request): its copy may still be there, so one that
    /// leaves the view or is forgotten before the new copy goes is owed a
    /// withdrawal all the same. At most the view's chunks.
    resent: HashSet<ChunkPos>,
    /// Chunks to send as snapshots, nearest first.
    pub pending: Pending,
    /// Chunks the client asked to receive as full data even at version 0.
    pub full_data: HashSet<ChunkPos>,
    /// Set when a queue overflowed and the connection should be closed:
    /// from then on nothing more is sent to it ([`Self::send_update`],
    /// [`Self::send_control`]), so it never sees a later verdict or delta
    /// after one it missed.
    pub failed: bool,
    /// The chunk around which collision meshes were last queued.
    pub premeshed: Option<ChunkPos>,
    /// The newest position report not yet handled.
    pub position: Arc<LatestPosition>,
    /// `Hello::capabilities` bits this server knows (the rest dropped).
    pub capabilities: u32,
    /// Where the session started (`Welcome::start`): before an accepted
    /// position, its subscriptions stay near it.
    pub start: Start,
    /// The view changed and its `InterestComplete` is owed once `pending`
    /// is empty.
    pub complete_due: bool,
    /// When (ms) the last `PositionRefused` was sent, for its rate bound.
    pub refused_at: Option<u64>,
    /// The regions and holders last sent in `RegionOwners` (cluster only).
    pub owners_told: Vec<strata_protocol::RegionOwner>,
    /// When (ms) the ticket last sent was minted.
    pub ticket_ms: Option<u64>,
    /// Chunks whose changes were dropped on a full updates queue: the
    /// client's copies are stale, and it is told to drop them
    /// (`UnsubscribedMany`) before anything else reaches its updates
    /// stream ([`Self::send_update`]). Each is also waiting in `pending`,
    /// not held, so no chunk is listed twice and the list is bounded by
    /// the view.
    withdraw: Vec<ChunkPos>,
    /// The chunks of `withdraw`, for a membership test in constant time.
    withdrawing: HashSet<ChunkPos>,
    /// Times `withdraw` was encoded for the updates stream.
    #[cfg(test)]
    pub withdrawals_encoded: usize,
    /// The fan-out queued a batch of changes since the stream last sent a
    /// batch of chunks: one such batch queued does not hold the stream
    /// back ([`Self::may_stream`]).
    pub changes_queued: bool,
    kick: Option<oneshot::Sender<Kick>>,
}

impl Peer {
    pub fn new(
        control: FrameSender,
        updates: FrameSender,
        interest: Interest,
        kick: oneshot::Sender<Kick>,
        position: Arc<LatestPosition>,
        start: Start,
    ) -> Self {
        Self {
            control,
            updates,
            interest,
            known: FxHashMap::default(),
            resent: HashSet::new(),
            pending: Pending::default(),
            full_data: HashSet::new(),
            failed: false,
            premeshed: None,
            position,
            capabilities: 0,
            start,
            complete_due: false,
            refused_at: None,
            owners_told: Vec::new(),
            ticket_ms: None,
            withdraw: Vec::new(),
            withdrawing: HashSet::new(),
            #[cfg(test)]
            withdrawals_encoded: 0,
            changes_queued: false,
            kick: Some(kick),
        }
    }

    /// What a `Subscribe` centre must stay near before any accepted position.
    pub fn start_anchor(&self) -> Anchor {
        Anchor::of_start(self.start)
    }

    /// Whether the session was told to close already.
    pub fn is_kicked(&self) -> bool {
        self.kick.is_none()
    }

    /// Tells the session to close its connection with `code`.
    pub fn kick(&mut self, code: ErrorCode, message: &str) {
        if let Some(k) = self.kick.take() {
            let _ = k.send((code, message.to_string()));
        }
    }

    /// The version of `pos` the client holds, if it holds it.
    pub fn held(&self, pos: ChunkPos) -> Option<u64> {
        self.known.get(&pos).copied()
    }

    /// Every chunk the client holds, with its version.
    pub fn holdings(&self) -> &FxHashMap<ChunkPos, u64> {
        &self.known
    }

    /// The client was sent `pos` whole at `version`: it holds it now, and
    /// `holders` lists it as session `id`'s.
    pub fn receive(&mut self, holders: &mut Holders, id: u64, pos: ChunkPos, version: u64) {
        self.known.insert(pos, version);
        self.resent.remove(&pos);
        holders.add(pos, id);
    }

    /// Whether the client may hold `pos` (sent, or sent and to be sent
    /// again): takes it off both lists.
    fn take_sent(&mut self, pos: ChunkPos) -> bool {
        let known = self.known.remove(&pos).is_some();
        self.resent.remove(&pos) || known
    }

    /// The client was sent the changes of a chunk it holds, up to `version`.
    pub fn advance(&mut self, pos: ChunkPos, version: u64) {
        if let Some(v) = self.known.get_mut(&pos) {
            *v = version;
        }
    }

    /// Unlists every chunk of session `id` (the session is ending): every
    /// chunk it is listed for lies in its view (a chunk leaving the view is
    /// unlisted), held or waiting to be sent again after a resend.
    pub fn unlist_all(&self, holders: &mut Holders, id: u64) {
        for pos in self.interest.subscribed() {
            holders.remove(pos, id);
        }
    }

    /// Queues new chunks and forgets dropped ones (unlisting them for
    /// session `id`); the whole queue (chunks still waiting from earlier
    /// views included) is then nearest first from the new centre. Those
    /// the client was sent are withdrawn ([`Self::withdraw`]): owed, and
    /// sent now if the updates queue has room, else before its next
    /// update (a lagging client is served late, not failed).
    pub fn apply_interest(&mut self, holders: &mut Holders, id: u64, change: InterestChange) {
        let mut sent = Vec::new();
        for &pos in &change.unsubscribe {
            if self.take_sent(pos) {
                sent.push(pos);
            }
            holders.remove(pos, id);
            self.full_data.remove(&pos);
            self.pending.remove(pos);
        }
        self.withdraw(sent);
        for pos in change.subscribe {
            if !self.known.contains_key(&pos) {
                self.pending.push_back(pos);
            }
        }
        if let Some(center) = self.interest.center().filter(|_| change.recentred) {
            self.pending.sort_by_key(|p| nearest_first(*p, center));
            self.complete_due = true;
        }
    }

    /// Tells the client to drop `chunks` it was sent (`UnsubscribedMany`):
    /// owed, and sent ahead of any later update, now if the updates queue
    /// has room ([`Self::confirm_withdrawals`]).
    pub fn withdraw(&mut self, chunks: impl IntoIterator<Item = ChunkPos>) {
        let mut any = false;
        for pos in chunks {
            self.owe_withdrawal(pos);
            any = true;
        }
        // Only for new ones: a request that withdrew nothing encodes nothing.
        if any {
            self.confirm_withdrawals();
        }
    }

    /// Whether `pos` goes to the client whole even at version 0: it asked
    /// so, or it is a thin client (no generator) that gets every chunk whole.
    pub fn wants_full(&self, pos: ChunkPos) -> bool {
        self.full_data.contains(&pos) || self.has(strata_protocol::CAP_SNAPSHOTS)
    }

    /// Whether the client asked for `cap` (`strata_protocol::capabilities`).
    pub fn has(&self, cap: u32) -> bool {
        strata_protocol::capabilities::has(self.capabilities, cap)
    }

    /// The client dropped `chunks`: those in view are no longer held (nor
    /// listed for session `id`), so no update of them is sent until a
    /// resync or until they leave the view and come back. Others are ignored.
    /// Each one the client was sent is owed an `UnsubscribedMany` (see
    /// [`Self::send_update`]): on the updates stream after everything sent
    /// before, it tells the client nothing more of the chunk is on its way.
    /// Without it a chunk sent again after a withdrawal the client read
    /// before the server took its `Forget` would be held, and never updated.
    /// Whether any withdrawal was owed for it (then the caller confirms).
    pub fn forget(&mut self, holders: &mut Holders, id: u64, chunks: &[ChunkPos]) -> bool {
        let dropped: HashSet<ChunkPos> = chunks
            .iter()
            .copied()
            .filter(|p| self.interest.covers(*p))
            .collect();
        // Work in proportion to the chunks named, never to the queue.
        let mut owed = false;
        for pos in &dropped {
            if self.take_sent(*pos) {
                self.owe_withdrawal(*pos);
                owed = true;
            }
            holders.remove(*pos, id);
            self.pending.remove(*pos);
        }
        owed
    }

    /// Whether the stream may hand this session a batch of chunks now:
    /// its writer has taken everything queued, or what it has not taken is
    /// one batch of changes the fan-out queued since the stream's last
    /// batch (queued at the tick's end, it would otherwise keep a session
    /// that sees changes every tick from ever filling its view). Either
    /// way a change queued next waits behind one batch of chunks at most.
    pub fn may_stream(&self) -> bool {
        self.updates.is_idle() || (self.changes_queued && self.updates.queued() == 1)
    }

    /// Whether withdrawals are owed ([`Self::send_update`] sends them first).
    pub fn owes_withdrawals(&self) -> bool {
        !self.withdraw.is_empty()
    }

    fn owe_withdrawal(&mut self, pos: ChunkPos) {
        self.resent.remove(&pos);
        if self.withdrawing.insert(pos) {
            self.withdraw.push(pos);
        }
    }

    /// Sends the withdrawals owed now (a `Forget`'s confirmation), if the
    /// updates queue has room. With none (a client that does not read)
    /// they stay owed for the next batch, and nothing is encoded: else
    /// each `Forget` of a client keeping its queue full would encode the
    /// whole list again, work out of proportion to the request.
    ///
    /// The room asked for is the frames' size at most, so a queue whose
    /// bytes are nearly at their bound encodes nothing either; a writer
    /// gone fails the session (dropped at the tick's end) rather than
    /// leaving it owed forever.
    pub fn confirm_withdrawals(&mut self) {
        if !self.owes_withdrawals() {
            return;
        }
        if self.updates.is_closed() {
            self.failed = true;
            return;
        }
        if self.updates.has_room_for(self.withdrawal_bytes()) {
            if let Err(SendRefused::Closed) = self.send_update(Bytes::new(), false) {
                self.failed = true;
            }
        }
    }

    /// At most the bytes the withdrawals owed encode to: a chunk position
    /// is three varints, each 5 bytes at most, and each frame of them has
    /// its header and tags.
    fn withdrawal_bytes(&self) -> usize {
        let frames = self
            .withdraw
            .len()
            .div_ceil(strata_protocol::limits::MAX_UNSUBSCRIBED_PER_UPDATE);
        self.withdraw.len() * WITHDRAWN_POS_BYTES + frames * WITHDRAWAL_FRAME_BYTES
    }

    /// The changes of `chunks` (all held) were not sent: each is sent
    /// again whole, after the client is told to drop its stale copy. Until
    /// then a neighbour's change would be meshed against it.
    pub fn dropped(&mut self, chunks: &[ChunkPos]) {
        for &pos in chunks {
            if self.known.contains_key(&pos) {
                self.resend(pos);
                self.owe_withdrawal(pos);
            }
        }
    }

    /// Chunks owed an `UnsubscribedMany` before the next update.
    #[cfg(test)]
    pub fn withdrawals_owed(&self) -> &[ChunkPos] {
        &self.withdraw
    }

    /// Hands `batch` (whole update frames) to the updates stream, after
    /// the withdrawals owed ([`Self::dropped`]); `direct`: written into the
    /// stream when it can go at once ([`FrameSender::send_now`]). On
    /// failure nothing was sent and the withdrawals stay owed.
    pub fn send_update(&mut self, batch: Bytes, direct: bool) -> Result<Handed, SendRefused> {
        if self.failed {
            return Err(SendRefused::Closed);
        }
        let batch = if self.withdraw.is_empty() {
            batch
        } else {
            #[cfg(test)]
            {
                self.withdrawals_encoded += 1;
            }
            let mut buf = BytesMut::new();
            for part in self
                .withdraw
                .chunks(strata_protocol::limits::MAX_UNSUBSCRIBED_PER_UPDATE)
            {
                let update = WorldUpdate::UnsubscribedMany {
                    chunks: part.to_vec(),
                };
                buf.extend_from_slice(&super::fanout::encode_update(&update));
            }
            buf.extend_from_slice(&batch);
            buf.freeze()
        };
        let sent = if direct {
            self.updates.send_now(batch)
        } else {
            self.updates.try_send(batch).map(|()| Handed::Queued)
        };
        if sent.is_ok() {
            self.withdraw.clear();
            self.withdrawing.clear();
        }
        sent
    }

    /// Queues a control frame (a verdict, a notice). One that does not fit
    /// fails the session: control frames are never dropped silently.
    /// Returns whether it was queued.
    pub fn send_control(&mut self, frame: Bytes) -> bool {
        if self.failed {
            return false;
        }
        let sent = self.control.try_send(frame).is_ok();
        self.failed = !sent;
        sent
    }

    /// Forgets the client's copy of `pos` and sends it again first. The
    /// engine's [`Holders`] may still list it: the fan-out unlists it the
    /// next time it finds it not held.
    pub fn resend(&mut self, pos: ChunkPos) {
        if self.known.remove(&pos).is_some() {
            self.resent.insert(pos);
        }
        self.pending.push_front(pos);
    }
}
