//! Answering refused position reports, at a bounded rate per session.

use strata_protocol::ServerMessage;
use tracing::debug;

use super::{fanout, Engine};
use crate::metrics as m;
use crate::validate::position::PositionReject;

impl Engine {
    /// Tells the client its report was refused, and where the server holds
    /// the player, at most once per
    /// `[validation] position_refusal_ms` per session, and only if its
    /// control queue has room: a flood of bad datagrams costs one frame
    /// an interval and never blocks or fails the session.
    pub(super) fn refuse_position(
        &mut self,
        session: u64,
        seq: u32,
        reason: &PositionReject,
        now: u64,
    ) {
        debug!(session, ?reason, "position refused");
        let interval = self.seq.validation().position_refusal_ms;
        let at = self.seq.position(session).map(|p| p.feet);
        let Some(reason) = reason.refusal() else {
            return;
        };
        let label = strata_protocol::refusal_label(&reason);
        metrics::counter!(m::POSITIONS_REFUSED, "reason" => label).increment(1);
        let Some(p) = self.peers.get_mut(&session) else {
            return;
        };
        let quiet = p
            .refused_at
            .is_some_and(|at| now.saturating_sub(at) < interval);
        if interval == 0 || quiet || p.failed {
            return;
        }
        let msg = ServerMessage::PositionRefused { seq, reason, at };
        if p.control.try_send(fanout::encode_control(&msg)).is_ok() {
            p.refused_at = Some(now);
        }
    }
}
