//! Encoding frames once and fanning deltas out to the sessions that see them.

use std::collections::HashMap;

use bytes::{Bytes, BytesMut};
use rayon::prelude::*;
use strata_protocol::{encode_frame, DeltaUpdate, Direction, ServerMessage, WorldUpdate};
use strata_terrain::ChunkPos;

use super::peer::Peer;
use crate::metrics as m;
use crate::net::writer::SendRefused;
use crate::sequencer::{AppliedEdit, ChunkUpdate};

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
/// base version. Each session gets its deltas of the tick and the `TickEnd`
/// marker as one frame batch (one queue slot, one write, few packets). A
/// session whose queue is full loses the batch and gets snapshots of its
/// chunks later; it never slows the others down.
pub fn broadcast(peers: &mut HashMap<u64, Peer>, applied: &[AppliedEdit], last_seq: u64) {
    // Each change's frame, encoded once, in order.
    let changes: Vec<(&ChunkUpdate, Bytes)> = applied
        .iter()
        .flat_map(|a| {
            a.changes.iter().map(move |c| {
                let frame = encode_update(&WorldUpdate::Delta(DeltaUpdate {
                    delta: c.delta.clone(),
                    mesh_hash: c.mesh_hash,
                    seq: a.seq,
                }));
                (c, frame)
            })
        })
        .collect();
    if changes.is_empty() {
        return;
    }
    let end = encode_update(&WorldUpdate::TickEnd { last_seq });
    // Peers outside, changes inside: each session is visited once per
    // tick, sessions on every worker of the current pool.
    let mut all: Vec<&mut Peer> = peers.values_mut().collect();
    all.par_iter_mut()
        .with_min_len(PEERS_PER_TASK)
        .for_each(|p| send_tick(p, &changes, &end));
}

/// Sessions one fan-out task visits at least: fewer would cost more in
/// scheduling than the lookups they save.
const PEERS_PER_TASK: usize = 64;

/// Queues the tick's frames `p` holds the base of, then `end`, as one batch.
fn send_tick(p: &mut Peer, changes: &[(&ChunkUpdate, Bytes)], end: &Bytes) {
    let mut buf = BytesMut::new();
    let mut chunks: Vec<ChunkPos> = Vec::new();
    for (c, frame) in changes {
        // The Fx-hashed `known` lookup rules most sessions out; `covers`
        // (a tree lookup) only confirms the few that hold the base.
        if p.known.get(&c.pos) != Some(&c.from_version) || !p.interest.covers(c.pos) {
            continue;
        }
        p.known.insert(c.pos, c.to_version);
        buf.extend_from_slice(frame);
        chunks.push(c.pos);
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
