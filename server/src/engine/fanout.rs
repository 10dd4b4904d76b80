//! Encoding frames once and fanning deltas out to the sessions that see them.

use std::collections::HashMap;

use bytes::{Bytes, BytesMut};
use rayon::prelude::*;
use strata_protocol::{
    encode_frame, DeltaUpdate, Direction, ServerMessage, WorldUpdate, CAP_OP_REPLAY,
};
use strata_terrain::ChunkPos;

use super::ops;
use super::peer::Peer;
use crate::metrics as m;
use crate::net::writer::SendRefused;
use crate::sequencer::AppliedEdit;

/// Encodes an updates-stream frame. Server messages are built from
/// validated state, so a failure here is a bug, not bad input.
pub fn encode_update(u: &WorldUpdate) -> Bytes {
    Bytes::from(
        encode_frame(u, Direction::ServerToClient).expect("server updates fit the frame cap"),
    )
}

pub fn encode_control(msg: &ServerMessage) -> Bytes {
    Bytes::from(
        encode_frame(msg, Direction::ServerToClient).expect("control messages fit the frame cap"),
    )
}

/// Sends each change to every session that holds the chunk at the delta's
/// base version: as `Delta`s, or as one `Op` per edit to sessions with
/// `CAP_OP_REPLAY` (see [`super::ops`]). Each session gets its updates of
/// the tick and the `TickEnd` marker as one frame batch (one queue slot,
/// one write, few packets). A session whose queue is full loses the batch
/// and gets snapshots of its chunks later; it never slows the others down.
pub fn broadcast(peers: &mut HashMap<u64, Peer>, applied: &[AppliedEdit], last_seq: u64) {
    // Each edit's delta frames (and op, when a session replays ops),
    // encoded once, in order.
    let ops = peers.values().any(|p| p.has(CAP_OP_REPLAY));
    let edits: Vec<TickEdit<'_>> = applied
        .iter()
        .filter(|a| !a.changes.is_empty())
        .map(|a| TickEdit::new(a, ops))
        .collect();
    if edits.is_empty() {
        return;
    }
    let end = encode_update(&WorldUpdate::TickEnd { last_seq });
    // Peers outside, changes inside: each session is visited once per
    // tick, sessions on every worker of the current pool.
    let mut all: Vec<&mut Peer> = peers.values_mut().collect();
    all.par_iter_mut()
        .with_min_len(PEERS_PER_TASK)
        .for_each(|p| send_tick(p, &edits, &end));
}

/// One applied edit of the tick with its changes' `Delta` frames.
struct TickEdit<'a> {
    edit: &'a AppliedEdit,
    deltas: Vec<Bytes>,
    /// How the edit goes out as an op, if it can be one.
    op: Option<ops::OpPlan>,
}

impl<'a> TickEdit<'a> {
    /// `ops`: some session replays ops, so plan the edit's.
    fn new(a: &'a AppliedEdit, ops: bool) -> Self {
        let deltas = a
            .changes
            .iter()
            .map(|c| {
                encode_update(&WorldUpdate::Delta(DeltaUpdate {
                    delta: c.delta.clone(),
                    mesh_hash: c.mesh_hash,
                    seq: a.seq,
                }))
            })
            .collect();
        Self {
            edit: a,
            deltas,
            op: ops.then(|| ops::OpPlan::new(a)).flatten(),
        }
    }
}

/// Sessions one fan-out task visits at least: fewer would cost more in
/// scheduling than the lookups they save.
const PEERS_PER_TASK: usize = 64;

/// Queues the tick's frames `p` holds the base of, then `end`, as one batch.
fn send_tick(p: &mut Peer, edits: &[TickEdit<'_>], end: &Bytes) {
    let mut buf = BytesMut::new();
    let mut chunks: Vec<ChunkPos> = Vec::new();
    let replay = p.has(CAP_OP_REPLAY);
    // Indices of an edit's changes `p` holds the base of (one buffer per
    // session and tick, not one per edit).
    let mut held: Vec<usize> = Vec::new();
    for e in edits {
        // The Fx-hashed `known` lookup rules most sessions out; `covers`
        // (a tree lookup) only confirms the few that hold the base.
        held.clear();
        held.extend(
            e.edit
                .changes
                .iter()
                .enumerate()
                .filter(|(_, c)| {
                    p.known.get(&c.pos) == Some(&c.from_version) && p.interest.covers(c.pos)
                })
                .map(|(i, _)| i),
        );
        if held.is_empty() {
            continue;
        }
        match e.op.as_ref().filter(|op| replay && op.replayable_by(p)) {
            Some(op) => {
                buf.extend_from_slice(&op.frame(e.edit, &held));
                metrics::counter!(m::OPS_SENT).increment(1);
            }
            None => {
                for &i in &held {
                    buf.extend_from_slice(&e.deltas[i]);
                }
            }
        }
        for &i in &held {
            let c = &e.edit.changes[i];
            p.known.insert(c.pos, c.to_version);
            chunks.push(c.pos);
        }
    }
    if chunks.is_empty() {
        return;
    }
    buf.extend_from_slice(end);
    match p.updates.try_send(buf.freeze()) {
        Ok(()) => metrics::counter!(m::DELTAS_SENT).increment(chunks.len() as u64),
        Err(SendRefused::Full) => {
            metrics::counter!(m::DELTAS_DROPPED).increment(chunks.len() as u64);
            for pos in chunks {
                p.resend(pos);
            }
        }
        Err(SendRefused::Closed) => p.failed = true,
    }
}
