//! Serving one command from a session or an operator, between ticks.

use std::time::Instant;

use strata_protocol::{ErrorCode, Refusal, ServerMessage};
use tracing::{info, warn};

use super::peer::Peer;
use super::{fanout, now_ms, Command, Engine, JoinReply};
use crate::interest::{Anchor, Interest};
use crate::metrics as m;

impl Engine {
    pub(super) fn handle(&mut self, cmd: Command) {
        let now = now_ms();
        match cmd {
            Command::Join {
                session,
                player,
                role,
                control,
                updates,
                reply,
                kick,
                position,
                capabilities,
                stored,
            } => {
                // A new login replaces the player's oldest sessions past the
                // cap, by id (the order their connections came, as the
                // session slots go): this one too, when a newer login's
                // Join came first.
                let mut all = self.sessions_of(&player);
                all.push(session);
                all.sort_unstable();
                let excess = all
                    .len()
                    .saturating_sub(self.cfg.sessions_per_player.max(1));
                let replaced: Vec<u64> = all.drain(..excess).collect();
                for &id in replaced.iter().filter(|&&id| id != session) {
                    info!(session = id, %player, "replaced by a newer login");
                    self.end_session(id, ErrorCode::Kicked, super::REPLACED);
                }
                // A cluster node's session read where the player was last
                // saved: a node that had it since knows a newer place and
                // time, and an older ticket must not take it back there.
                self.seq.session_joined(session, player, role);
                let start = self.seq.resume_position(session, now, stored.map(|p| *p));
                metrics::counter!(m::SESSIONS_TOTAL).increment(1);
                let interest = Interest::new(self.interest, self.bounds);
                let mut peer = Peer::new(control, updates, interest, kick, position, start);
                peer.capabilities = capabilities;
                if let Some(old) = self.peers.insert(session, peer) {
                    old.unlist_all(&mut self.holders, session);
                }
                // A join may arrive mid-commit: name no seq a power cut could
                // still take back.
                let _ = reply.send(JoinReply {
                    last_seq: self.durable_seq,
                    start,
                });
                if replaced.contains(&session) {
                    info!(session, "replaced by a newer login before it joined");
                    self.end_session(session, ErrorCode::Kicked, super::REPLACED);
                }
            }
            Command::Leave { session } => {
                self.seq.session_left(session);
                if let Some(p) = self.peers.remove(&session) {
                    p.unlist_all(&mut self.holders, session);
                }
            }
            Command::Edit {
                session,
                request,
                received,
            } => {
                metrics::histogram!(m::EDIT_INBOX_SECONDS).record(received.elapsed().as_secs_f64());
                self.submit(session, request, now)
            }
            Command::Position { session } => {
                let update = self.peers.get(&session).and_then(|p| p.position.take());
                if let Some(update) = update {
                    self.position(session, update, now);
                }
            }
            Command::Subscribe {
                session,
                center,
                radius,
            } => {
                // Admins may look anywhere; players only around themselves,
                // or before any position, around their start: the whole
                // view within reach (`Interest::within_reach`).
                let player = match self.seq.session(session) {
                    Some(s) if s.role == strata_protocol::Role::Admin => None,
                    Some(_) => Some(self.seq.position(session).map(|p| {
                        Anchor::Chunk(crate::validate::position::feet_voxel(p.feet).chunk())
                    })),
                    None => return,
                };
                let Some(p) = self.peers.get_mut(&session) else {
                    return;
                };
                let allowed = match player {
                    None => Ok(false),
                    Some(at) => {
                        let anchor = at.unwrap_or_else(|| p.start_anchor());
                        p.interest
                            .check_centre(center, radius, anchor)
                            .map(|()| true)
                    }
                };
                match allowed {
                    Ok(near) => {
                        let change = if near {
                            p.interest.subscribe(center, radius)
                        } else {
                            p.interest.subscribe_anywhere(center, radius)
                        };
                        self.apply_interest(session, change);
                    }
                    Err(max) => {
                        let refusal = Refusal::SubscribeTooFar { center, max };
                        self.send_control(session, &ServerMessage::RequestRefused(refusal));
                    }
                }
            }
            Command::Resync { session, pos } | Command::FullSnapshot { session, pos } => {
                let full = matches!(cmd, Command::FullSnapshot { .. });
                let Some(p) = self.peers.get_mut(&session) else {
                    return;
                };
                if p.interest.covers(pos) {
                    metrics::counter!(m::RESYNCS).increment(1);
                    if full {
                        p.full_data.insert(pos);
                    }
                    p.resend(pos);
                } else {
                    let refusal = Refusal::NotInInterest { pos };
                    self.send_control(session, &ServerMessage::RequestRefused(refusal));
                }
            }
            Command::Forget { session, chunks } => {
                if let Some(p) = self.peers.get_mut(&session) {
                    // Confirmed at once, not with the session's next update
                    // (which a quiet view may not get for long). A full
                    // queue keeps it owed until the next batch; a request
                    // that owed nothing new encodes nothing.
                    if p.forget(&mut self.holders, session, &chunks) {
                        p.confirm_withdrawals();
                    }
                }
            }
            Command::Arrive {
                session,
                feet,
                issued_ms,
            } => {
                let msg = match self.seq.arrive(session, feet, issued_ms, now_ms()) {
                    Ok(start) => {
                        if let Some(p) = self.peers.get_mut(&session) {
                            p.start = start;
                        }
                        // Where it was placed: the ticket's spot or a
                        // newer saved one.
                        let placed = match start {
                            strata_protocol::Start::Resume { feet } => feet,
                            strata_protocol::Start::Spawn { .. } => feet,
                        };
                        ServerMessage::Arrived { feet: placed }
                    }
                    Err(reason) => ServerMessage::RequestRefused(Refusal::BadTicket { reason }),
                };
                self.send_control(session, &msg);
            }
            Command::Admin(c) => self.admin(c),
            Command::Stop | Command::Wake => {}
        }
        metrics::gauge!(m::QUEUE_DEPTH).set((self.seq.queued() + self.seq.sighting()) as f64);
    }

    fn submit(&mut self, session: u64, request: strata_protocol::EditRequest, now: u64) {
        let id = request.client_edit_id;
        // Every rule that reads no terrain first: a refused edit loads,
        // generates and meshes nothing.
        let result = self
            .seq
            .precheck(session, &request.edit, now)
            .and_then(|pre| {
                let claim = self.check_regions(session, &request.edit, pre.ray(), now)?;
                if let Some(c) = &claim {
                    self.before_claiming(&c.free)?;
                }
                let needed = self.seq.missing(pre.reads());
                // A chunk found unreadable lately is not read again for
                // each edit: the edit is `Busy` (free) below.
                if !self.unreadable.holds_any(&needed, Instant::now()) {
                    if let Err(e) = self.make_resident(&needed) {
                        crate::log_every::store_error("read", "store read failed", &e);
                    }
                }
                // Line of sight is checked in a batch (`check_sighted`),
                // at once for an edit whose regions are claimed for it.
                self.seq.admit_prechecked(session, request, pre, now)?;
                match &claim {
                    Some(c) => self.claim_after_sight(session, id, c, now),
                    None => Ok(()),
                }
            });
        if let Err(reason) = result {
            self.refuse_edit(session, id, reason);
        }
        self.kick_refused();
    }

    pub(super) fn refuse_edit(
        &mut self,
        session: u64,
        client_edit_id: u64,
        reason: strata_protocol::RejectReason,
    ) {
        metrics::counter!(m::EDITS_REJECTED, "reason" => m::reject_label(&reason)).increment(1);
        let msg = ServerMessage::EditRejected {
            client_edit_id,
            reason,
        };
        self.send_control(session, &msg);
    }

    /// Checks the line of sight of every edit admitted since the last
    /// check, on the workers, and answers those it refuses; the rest are
    /// queued for the tick.
    pub(super) fn check_sighted(&mut self) {
        if self.seq.sighting() == 0 {
            return;
        }
        let pool = self.pool.clone();
        let seq = &mut self.seq;
        let refused = pool.install(|| seq.check_sighted(now_ms()));
        for r in refused {
            self.refuse_edit(r.session_id, r.client_edit_id, r.reason);
        }
        self.kick_refused();
    }

    /// Disconnects players out of rejection tokens.
    fn kick_refused(&mut self) {
        for s in self.seq.take_disconnects() {
            // Each later refusal until the session ends names it again.
            if let Some(p) = self.peers.get_mut(&s).filter(|p| !p.is_kicked()) {
                warn!(session = s, "disconnecting: too many refused edits");
                metrics::counter!(m::SESSIONS_KICKED, "reason" => "rejected_edits").increment(1);
                p.kick(ErrorCode::Kicked, "too many refused edits; slow down");
            }
        }
    }

    fn position(&mut self, session: u64, update: strata_protocol::PositionUpdate, now: u64) {
        // Stale, out of bounds or too fast: refused before any chunk is
        // loaded or generated.
        if let Err(reason) = self.seq.precheck_position(session, &update, now) {
            return self.refuse_position(session, update.seq, &reason, now);
        }
        if let Err(reason) = self.seq.charge_placement(session, now) {
            metrics::counter!(m::POSITIONS_DROPPED, "reason" => "placement").increment(1);
            return self.refuse_position(session, update.seq, &reason, now);
        }
        self.know_feet_region(update.pos);
        let needed = self.seq.chunks_needed_for_position(session, &update);
        // Nor for each position report: it is dropped, as on a failed read.
        if self.unreadable.holds_any(&needed, Instant::now()) {
            metrics::counter!(m::POSITIONS_DROPPED, "reason" => "unreadable").increment(1);
            return;
        }
        if let Err(e) = self.make_resident(&needed) {
            crate::log_every::store_error("read", "store read failed", &e);
            return;
        }
        match self.seq.update_position(session, update, now) {
            Ok(()) => {
                if let Some(p) = self.peers.get_mut(&session) {
                    let change = p.interest.follow_position(update.pos);
                    self.apply_interest(session, change);
                }
                self.premesh_around(session, update.pos);
            }
            Err(reason) => self.refuse_position(session, update.seq, &reason, now),
        }
    }

    fn apply_interest(&mut self, session: u64, change: crate::interest::InterestChange) {
        if let Some(p) = self.peers.get_mut(&session) {
            p.apply_interest(&mut self.holders, session, change);
        }
    }

    pub(super) fn send_control(&mut self, session: u64, msg: &ServerMessage) {
        if let Some(p) = self.peers.get_mut(&session) {
            // A client this far behind is disconnected (`drop_failed`).
            p.send_control(fanout::encode_control(msg));
        }
    }
}
