//! Optional client-side prediction: the client applies its own edit to a
//! *predicted view* at once, then reconciles with the server.
//!
//! - The authoritative [`Replica`] stays exactly what the server sent.
//! - The predicted view is the authoritative chunks with this client's
//!   pending edits re-applied in order, with [`Edit::apply`] (the server's
//!   own code). It is rebuilt from scratch (rollback and replay) at every
//!   verdict and whenever an update changes a chunk a pending edit reads.
//!   An accepted edit stops being replayed on a chunk once the replica
//!   holds the version the server gave that chunk for it (or when the
//!   server's edit did not change that chunk at all).
//!
//! **What is compared.** The prediction of an edit is made once, when it is
//! sent: the edit applied on top of the predicted view the client had then
//! (its authoritative chunks plus its earlier pending edits). The chunks it
//! changed, as they were at that moment, are kept. The server's result is
//! each chunk its `EditAccepted` lists, exactly as the delta of that edit's
//! own `seq` left it in the replica. The prediction is **exact** when both
//! changed the same set of chunks and each of them is bit-identical
//! (densities and materials); otherwise it is **mispredicted** (another
//! edit was sequenced between the prediction's base and ours, or one of our
//! earlier edits was refused), and counted apart when only voxels outside
//! the edit's own box differ. An accepted edit for which the replica never
//! applied its own delta on some chunk (the chunk came whole, or left the
//! view) is **unverified** unless the chunk sets already differ. A rejected
//! edit, or one whose verdict never came, is **rolled back**.

use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet, VecDeque};
use std::sync::Arc;

use serde::Serialize;
use strata_protocol::{ChunkVersion, WorldUpdate};
use strata_terrain::edit::StructureLibrary;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{
    Chunk, ChunkPos, Edit, EditContext, MaterialTable, Voxel, VoxelBox, VoxelPos, World,
};

use crate::client::Verdict;
use crate::replica::Replica;

/// Predicted edits a client keeps unsettled at once; beyond it, new edits
/// are sent without a prediction (counted in [`PredictionStats::skipped`]).
pub const MAX_PENDING_PREDICTIONS: usize = 64;
/// Server results (one chunk each) kept for edits whose verdict has not
/// arrived yet (the verdict and the deltas come on different streams).
pub const MAX_UNCLAIMED_RESULTS: usize = 256;

/// How a client's predictions fared.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct PredictionStats {
    /// Edits applied to the predicted view when sent.
    pub made: u64,
    /// Bit-identical to the server's result in every changed chunk.
    pub exact: u64,
    /// Different from the server's result.
    pub mispredicted: u64,
    /// Of `mispredicted`: every voxel in the edit's own box matched; only
    /// voxels elsewhere in its chunks differed (another edit changed them
    /// between the prediction's base and the edit).
    pub mispredicted_outside_box: u64,
    /// Rejected (or never answered): dropped from the predicted view.
    pub rolled_back: u64,
    /// Accepted, but the edit's own delta never reached the replica for
    /// some chunk, so there was nothing to compare with.
    pub unverified: u64,
    /// Predicted and not settled yet.
    pub pending: u64,
    /// Edits sent without a prediction: the cap was reached, a chunk the
    /// edit reads is not held, or the edit is invalid here.
    pub skipped: u64,
}

impl PredictionStats {
    /// Adds another client's counts.
    pub fn add(&mut self, o: &PredictionStats) {
        self.made += o.made;
        self.exact += o.exact;
        self.mispredicted += o.mispredicted;
        self.mispredicted_outside_box += o.mispredicted_outside_box;
        self.rolled_back += o.rolled_back;
        self.unverified += o.unverified;
        self.pending += o.pending;
        self.skipped += o.skipped;
    }
}

/// What an update does to the replica, as far as prediction cares (taken
/// before the replica applies it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Touched {
    /// A delta of edit `seq` taking `pos` to `to_version`.
    Delta {
        pos: ChunkPos,
        seq: u64,
        to_version: u64,
    },
    /// A whole chunk: generated, snapshot or patch.
    Whole(ChunkPos),
    /// The chunk left the view.
    Gone(ChunkPos),
}

impl Touched {
    /// What `u` touches; `None` for a tick end (and a list of chunks).
    pub fn of(u: &WorldUpdate) -> Option<Touched> {
        Some(match u {
            WorldUpdate::Delta(d) => Touched::Delta {
                pos: d.delta.pos,
                seq: d.seq,
                to_version: d.delta.to_version,
            },
            WorldUpdate::Generated { pos } | WorldUpdate::Snapshot { pos, .. } => {
                Touched::Whole(*pos)
            }
            WorldUpdate::Patched { delta, .. } => Touched::Whole(delta.pos),
            WorldUpdate::Unsubscribed { pos } => Touched::Gone(*pos),
            // Many chunks: the client passes them on one `Unsubscribed` each.
            // Many chunks: the client passes an op's chunks one by one.
            WorldUpdate::TickEnd { .. }
            | WorldUpdate::UnsubscribedMany { .. }
            | WorldUpdate::Op(_)
            | WorldUpdate::InterestComplete { .. } => return None,
        })
    }

    /// The chunk it touches.
    pub fn pos(self) -> ChunkPos {
        match self {
            Touched::Delta { pos, .. } | Touched::Whole(pos) | Touched::Gone(pos) => pos,
        }
    }
}

/// How a settled prediction compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Exact,
    /// `in_box`: the difference includes voxels of the edit's box.
    Mispredicted {
        in_box: bool,
    },
    Unverified,
}

/// The server's answer to an edit we predicted.
#[derive(Debug)]
struct Accepted {
    seq: u64,
    changes: Vec<ChunkVersion>,
}

/// One predicted edit awaiting its verdict or its deltas.
#[derive(Debug)]
struct PendingEdit {
    /// Its `client_edit_id`.
    id: u64,
    edit: Edit,
    /// Every voxel the edit may change.
    bbox: VoxelBox,
    /// Every chunk the edit reads (its box plus the read margin).
    reads: Vec<ChunkPos>,
    /// The prediction: each chunk the edit changed, as made when sent.
    made: Vec<(ChunkPos, Arc<Chunk>)>,
    accepted: Option<Accepted>,
    /// The server's result per changed chunk: the replica's chunk right
    /// after the delta of `accepted.seq`.
    results: HashMap<ChunkPos, Arc<Chunk>>,
    /// Changed chunks that left the replica before they could be compared.
    gone: HashSet<ChunkPos>,
}

impl PendingEdit {
    /// Whether the replica's copy of `pos` already reflects this edit.
    fn included(&self, pos: ChunkPos, replica: &Replica) -> bool {
        let Some(a) = &self.accepted else {
            return false;
        };
        match a.changes.iter().find(|c| c.pos == pos) {
            // The server's edit left `pos` alone.
            None => true,
            Some(c) => {
                self.gone.contains(&pos) || replica.get(pos).is_some_and(|h| h.version >= c.version)
            }
        }
    }

    fn settled(&self, replica: &Replica) -> bool {
        self.accepted
            .as_ref()
            .is_some_and(|a| a.changes.iter().all(|c| self.included(c.pos, replica)))
    }

    fn outcome(&self) -> Outcome {
        let Some(a) = &self.accepted else {
            return Outcome::Unverified;
        };
        let made: BTreeSet<ChunkPos> = self.made.iter().map(|(p, _)| *p).collect();
        let server: BTreeSet<ChunkPos> = a.changes.iter().map(|c| c.pos).collect();
        if made != server {
            return Outcome::Mispredicted { in_box: true };
        }
        let (mut differ, mut in_box, mut unverified) = (false, false, false);
        for (pos, predicted) in &self.made {
            match self.results.get(pos) {
                None => unverified = true,
                Some(r) if Arc::ptr_eq(r, predicted) || **r == **predicted => {}
                Some(r) => {
                    differ = true;
                    in_box |= !same_within(self.bbox, *pos, predicted, r);
                }
            }
        }
        match (differ, unverified) {
            (true, _) => Outcome::Mispredicted { in_box },
            (false, true) => Outcome::Unverified,
            (false, false) => Outcome::Exact,
        }
    }
}

/// Whether chunks `a` and `b` at `pos` agree on every voxel of `bbox`.
fn same_within(bbox: VoxelBox, pos: ChunkPos, a: &Chunk, b: &Chunk) -> bool {
    let Some(sub) = bbox.within_chunk(pos) else {
        return true;
    };
    (sub.min.z..=sub.max.z).all(|z| {
        (sub.min.y..=sub.max.y).all(|y| {
            (sub.min.x..=sub.max.x).all(|x| {
                let (lx, ly, lz) = VoxelPos::new(x, y, z).local();
                a.get(lx, ly, lz) == b.get(lx, ly, lz)
            })
        })
    })
}

/// The chunks an edit with box `bbox` and read margin `m` reads.
fn read_chunks(bbox: VoxelBox, m: i32) -> Vec<ChunkPos> {
    VoxelBox {
        min: VoxelPos::new(bbox.min.x - m, bbox.min.y - m, bbox.min.z - m),
        max: VoxelPos::new(bbox.max.x + m, bbox.max.y + m, bbox.max.z + m),
    }
    .chunks()
    .collect()
}

/// One client's predicted view and pending predictions. Every method that
/// changes it takes the authoritative replica (lock the replica first).
#[derive(Debug)]
pub struct Prediction {
    materials: MaterialTable,
    structures: Arc<StructureLibrary>,
    cap: usize,
    /// In the order the edits were sent.
    pending: Vec<PendingEdit>,
    /// Predicted chunks that differ from the replica's.
    view: HashMap<ChunkPos, Arc<Chunk>>,
    /// Results of deltas that may belong to an edit whose verdict is on
    /// its way: (seq, pos, chunk), oldest first.
    unclaimed: VecDeque<(u64, ChunkPos, Arc<Chunk>)>,
    stats: PredictionStats,
}

impl Prediction {
    /// `structures` lets `PlaceStructure` edits be predicted (with an empty
    /// library they are skipped); at most `cap` predictions are pending.
    pub fn new(structures: Arc<StructureLibrary>, cap: usize) -> Self {
        Self {
            materials: MaterialTable::default(),
            structures,
            cap,
            pending: Vec::new(),
            view: HashMap::new(),
            unclaimed: VecDeque::new(),
            stats: PredictionStats::default(),
        }
    }

    pub fn stats(&self) -> PredictionStats {
        PredictionStats {
            pending: self.pending.len() as u64,
            ..self.stats
        }
    }

    /// The chunk as the player should see it: predicted if a pending edit
    /// changed it, else the replica's.
    pub fn chunk(&self, pos: ChunkPos, replica: &Replica) -> Option<Arc<Chunk>> {
        self.view
            .get(&pos)
            .or_else(|| replica.get(pos).map(|h| &h.chunk))
            .cloned()
    }

    /// One voxel of the predicted view; `None` when its chunk is not held.
    pub fn voxel(&self, p: VoxelPos, replica: &Replica) -> Option<Voxel> {
        let (x, y, z) = p.local();
        self.chunk(p.chunk(), replica).map(|c| c.get(x, y, z))
    }

    /// Chunks whose predicted copy differs from the replica's.
    pub fn predicted_chunks(&self) -> impl Iterator<Item = ChunkPos> + '_ {
        self.view.keys().copied()
    }

    /// Applies edit `id` to the predicted view before it is sent; returns
    /// whether it was predicted.
    pub fn predict(&mut self, id: u64, edit: Edit, replica: &Replica) -> bool {
        let ctx = EditContext {
            materials: &self.materials,
            structures: &self.structures,
        };
        let bbox = match edit.validate(&ctx) {
            Ok(b) if self.pending.len() < self.cap => b,
            _ => {
                self.stats.skipped += 1;
                return false;
            }
        };
        let reads = read_chunks(bbox, edit.read_margin());
        if !reads.iter().all(|p| replica.get(*p).is_some()) {
            self.stats.skipped += 1;
            return false;
        }
        self.pending.push(PendingEdit {
            id,
            edit,
            bbox,
            reads,
            made: Vec::new(),
            accepted: None,
            results: HashMap::new(),
            gone: HashSet::new(),
        });
        match self.replay(replica) {
            Some(made) => {
                self.pending.last_mut().expect("pushed above").made = made;
                self.stats.made += 1;
                true
            }
            None => {
                self.pending.pop();
                self.replay(replica);
                self.stats.skipped += 1;
                false
            }
        }
    }

    /// Reconciles edit `id` with its verdict (`changes`: the chunk versions
    /// it made). Edits that were not predicted are ignored.
    pub fn verdict(
        &mut self,
        id: u64,
        verdict: &Verdict,
        changes: &[ChunkVersion],
        replica: &Replica,
    ) {
        let Some(i) = self.pending.iter().position(|p| p.id == id) else {
            return;
        };
        match *verdict {
            Verdict::Accepted { seq } => {
                let p = &mut self.pending[i];
                // Only chunks the edit reads can be among its changes, each
                // once: whatever else a server lists is dropped, so a huge
                // list costs nothing later (each settle scans this one).
                let reads: HashSet<ChunkPos> = p.reads.iter().copied().collect();
                let mut kept: BTreeMap<ChunkPos, u64> = BTreeMap::new();
                for c in changes.iter().filter(|c| reads.contains(&c.pos)) {
                    kept.entry(c.pos).or_insert(c.version);
                }
                let changes: Vec<ChunkVersion> = kept
                    .into_iter()
                    .map(|(pos, version)| ChunkVersion { pos, version })
                    .collect();
                let changes = &changes[..];
                p.accepted = Some(Accepted {
                    seq,
                    changes: changes.to_vec(),
                });
                // A chunk the replica lost cannot get this edit's delta.
                for c in changes {
                    if replica.get(c.pos).is_none() {
                        p.gone.insert(c.pos);
                    }
                }
                for (s, pos, chunk) in std::mem::take(&mut self.unclaimed) {
                    if s != seq {
                        self.unclaimed.push_back((s, pos, chunk));
                    } else if changes.iter().any(|c| c.pos == pos) {
                        self.pending[i].results.insert(pos, chunk);
                    }
                }
            }
            Verdict::Rejected(_) => {
                self.pending.remove(i);
                self.stats.rolled_back += 1;
            }
        }
        self.settle(replica);
    }

    /// Drops edit `id`, whose verdict will never come (timeout, closed
    /// connection): a rollback.
    pub fn abandon(&mut self, id: u64, replica: &Replica) {
        if let Some(i) = self.pending.iter().position(|p| p.id == id) {
            self.pending.remove(i);
            self.stats.rolled_back += 1;
            self.settle(replica);
        }
    }

    /// Follows an update the replica has just applied.
    pub fn after_update(&mut self, touched: Touched, replica: &Replica) {
        if self.pending.is_empty() {
            return;
        }
        match touched {
            Touched::Delta {
                pos,
                seq,
                to_version,
            } => {
                if let Some(h) = replica.get(pos).filter(|h| h.version == to_version) {
                    self.record_result(seq, pos, h.chunk.clone());
                }
            }
            Touched::Gone(pos) => {
                for p in &mut self.pending {
                    if p.accepted.is_some() && !p.included(pos, replica) {
                        p.gone.insert(pos);
                    }
                }
            }
            Touched::Whole(_) => {}
        }
        let pos = touched.pos();
        if self.pending.iter().any(|p| p.reads.contains(&pos)) {
            self.settle(replica);
        }
    }

    /// Keeps the replica's chunk after the delta of `seq` if it is the
    /// result of one of our edits (or may be, its verdict not being in).
    fn record_result(&mut self, seq: u64, pos: ChunkPos, chunk: Arc<Chunk>) {
        let mine = self
            .pending
            .iter_mut()
            .find(|p| p.accepted.as_ref().is_some_and(|a| a.seq == seq));
        if let Some(p) = mine {
            let a = p.accepted.as_ref().expect("found by its seq");
            if a.changes.iter().any(|c| c.pos == pos) {
                p.results.insert(pos, chunk);
            }
            return;
        }
        let maybe_mine = self
            .pending
            .iter()
            .any(|p| p.accepted.is_none() && p.made.iter().any(|(c, _)| *c == pos));
        if maybe_mine {
            if self.unclaimed.len() >= MAX_UNCLAIMED_RESULTS {
                self.unclaimed.pop_front();
            }
            self.unclaimed.push_back((seq, pos, chunk));
        }
    }

    /// Counts and drops every edit the replica now fully reflects, then
    /// rebuilds the view.
    fn settle(&mut self, replica: &Replica) {
        let mut i = 0;
        while i < self.pending.len() {
            if !self.pending[i].settled(replica) {
                i += 1;
                continue;
            }
            match self.pending.remove(i).outcome() {
                Outcome::Exact => self.stats.exact += 1,
                Outcome::Mispredicted { in_box } => {
                    self.stats.mispredicted += 1;
                    self.stats.mispredicted_outside_box += u64::from(!in_box);
                }
                Outcome::Unverified => self.stats.unverified += 1,
            }
        }
        if self.pending.iter().all(|p| p.accepted.is_some()) {
            self.unclaimed.clear();
        }
        self.replay(replica);
    }

    /// Rebuilds the view: the replica's chunks, then every pending edit in
    /// order, each undone on the chunks that already reflect it. Returns
    /// the chunks the last pending edit changed (`None` if it could not be
    /// applied).
    fn replay(&mut self, replica: &Replica) -> Option<Vec<(ChunkPos, Arc<Chunk>)>> {
        self.view.clear();
        let ctx = EditContext {
            materials: &self.materials,
            structures: &self.structures,
        };
        // Every chunk an edit reads is inserted before it is applied, so
        // the world never generates one: its generator is never consulted.
        let mut world = World::new(Arc::new(FlatGenerator { ground: Voxel::AIR }));
        let mut written = BTreeSet::new();
        let mut last = None;
        for (i, p) in self.pending.iter().enumerate() {
            let is_last = i + 1 == self.pending.len();
            let mut held = true;
            for &c in &p.reads {
                if world.peek(c).is_some() {
                    continue;
                }
                match replica.get(c) {
                    Some(h) => world.insert(c, h.chunk.clone(), h.version),
                    None => held = false,
                }
            }
            if !held {
                continue;
            }
            let Ok(out) = p.edit.apply(&mut world, &ctx) else {
                continue;
            };
            let mut changed = Vec::new();
            for ch in out.changed {
                if p.included(ch.pos, replica) {
                    world.insert(ch.pos, ch.before, ch.from_version);
                } else {
                    written.insert(ch.pos);
                    changed.push(ch.pos);
                }
            }
            if is_last {
                last = Some(changed);
            }
        }
        let mut fresh = HashMap::new();
        for pos in written {
            let Some(c) = world.peek(pos).map(|v| &v.chunk) else {
                continue;
            };
            // The world's own chunk, shared: no copy.
            let chunk = c.clone();
            if replica.get(pos).is_none_or(|h| *h.chunk != **c) {
                self.view.insert(pos, chunk.clone());
            }
            fresh.insert(pos, chunk);
        }
        last.map(|ps| {
            ps.into_iter()
                .filter_map(|p| fresh.get(&p).map(|c| (p, c.clone())))
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::edit::{Fixed, FixedVec3};

    /// A replica holding every chunk around the origin, generated flat.
    fn replica() -> Replica {
        let stone = Voxel::solid(strata_terrain::material::ids::STONE);
        let mut r = Replica::new(Some(Arc::new(FlatGenerator { ground: stone })));
        for x in -2..=2 {
            for y in -2..=2 {
                for z in -2..=2 {
                    r.apply(WorldUpdate::Generated {
                        pos: ChunkPos::new(x, y, z),
                    });
                }
            }
        }
        r
    }

    #[test]
    fn a_verdict_keeps_only_changes_the_edit_could_make_each_once() {
        let replica = replica();
        let mut p = Prediction::new(Arc::new(StructureLibrary::default()), 4);
        let at = |v: f64| Fixed::from_f64(v).unwrap();
        let edit = Edit::Mine {
            center: FixedVec3::new(at(4.0), at(4.0), at(4.0)),
            radius: at(2.0),
            strength: 60,
        };
        assert!(p.predict(1, edit, &replica));
        let here = ChunkPos::new(0, 0, 0);
        // A hostile verdict: the edit's own chunk many times over, and
        // chunks it cannot have changed.
        let mut changes = vec![
            ChunkVersion {
                pos: here,
                version: 1
            };
            10_000
        ];
        changes.extend((0..10_000).map(|i| ChunkVersion {
            pos: ChunkPos::new(1_000 + i, 0, 0),
            version: 1,
        }));
        p.verdict(1, &Verdict::Accepted { seq: 1 }, &changes, &replica);
        let kept = &p.pending[0].accepted.as_ref().unwrap().changes;
        assert_eq!(
            kept,
            &[ChunkVersion {
                pos: here,
                version: 1
            }]
        );
    }
}
