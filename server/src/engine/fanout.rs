//! Encoding frames once and fanning deltas out to the sessions that see them.

use std::collections::HashMap;

use bytes::{Bytes, BytesMut};
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use strata_protocol::{
    encode_frame, DeltaUpdate, Direction, ServerMessage, WorldUpdate, CAP_OP_REPLAY,
};
use strata_terrain::ChunkPos;

use super::holders::Holders;
use super::ops;
use super::peer::Peer;
use crate::metrics as m;
use crate::net::writer::{Handed, SendRefused};
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
///
/// Only the sessions `holders` lists for a changed chunk are visited; a
/// listed session found not to hold the chunk is unlisted.
pub fn broadcast(
    peers: &mut HashMap<u64, Peer>,
    holders: &mut Holders,
    applied: &[AppliedEdit],
    last_seq: u64,
) {
    debug_assert!(every_holding_listed(peers, holders));
    let changed: Vec<&AppliedEdit> = applied.iter().filter(|a| !a.changes.is_empty()).collect();
    let chains = chains(&changed);
    // The chains each listed session may hold the base of, in chain order.
    let mut wants: FxHashMap<u64, Vec<u32>> = FxHashMap::default();
    for (i, (pos, _)) in chains.iter().enumerate() {
        for &id in holders.of(*pos) {
            wants.entry(id).or_default().push(i as u32);
        }
    }
    if wants.is_empty() {
        return;
    }
    let end = encode_update(&WorldUpdate::TickEnd { last_seq });
    let mut stale: Vec<(ChunkPos, u64)> = Vec::new();
    // Decided on live sessions only, never more than the engine's count
    // (by which it entered its pool or not).
    let live = wants.keys().filter(|id| peers.contains_key(id)).count();
    // Each edit's delta frames (and op, when a visited session replays
    // ops), encoded once, in order.
    let ops = wants
        .keys()
        .any(|id| peers.get(id).is_some_and(|p| p.has(CAP_OP_REPLAY)));
    let workers = on_workers(live);
    let edits: Vec<TickEdit<'_>> = if workers && changed.len() > EDITS_PER_TASK {
        // Off the pool, a parallel iterator would start rayon's global one.
        changed
            .par_iter()
            .with_min_len(EDITS_PER_TASK)
            .map(|a| TickEdit::new(a, ops))
            .collect()
    } else {
        changed.iter().map(|a| TickEdit::new(a, ops)).collect()
    };
    let counters = Counters::new();
    if workers {
        // Sessions outside, chains inside: each visited once per tick, on
        // every worker of the current pool.
        let mut visits: Vec<(u64, &mut Peer, Vec<u32>)> = peers
            .iter_mut()
            .filter_map(|(id, p)| wants.remove(id).map(|w| (*id, p, w)))
            .collect();
        let gone: Vec<(ChunkPos, u64)> = visits
            .par_iter_mut()
            .with_min_len(PEERS_PER_TASK)
            .flat_map_iter(|(id, p, mine)| {
                let id = *id;
                send_tick(p, &edits, &chains, mine, &end, &counters, true)
                    .into_iter()
                    .map(move |pos| (pos, id))
            })
            .collect();
        stale.extend(gone);
    } else {
        let mut ids: Vec<u64> = wants.keys().copied().collect();
        ids.sort_unstable();
        for id in ids {
            // A session not found stays in `wants`, to be unlisted below.
            let Some(p) = peers.get_mut(&id) else {
                continue;
            };
            let mine = wants.remove(&id).unwrap_or_default();
            let gone = send_tick(p, &edits, &chains, &mine, &end, &counters, false);
            stale.extend(gone.into_iter().map(|pos| (pos, id)));
        }
    }
    // Sessions listed but gone (every end unlists its whole view, so none
    // should be).
    for (id, mine) in wants {
        stale.extend(mine.into_iter().map(|i| (chains[i as usize].0, id)));
    }
    for (pos, id) in stale {
        holders.remove(pos, id);
    }
}

/// Whether `holders` lists every chunk every session holds (checked in
/// debug builds: on every fan-out in unit tests, on one in 16 elsewhere, as
/// it reads every session's chunks).
fn every_holding_listed(peers: &HashMap<u64, Peer>, holders: &Holders) -> bool {
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    if !cfg!(test) && n % 16 != 0 {
        return true;
    }
    peers
        .iter()
        .all(|(id, p)| p.holdings().keys().all(|pos| holders.lists(*pos, *id)))
}

/// Whether a fan-out to `peers` sessions is worth the worker pool: more
/// than one task's worth. Below that, [`broadcast`] runs on the calling
/// thread and touches no pool, so the engine need not enter one.
pub fn on_workers(peers: usize) -> bool {
    peers > PEERS_PER_TASK
}

/// Where a change sits: (index into the tick's edits, index of the change).
type At = (u32, u32);

/// Each chunk the tick changed, with its changes in order (a version
/// chain): a session looks up each chunk once, not each change. `edits`
/// are the tick's edits that changed something, in order.
fn chains(edits: &[&AppliedEdit]) -> Vec<(ChunkPos, Vec<At>)> {
    let mut at: HashMap<ChunkPos, usize> = HashMap::new();
    let mut out: Vec<(ChunkPos, Vec<At>)> = Vec::new();
    for (e, edit) in edits.iter().enumerate() {
        for (c, change) in edit.changes.iter().enumerate() {
            let i = *at.entry(change.pos).or_insert_with(|| {
                out.push((change.pos, Vec::new()));
                out.len() - 1
            });
            out[i].1.push((e as u32, c as u32));
        }
    }
    out
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

/// The fan-out's counters, looked up once a tick rather than once a
/// session (a registry lookup each).
struct Counters {
    ops_sent: metrics::Counter,
    deltas_sent: metrics::Counter,
    deltas_dropped: metrics::Counter,
    /// Batches by [`Handed`]: written, begun, queued.
    batches: [metrics::Counter; 3],
}

impl Counters {
    fn new() -> Self {
        Self {
            ops_sent: metrics::counter!(m::OPS_SENT),
            deltas_sent: metrics::counter!(m::DELTAS_SENT),
            deltas_dropped: metrics::counter!(m::DELTAS_DROPPED),
            batches: ["written", "begun", "queued"]
                .map(|how| metrics::counter!(m::FANOUT_BATCHES, "how" => how)),
        }
    }
}

/// Sessions one fan-out task visits at least: fewer would cost more in
/// scheduling than the lookups they save.
const PEERS_PER_TASK: usize = 64;

/// Edits whose frames one task encodes at least, when the fan-out runs on
/// the workers: a busy tick's encoding is otherwise one worker's, while
/// the others wait for it.
const EDITS_PER_TASK: usize = 32;

/// A frame of a session's batch: one encoded for the whole tick (not
/// cloned: a shared count written by every worker would bounce between
/// cores), or one built for this session.
enum Frame<'a> {
    Shared(&'a Bytes),
    Own(Bytes),
}

impl std::ops::Deref for Frame<'_> {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            Frame::Shared(b) => b,
            Frame::Own(b) => b,
        }
    }
}

/// Queues the tick's frames `p` holds the base of, then `end`, as one
/// batch. `mine`: the chains (indices into `chains`) of the chunks `p` is
/// listed for. `direct`: on a worker, write the batch into the stream
/// when it can go at once (the engine thread only queues). Returns those
/// chunks it turned out not to hold.
fn send_tick(
    p: &mut Peer,
    edits: &[TickEdit<'_>],
    chains: &[(ChunkPos, Vec<At>)],
    mine: &[u32],
    end: &Bytes,
    counters: &Counters,
    direct: bool,
) -> Vec<ChunkPos> {
    // A failed session is sent nothing more (it is dropped after the tick).
    if p.failed {
        return Vec::new();
    }
    // The changes `p` gets: along each chunk's chain from the version it
    // holds; `covers` (a tree lookup) only confirms the chunks it holds.
    let mut not_held: Vec<ChunkPos> = Vec::new();
    let mut picked: Vec<At> = Vec::new();
    for &i in mine {
        let (pos, chain) = &chains[i as usize];
        let Some(held) = p.held(*pos) else {
            not_held.push(*pos);
            continue;
        };
        let mut version = held;
        let mut covered = None;
        for &(e, c) in chain {
            let change = &edits[e as usize].edit.changes[c as usize];
            if change.from_version != version {
                continue;
            }
            if !*covered.get_or_insert_with(|| p.interest.covers(*pos)) {
                break;
            }
            picked.push((e, c));
            version = change.to_version;
        }
        if version != held {
            p.advance(*pos, version);
        }
    }
    if picked.is_empty() {
        return not_held;
    }
    // Frames in the tick's order: by edit, then change.
    picked.sort_unstable();
    let mut frames: Vec<Frame<'_>> = Vec::with_capacity(picked.len() + 1);
    let mut chunks: Vec<ChunkPos> = Vec::with_capacity(picked.len());
    let replay = p.has(CAP_OP_REPLAY);
    let mut held: Vec<usize> = Vec::new();
    for group in picked.chunk_by(|a, b| a.0 == b.0) {
        let e = &edits[group[0].0 as usize];
        held.clear();
        held.extend(group.iter().map(|&(_, c)| c as usize));
        match e.op.as_ref().filter(|op| replay && op.replayable_by(p)) {
            Some(op) => {
                frames.push(Frame::Own(op.frame(e.edit, &held)));
                counters.ops_sent.increment(1);
            }
            None => frames.extend(held.iter().map(|&i| Frame::Shared(&e.deltas[i]))),
        }
        chunks.extend(held.iter().map(|&i| e.edit.changes[i].pos));
    }
    if chunks.is_empty() {
        return not_held;
    }
    frames.push(Frame::Shared(end));
    // One allocation of the batch's size: growing it frame by frame
    // copied a busy tick's batch about ten times over.
    let mut buf = BytesMut::with_capacity(frames.iter().map(|f| f.len()).sum());
    for f in &frames {
        buf.extend_from_slice(f);
    }
    let batch = buf.freeze();
    match p.send_update(batch, direct) {
        Ok(how) => {
            p.changes_queued |= how == Handed::Queued;
            counters.deltas_sent.increment(chunks.len() as u64);
            counters.batches[how as usize].increment(1);
        }
        Err(SendRefused::Full) => {
            counters.deltas_dropped.increment(chunks.len() as u64);
            p.dropped(&chunks);
        }
        Err(SendRefused::Closed) => p.failed = true,
    }
    not_held
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interest::{Interest, InterestConfig};
    use crate::sequencer::ChunkUpdate;
    use crate::validate::bounds::WorldBounds;
    use strata_protocol::Start;
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::{Chunk, Edit, Fixed, FixedVec3, Voxel};

    /// A change of `pos` from `from` to `from + 1` (uniform chunks whose
    /// density is the version, so every delta is distinct).
    fn change(pos: ChunkPos, from: u64) -> ChunkUpdate {
        let at = |v: u64| Chunk::Uniform(Voxel::new(v as u8, 1));
        ChunkUpdate {
            pos,
            from_version: from,
            to_version: from + 1,
            delta: ChunkDelta::encode(pos, from, from + 1, &at(from), &at(from + 1)).unwrap(),
            mesh_hash: from,
        }
    }

    fn applied(seq: u64, changes: Vec<ChunkUpdate>) -> AppliedEdit {
        AppliedEdit {
            seq,
            session_id: 0,
            client_edit_id: seq,
            player: "p".into(),
            edit: Edit::Mine {
                center: FixedVec3::from_voxels(0, 0, 0),
                radius: Fixed::from_voxels(1),
                strength: 1,
            },
            changes,
            queued_at: std::time::Instant::now(),
        }
    }

    /// A session `id` holding `known`, listed in `holders`.
    fn listed_peer(
        holders: &mut Holders,
        id: u64,
        known: &[(ChunkPos, u64)],
    ) -> (Peer, tokio::sync::mpsc::Receiver<Bytes>) {
        let (mut p, rx) = peer(&[]);
        for &(pos, v) in known {
            p.receive(holders, id, pos, v);
        }
        (p, rx)
    }

    /// A session holding `known` (listed in an index of its own).
    fn peer(known: &[(ChunkPos, u64)]) -> (Peer, tokio::sync::mpsc::Receiver<Bytes>) {
        let (control, _) = crate::net::writer::FrameSender::channel(4);
        let (updates, rx) = crate::net::writer::FrameSender::channel(4);
        let mut interest = Interest::new(InterestConfig::default(), WorldBounds::default());
        let _ = interest.subscribe(ChunkPos::new(0, 0, 0), 2);
        let (kick, _) = tokio::sync::oneshot::channel();
        let position = std::sync::Arc::new(super::super::LatestPosition::default());
        let start = Start::Spawn {
            x: 0,
            z: 0,
            radius: 0,
        };
        let mut p = Peer::new(control, updates, interest, kick, position, start);
        let mut own = Holders::default();
        for &(pos, v) in known {
            p.receive(&mut own, 0, pos, v);
        }
        (p, rx)
    }

    /// The per-change walk `send_tick` replaced: every change of every
    /// edit, in order, against the versions held so far. Returns the batch
    /// and the versions held after it.
    fn reference(
        known: &[(ChunkPos, u64)],
        edits: &[TickEdit<'_>],
        end: &Bytes,
    ) -> (Vec<u8>, rustc_hash::FxHashMap<ChunkPos, u64>) {
        let (mut p, _) = peer(known);
        let mut out = Vec::new();
        for e in edits {
            for (i, c) in e.edit.changes.iter().enumerate() {
                if p.held(c.pos) == Some(c.from_version) && p.interest.covers(c.pos) {
                    out.extend_from_slice(&e.deltas[i]);
                    p.advance(c.pos, c.to_version);
                }
            }
        }
        if !out.is_empty() {
            out.extend_from_slice(end);
        }
        (out, p.holdings().clone())
    }

    #[test]
    fn a_session_that_missed_a_verdict_is_sent_nothing_more() {
        let a = ChunkPos::new(0, 0, 0);
        let (mut p, mut rx) = peer(&[(a, 4)]);
        let (control, mut verdicts) = crate::net::writer::FrameSender::channel(1);
        p.control = control;
        assert!(p.send_control(Bytes::from_static(b"one")));
        assert!(!p.send_control(Bytes::from_static(b"two")), "full: missed");
        assert!(p.failed);
        // Room again, and still nothing more on either stream.
        assert_eq!(&verdicts.try_recv().unwrap()[..], b"one");
        assert!(!p.send_control(Bytes::from_static(b"three")));
        assert!(verdicts.try_recv().is_err());
        let applied = [applied(1, vec![change(a, 4)])];
        let edits: Vec<TickEdit<'_>> = applied.iter().map(|a| TickEdit::new(a, false)).collect();
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 1 });
        let chains = chains(&applied.iter().collect::<Vec<_>>());
        send_tick(&mut p, &edits, &chains, &[0], &end, &Counters::new(), true);
        assert!(rx.try_recv().is_err(), "no delta after the missed verdict");
        assert!(p.send_update(end.clone(), false).is_err());
        assert!(rx.try_recv().is_err());
    }

    #[test]
    fn each_session_gets_the_chains_it_holds_in_the_ticks_order() {
        let (a, b, c) = (
            ChunkPos::new(0, 0, 0),
            ChunkPos::new(1, 0, 0),
            ChunkPos::new(0, 1, 0),
        );
        let far = ChunkPos::new(40, 0, 0);
        // a changes three times, b twice, c and far once, interleaved.
        let applied = [
            applied(1, vec![change(a, 4), change(b, 0)]),
            applied(2, vec![change(c, 7)]),
            applied(3, vec![change(a, 5), change(far, 0)]),
            applied(4, vec![change(b, 1), change(a, 6)]),
        ];
        let edits: Vec<TickEdit<'_>> = applied.iter().map(|a| TickEdit::new(a, false)).collect();
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 4 });
        let chains = chains(&applied.iter().collect::<Vec<_>>());
        let all: Vec<u32> = (0..chains.len() as u32).collect();
        assert_eq!(chains.len(), 4);
        let cases: Vec<Vec<(ChunkPos, u64)>> = vec![
            vec![(a, 4), (b, 0), (c, 7)],
            vec![(a, 5), (b, 1)],
            // Held too old or too new: nothing of a or b.
            vec![(a, 3), (b, 2)],
            vec![(c, 7), (far, 0)],
            vec![(a, 6)],
            vec![],
        ];
        for known in cases {
            let (mut p, mut rx) = peer(&known);
            let not_held = send_tick(&mut p, &edits, &chains, &all, &end, &Counters::new(), true);
            let got = rx.try_recv().map(|b| b.to_vec()).unwrap_or_default();
            let (want, held) = reference(&known, &edits, &end);
            assert_eq!(got, want, "holding {known:?}");
            assert_eq!(*p.holdings(), held, "holding {known:?}");
            let missing: Vec<ChunkPos> = chains
                .iter()
                .map(|(pos, _)| *pos)
                .filter(|pos| !known.iter().any(|(k, _)| k == pos))
                .collect();
            assert_eq!(not_held, missing, "holding {known:?}");
        }
    }

    #[test]
    fn broadcast_reaches_every_session_here_or_on_the_workers() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let short = vec![
            applied(1, vec![change(a, 4), change(b, 0)]),
            applied(2, vec![change(a, 5)]),
        ];
        // Enough edits that the workers encode their frames together.
        let long: Vec<AppliedEdit> = (1..=3 * EDITS_PER_TASK as u64)
            .map(|seq| applied(seq, vec![change(a, 3 + seq)]))
            .collect();
        let holds = [vec![(a, 4), (b, 0)], vec![(a, 5)], vec![(b, 0)], vec![]];
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        for tick in [short, long] {
            let last_seq = tick.len() as u64;
            let edits: Vec<TickEdit<'_>> = tick.iter().map(|a| TickEdit::new(a, false)).collect();
            let end = encode_update(&WorldUpdate::TickEnd { last_seq });
            for sessions in [PEERS_PER_TASK, 3 * PEERS_PER_TASK + 5] {
                assert_eq!(on_workers(sessions), sessions > PEERS_PER_TASK);
                let mut peers = HashMap::new();
                let mut holders = Holders::default();
                let mut rxs = Vec::new();
                for id in 0..sessions {
                    let known = &holds[id % holds.len()];
                    let (p, rx) = listed_peer(&mut holders, id as u64, known);
                    peers.insert(id as u64, p);
                    rxs.push((id, rx));
                }
                if on_workers(sessions) {
                    pool.install(|| broadcast(&mut peers, &mut holders, &tick, last_seq));
                } else {
                    broadcast(&mut peers, &mut holders, &tick, last_seq);
                }
                for (id, mut rx) in rxs {
                    let known = &holds[id % holds.len()];
                    let got = rx.try_recv().map(|b| b.to_vec()).unwrap_or_default();
                    let (want, held) = reference(known, &edits, &end);
                    let edits = tick.len();
                    assert_eq!(
                        got, want,
                        "{edits} edits, {sessions} sessions, session {id}"
                    );
                    assert_eq!(*peers[&(id as u64)].holdings(), held, "session {id}");
                }
            }
        }
    }

    #[test]
    fn only_listed_sessions_are_visited_and_stale_listings_are_dropped() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let applied = [
            applied(1, vec![change(a, 4)]),
            applied(2, vec![change(b, 0)]),
        ];
        let mut holders = Holders::default();
        let mut peers = HashMap::new();
        // 1 holds a; 2 held b but was told to resend it (still listed);
        // 3 is listed for a but has ended.
        let (p1, mut rx1) = listed_peer(&mut holders, 1, &[(a, 4)]);
        let (mut p2, mut rx2) = listed_peer(&mut holders, 2, &[(b, 0)]);
        p2.resend(b);
        holders.add(a, 3);
        peers.insert(1, p1);
        peers.insert(2, p2);
        assert_eq!(holders.pairs(), 3);
        broadcast(&mut peers, &mut holders, &applied, 2);
        assert!(rx1.try_recv().is_ok(), "the holder of a got its change");
        assert!(rx2.try_recv().is_err(), "nothing for a chunk being resent");
        assert_eq!(peers[&1].held(a), Some(5));
        assert_eq!(holders.of(a), &[1]);
        assert!(holders.of(b).is_empty());
        // Ending and unlisting a session leaves nothing of it.
        let p1 = peers.remove(&1).unwrap();
        p1.unlist_all(&mut holders, 1);
        assert_eq!(holders.pairs(), 0);
    }

    #[test]
    fn a_forget_on_a_full_queue_encodes_nothing_and_stays_owed() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let (mut p, mut rx) = peer(&[(a, 4), (b, 2)]);
        let mut holders = Holders::default();
        let filler = Bytes::from_static(b"x");
        while p.updates.try_send(filler.clone()).is_ok() {}
        // A client that does not read, forgetting chunk after chunk (or
        // the same one): no confirmation is encoded for a queue with no
        // room, however many requests come.
        for chunks in [[a], [b], [a], [b]] {
            p.forget(&mut holders, 0, &chunks);
            p.confirm_withdrawals();
        }
        assert_eq!(p.withdrawals_encoded, 0);
        assert_eq!(p.withdrawals_owed(), &[a, b], "each once, in order");
        // Once the writer takes a frame, the next confirmation goes.
        rx.try_recv().unwrap();
        p.confirm_withdrawals();
        assert_eq!(p.withdrawals_encoded, 1);
        assert!(!p.owes_withdrawals());
    }

    /// A client whose updates stream is gone (it stopped reading it) is
    /// failed at its next withdrawal, which is not encoded: it does not
    /// linger, each request encoding its whole list again. A request that
    /// owes nothing new encodes nothing either.
    #[test]
    fn a_gone_writer_fails_the_session_and_nothing_is_encoded_for_it() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let (mut p, rx) = peer(&[(a, 4), (b, 2)]);
        let mut holders = Holders::default();
        assert!(p.forget(&mut holders, 0, &[a]));
        p.confirm_withdrawals();
        assert_eq!(p.withdrawals_encoded, 1);
        // Nothing new owed: nothing to confirm, nothing encoded.
        assert!(!p.forget(&mut holders, 0, &[]));
        assert!(!p.forget(&mut holders, 0, &[a]));
        p.withdraw(std::iter::empty());
        assert_eq!(p.withdrawals_encoded, 1);
        assert!(!p.failed);
        drop(rx);
        assert!(p.forget(&mut holders, 0, &[b]));
        p.confirm_withdrawals();
        assert!(p.failed, "dropped at the tick's end");
        assert_eq!(p.withdrawals_encoded, 1);
    }

    #[test]
    fn changes_dropped_on_a_full_queue_are_withdrawn_before_the_next_update() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let (mut p, mut rx) = peer(&[(a, 4), (b, 0)]);
        let filler = Bytes::from_static(b"x");
        while p.updates.try_send(filler.clone()).is_ok() {}
        let first = [applied(1, vec![change(a, 4)])];
        let edits: Vec<TickEdit<'_>> = first.iter().map(|e| TickEdit::new(e, false)).collect();
        let chains1 = chains(&first.iter().collect::<Vec<_>>());
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 1 });
        let counters = Counters::new();
        send_tick(&mut p, &edits, &chains1, &[0], &end, &counters, true);
        // Dropped: a is no longer held, is sent again first, and the
        // client's copy (at 4) is owed a withdrawal.
        assert_eq!(p.held(a), None);
        assert_eq!(p.withdrawals_owed(), &[a]);
        assert_eq!(p.pending.pop_front(), Some(a));
        p.pending.push_front(a);
        while rx.try_recv().is_ok() {}

        // The next update, a change of b, carries the withdrawal first.
        let second = [applied(2, vec![change(b, 0)])];
        let edits: Vec<TickEdit<'_>> = second.iter().map(|e| TickEdit::new(e, false)).collect();
        let chains2 = chains(&second.iter().collect::<Vec<_>>());
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 2 });
        send_tick(&mut p, &edits, &chains2, &[0], &end, &counters, true);
        let got = rx.try_recv().unwrap().to_vec();
        let mut want = encode_update(&WorldUpdate::UnsubscribedMany { chunks: vec![a] }).to_vec();
        want.extend_from_slice(&reference(&[(b, 0)], &edits, &end).0);
        assert_eq!(got, want);
        assert!(p.withdrawals_owed().is_empty());
        assert_eq!(p.held(b), Some(1));
    }

    #[test]
    fn one_batch_of_changes_queued_does_not_hold_the_stream_back() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let (mut p, mut rx) = peer(&[(a, 4), (b, 0)]);
        assert!(p.may_stream(), "idle");
        let first = [applied(1, vec![change(a, 4)])];
        let edits: Vec<TickEdit<'_>> = first.iter().map(|e| TickEdit::new(e, false)).collect();
        let chains1 = chains(&first.iter().collect::<Vec<_>>());
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 1 });
        let counters = Counters::new();
        send_tick(&mut p, &edits, &chains1, &[0], &end, &counters, false);
        assert_eq!(p.updates.queued(), 1);
        assert!(p.may_stream(), "behind this tick's changes only");
        // A batch of chunks sent: the next changes wait behind it, and
        // nothing more is streamed until the writer takes it.
        p.changes_queued = false;
        assert!(!p.may_stream());
        let second = [applied(2, vec![change(b, 0)])];
        let edits: Vec<TickEdit<'_>> = second.iter().map(|e| TickEdit::new(e, false)).collect();
        let chains2 = chains(&second.iter().collect::<Vec<_>>());
        let end = encode_update(&WorldUpdate::TickEnd { last_seq: 2 });
        send_tick(&mut p, &edits, &chains2, &[0], &end, &counters, false);
        assert_eq!(p.updates.queued(), 2);
        assert!(!p.may_stream(), "two queued");
        while rx.try_recv().is_ok() {}
        assert!(p.may_stream(), "idle again");
    }

    /// A view that moves on while the client lags (its updates queue
    /// full): the chunks it was sent are owed a withdrawal, sent ahead of
    /// its next update; the session is not failed. Chunks never sent are
    /// owed nothing.
    #[test]
    fn a_recentre_on_a_full_queue_owes_its_withdrawals() {
        let mut holders = Holders::default();
        let ((mut p, mut rx), [a, b, c]) = two_sent_one_queued(&mut holders);
        let filler = Bytes::from_static(b"x");
        while p.updates.try_send(filler.clone()).is_ok() {}
        let change = crate::interest::InterestChange {
            unsubscribe: vec![a, b, c],
            ..Default::default()
        };
        p.apply_interest(&mut holders, 7, change);
        assert!(!p.failed, "served late, not failed");
        assert_eq!(p.withdrawals_owed(), &[a, b]);
        assert!(holders.of(a).is_empty() && p.pending.pop_front().is_none());
        while rx.try_recv().is_ok() {}
        assert!(p.send_update(Bytes::new(), false).is_ok());
        let got = rx.try_recv().unwrap().to_vec();
        let want = encode_update(&WorldUpdate::UnsubscribedMany { chunks: vec![a, b] });
        assert_eq!(got, want.to_vec());
    }

    /// A chunk the client holds and asked for again (to be sent again,
    /// no longer listed as held) that leaves the view, or that it then
    /// forgets, before the new copy goes is still withdrawn: the client's
    /// copy may be there.
    #[test]
    fn a_chunk_to_be_sent_again_is_withdrawn_when_it_goes() {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let mut holders = Holders::default();
        let (mut p, mut rx) = listed_peer(&mut holders, 7, &[(a, 4), (b, 2)]);
        p.resend(a);
        p.resend(b);
        let change = crate::interest::InterestChange {
            unsubscribe: vec![a],
            ..Default::default()
        };
        p.apply_interest(&mut holders, 7, change);
        p.forget(&mut holders, 7, &[b]);
        let mut got = Vec::new();
        while let Ok(f) = rx.try_recv() {
            got.extend_from_slice(&f);
        }
        let mut want = encode_update(&WorldUpdate::UnsubscribedMany { chunks: vec![a] }).to_vec();
        assert_eq!(&got[..], &want[..], "the re-centre's withdrawal");
        p.confirm_withdrawals();
        want = encode_update(&WorldUpdate::UnsubscribedMany { chunks: vec![b] }).to_vec();
        assert_eq!(rx.try_recv().unwrap().to_vec(), want, "the forget's");
        assert!(p.pending.pop_front().is_none(), "neither is sent again");
    }

    /// Session 7 sent chunks a (at 4) and b (at 0), c queued, not sent.
    fn two_sent_one_queued(
        holders: &mut Holders,
    ) -> ((Peer, tokio::sync::mpsc::Receiver<Bytes>), [ChunkPos; 3]) {
        let (a, b, c) = (
            ChunkPos::new(0, 0, 0),
            ChunkPos::new(1, 0, 0),
            ChunkPos::new(0, 1, 0),
        );
        let (mut p, rx) = listed_peer(holders, 7, &[(a, 4), (b, 0)]);
        p.pending.push_back(c);
        ((p, rx), [a, b, c])
    }

    #[test]
    fn a_forget_of_chunks_sent_is_confirmed_on_the_updates_stream() {
        let mut holders = Holders::default();
        let ((mut p, mut rx), [a, b, c]) = two_sent_one_queued(&mut holders);
        // b's change was dropped on a full queue: already owed a withdrawal.
        p.dropped(&[b]);
        p.forget(&mut holders, 7, &[a, b, c]);
        assert_eq!(p.withdrawals_owed(), &[b, a], "each sent chunk once");
        assert!(holders.of(a).is_empty());
        assert_eq!(p.pending.pop_front(), None);
        assert!(p.send_update(Bytes::new(), false).is_ok());
        let got = rx.try_recv().unwrap().to_vec();
        let want = encode_update(&WorldUpdate::UnsubscribedMany { chunks: vec![b, a] });
        assert_eq!(got, want.to_vec());
        // Forgetting again (nothing held) owes nothing.
        p.forget(&mut holders, 7, &[a, c]);
        assert!(!p.owes_withdrawals());
    }

    #[test]
    fn an_ending_session_is_unlisted_even_for_chunks_waiting_to_be_resent() {
        let b = ChunkPos::new(1, 0, 0);
        let mut holders = Holders::default();
        let (mut p, _rx) = listed_peer(&mut holders, 7, &[(b, 0)]);
        p.resend(b);
        assert_eq!(p.held(b), None);
        assert!(holders.lists(b, 7), "kept until a fan-out or the end");
        p.unlist_all(&mut holders, 7);
        assert_eq!(holders.pairs(), 0);
    }
}
