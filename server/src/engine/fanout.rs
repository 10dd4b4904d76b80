//! Encoding frames once and fanning deltas out to the sessions that see them.

use std::collections::HashMap;

use bytes::Bytes;
use strata_protocol::{encode_frame, DeltaUpdate, Direction, ServerMessage, WorldUpdate};

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
/// base version. A session whose queue is full loses the delta and gets a
/// snapshot later; it never slows the others down.
pub fn broadcast(peers: &mut HashMap<u64, Peer>, applied: &[AppliedEdit], last_seq: u64) {
    let mut touched: Vec<u64> = Vec::new();
    for a in applied {
        for c in &a.changes {
            let frame = encode_update(&WorldUpdate::Delta(DeltaUpdate {
                delta: c.delta.clone(),
                mesh_hash: c.mesh_hash,
                seq: a.seq,
            }));
            for (id, p) in peers.iter_mut() {
                if !p.interest.covers(c.pos) || p.known.get(&c.pos) != Some(&c.from_version) {
                    continue;
                }
                match p.updates.try_send(frame.clone()) {
                    Ok(()) => {
                        p.known.insert(c.pos, c.to_version);
                        if !touched.contains(id) {
                            touched.push(*id);
                        }
                    }
                    Err(SendRefused::Full) => {
                        metrics::counter!(m::DELTAS_DROPPED).increment(1);
                        p.resend(c.pos);
                    }
                    Err(SendRefused::Closed) => p.failed = true,
                }
            }
        }
    }
    let end = encode_update(&WorldUpdate::TickEnd { last_seq });
    for id in touched {
        if let Some(p) = peers.get_mut(&id) {
            // A lost marker only delays the client's meshing to the next one.
            let _ = p.updates.try_send(end.clone());
        }
    }
}
