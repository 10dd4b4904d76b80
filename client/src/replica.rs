//! The client's copy of the chunks it sees: snapshots and deltas applied
//! with version and hash checks, version-0 chunks regenerated from the seed,
//! and mesh hashes compared with the server's.

use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};
use std::sync::Arc;

use strata_protocol::{DeltaUpdate, OpUpdate, WorldUpdate};
use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::delta::{ChunkDelta, DeltaError};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Voxel, VoxelPos};

use crate::bounds::{ChunkLimits, Violation};
use crate::mesh_checks::{MeshCheck, MeshChecks};
use crate::pool::ChunkPool;
use crate::replay::{replay, ReplayFailure};

/// Mesh mismatches a replica keeps (the first ones); later ones are only
/// counted ([`Replica::mesh_mismatches_dropped`]): a server sending wrong
/// mesh hashes must not grow the client without end.
pub const MAX_MESH_MISMATCHES_KEPT: usize = 1024;

/// Chunks a replica remembers having asked for again (a gap, a failed
/// check) until their whole copy comes; past it, a late delta of one more
/// asks again, as if not remembered.
pub const MAX_ASKED_AGAIN: usize = 4096;

/// A chunk as held by the client.
#[derive(Debug, Clone)]
pub struct Held {
    /// Shared with other replicas holding the same version (see [`ChunkPool`]).
    pub chunk: Arc<Chunk>,
    pub version: u64,
    /// `chunk_hash(&chunk)`, checked when the chunk was taken in.
    pub hash: u64,
}

/// A mesh whose hash differs from the server's: a consistency bug.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MeshMismatch {
    pub pos: ChunkPos,
    pub version: u64,
    pub server: u64,
    pub client: u64,
}

/// A server mesh hash to compare at the next tick end.
#[derive(Debug, Clone, Copy)]
struct PendingMesh {
    version: u64,
    hash: u64,
    /// The edit whose delta carried it; `None` for a snapshot.
    seq: Option<u64>,
}

/// What the client must ask the server for after an update.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// A version gap or hash mismatch: resend the chunk.
    Resync(ChunkPos),
    /// The client cannot regenerate: send full data.
    FullSnapshot(ChunkPos),
    /// An op that did not replay on these chunks: resend each.
    ResyncMany(Vec<ChunkPos>),
}

/// Counters a load test reports.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplicaStats {
    /// Whole chunks taken in: snapshots and patches.
    pub snapshots: u64,
    /// Of those, patches (deltas from the generated chunk).
    pub patched: u64,
    pub generated: u64,
    pub deltas: u64,
    pub delta_payload_bytes: u64,
    /// Ops replayed (`WorldUpdate::Op`), and the chunks they took forward.
    pub ops: u64,
    pub op_chunks: u64,
    /// Op chunks not held at the op's base version (or a chunk the edit
    /// reads not held): resynced.
    pub op_gaps: u64,
    /// Op chunks whose replayed hash was not the server's: resynced.
    pub op_mismatches: u64,
    pub gaps: u64,
    pub hash_mismatches: u64,
    pub meshes_checked: u64,
    pub mesh_mismatches: u64,
    pub meshes_unverifiable: u64,
    /// Chunks compared with the server's copy on request ([`Replica::expect_check`]).
    pub checks_ok: u64,
    /// Checked chunks whose version or hash differed from the server's.
    pub checks_failed: u64,
}

impl std::ops::AddAssign for ReplicaStats {
    /// Sums counters (a player's connections, a load test's bots).
    fn add_assign(&mut self, b: Self) {
        self.snapshots += b.snapshots;
        self.patched += b.patched;
        self.generated += b.generated;
        self.deltas += b.deltas;
        self.delta_payload_bytes += b.delta_payload_bytes;
        self.gaps += b.gaps;
        self.hash_mismatches += b.hash_mismatches;
        self.meshes_checked += b.meshes_checked;
        self.mesh_mismatches += b.mesh_mismatches;
        self.meshes_unverifiable += b.meshes_unverifiable;
        self.checks_ok += b.checks_ok;
        self.checks_failed += b.checks_failed;
        self.ops += b.ops;
        self.op_chunks += b.op_chunks;
        self.op_gaps += b.op_gaps;
        self.op_mismatches += b.op_mismatches;
    }
}

/// Chunks held by one client.
#[derive(Debug)]
pub struct Replica {
    generator: Option<Arc<dyn ChunkGenerator>>,
    chunks: HashMap<ChunkPos, Held>,
    /// Server mesh hashes to check at the next tick end: pos -> (version, hash).
    pending_mesh: HashMap<ChunkPos, PendingMesh>,
    /// The first [`MAX_MESH_MISMATCHES_KEPT`] mismatches.
    mismatches: Vec<MeshMismatch>,
    /// Mismatches past [`MAX_MESH_MISMATCHES_KEPT`], not kept.
    mismatches_dropped: u64,
    /// Where the server's chunks may lie and how many may be held; `None`:
    /// anything goes (a replica fed by the caller, not a server).
    limits: Option<ChunkLimits>,
    /// Every version each chunk passed through, when recording.
    history: Option<HashMap<ChunkPos, Vec<u64>>>,
    /// The hash of every (chunk, version) held, when recording.
    version_hashes: Option<HashMap<(ChunkPos, u64), u64>>,
    /// Chunks whose next snapshot is compared with the held copy.
    checks: HashSet<ChunkPos>,
    pool: Arc<ChunkPool>,
    pub stats: ReplicaStats,
    last_seq: u64,
    /// Chunks the client forgot (`Forget`): deltas and whole chunks still
    /// in flight for them are dropped, not answered with a resync, until
    /// the client asks for the chunk again ([`Replica::undrop`]) or it
    /// leaves the view.
    dropped: HashSet<ChunkPos>,
    /// Chunks whose check ([`Self::expect_check`]) the server's withdrawal
    /// of the held copy cancelled: [`Self::take_lost_checks`].
    lost_checks: Vec<ChunkPos>,
    /// Set by [`Self::defer_mesh_checks`].
    defer_checks: bool,
    /// Held chunks asked for again ([`Self::expect_resync`]) whose whole
    /// copy has not come yet: the server sends no delta of them meanwhile,
    /// so no mesh reading them is checked.
    resyncing: HashSet<ChunkPos>,
    /// Chunks dropped and asked for again after a gap or a failed check,
    /// whose whole copy has not come yet: deltas and ops of them still in
    /// flight from before the request are late, not another gap, and ask
    /// nothing more. At most [`MAX_ASKED_AGAIN`].
    asked: HashSet<ChunkPos>,
}

impl Replica {
    /// Drops a chunk that left the view (or whose copy the server withdrew).
    fn forget(&mut self, pos: ChunkPos) {
        self.dropped.remove(&pos);
        self.resyncing.remove(&pos);
        self.asked.remove(&pos);
        if self.checks.remove(&pos) {
            self.lost_checks.push(pos);
        }
        self.chunks.remove(&pos);
        self.pending_mesh.remove(&pos);
    }

    /// `generator` regenerates version-0 chunks; without one, the replica
    /// asks for full snapshots instead.
    pub fn new(generator: Option<Arc<dyn ChunkGenerator>>) -> Self {
        Self::with_pool(generator, Arc::default())
    }

    /// A replica sharing chunks and mesh hashes with others through `pool`.
    pub fn with_pool(generator: Option<Arc<dyn ChunkGenerator>>, pool: Arc<ChunkPool>) -> Self {
        Self {
            generator,
            chunks: HashMap::default(),
            pending_mesh: HashMap::default(),
            mismatches: Vec::new(),
            mismatches_dropped: 0,
            limits: None,
            history: None,
            version_hashes: None,
            checks: HashSet::default(),
            pool,
            stats: ReplicaStats::default(),
            last_seq: 0,
            dropped: HashSet::default(),
            lost_checks: Vec::new(),
            defer_checks: false,
            resyncing: HashSet::default(),
            asked: HashSet::default(),
        }
    }

    /// Holds the server's updates to `limits` ([`Self::try_apply`]).
    pub fn limit(&mut self, limits: ChunkLimits) {
        self.limits = Some(limits);
    }

    pub fn limits(&self) -> Option<ChunkLimits> {
        self.limits
    }

    /// Drops a chunk the client no longer wants (it sends `Forget`): it is
    /// not held, and late deltas and whole chunks for it (sent before the
    /// server handled the `Forget`) are ignored until [`Self::undrop`] or
    /// the server's withdrawal. Only a chunk held is marked so: the server
    /// withdraws only chunks it sent, and one not held either was never
    /// sent (taken in when it is, once back in view), is on its way with
    /// its withdrawal behind it, or was withdrawn already.
    pub fn drop_chunk(&mut self, pos: ChunkPos) {
        let held = self.chunks.contains_key(&pos);
        self.forget(pos);
        if held {
            self.dropped.insert(pos);
        }
    }

    /// Marks `pos` dropped (the game forgot it while held, and it has left
    /// the replica): see [`Self::drop_chunk`].
    pub fn mark_dropped(&mut self, pos: ChunkPos) {
        self.dropped.insert(pos);
    }

    /// The client asks for a dropped chunk again (`ResyncRequest` or
    /// `FullSnapshotRequest`): the chunk sent in answer is taken in. Call
    /// before sending the request.
    pub fn undrop(&mut self, pos: ChunkPos) {
        self.dropped.remove(&pos);
    }

    /// The client asks for a fresh copy of `pos` (`ResyncRequest`): if it
    /// holds one, the server stops its deltas until the copy is sent, so
    /// meshes reading it are not checked meanwhile (a neighbour's change
    /// would be meshed against the stale copy: a false mismatch). Call
    /// before sending the request.
    pub fn expect_resync(&mut self, pos: ChunkPos) {
        if self.chunks.contains_key(&pos) {
            self.resyncing.insert(pos);
        }
    }

    /// Whether `pos` was dropped with [`Self::drop_chunk`] and not asked for
    /// again since.
    pub fn is_dropped(&self, pos: ChunkPos) -> bool {
        self.dropped.contains(&pos)
    }

    /// Records every version each chunk passes through, and its hash
    /// (ordering tests).
    pub fn record_history(&mut self) {
        self.history.get_or_insert_with(HashMap::default);
        self.version_hashes.get_or_insert_with(HashMap::default);
    }

    pub fn history(&self) -> Option<&HashMap<ChunkPos, Vec<u64>>> {
        self.history.as_ref()
    }

    /// The chunk hash of every `(pos, version)` held while recording.
    pub fn version_hashes(&self) -> Option<&HashMap<(ChunkPos, u64), u64>> {
        self.version_hashes.as_ref()
    }

    /// Compares the held copy of `pos` with the next `Snapshot` (or
    /// `Generated`) of it: the caller then asks the server for the chunk.
    /// Results land in `stats.checks_ok` / `stats.checks_failed`.
    pub fn expect_check(&mut self, pos: ChunkPos) {
        self.checks.insert(pos);
    }

    /// Checks asked for and not answered yet.
    pub fn checks_pending(&self) -> usize {
        self.checks.len()
    }

    /// Checks cancelled since the last call: the server withdrew the held
    /// copy (its changes dropped on a full queue, or the chunk left the
    /// view) before answering. A copy sent again can be checked anew.
    pub fn take_lost_checks(&mut self) -> Vec<ChunkPos> {
        std::mem::take(&mut self.lost_checks)
    }

    /// Whether the check of `pos` is still waiting for the server.
    pub fn is_checking(&self, pos: ChunkPos) -> bool {
        self.checks.contains(&pos)
    }

    fn check(&mut self, pos: ChunkPos, version: u64, hash: Option<u64>) {
        if !self.checks.remove(&pos) {
            return;
        }
        let same = self
            .chunks
            .get(&pos)
            .is_some_and(|h| h.version == version && hash.is_none_or(|hash| h.hash == hash));
        if same {
            self.stats.checks_ok += 1;
        } else {
            self.stats.checks_failed += 1;
        }
    }

    pub fn get(&self, pos: ChunkPos) -> Option<&Held> {
        self.chunks.get(&pos)
    }

    pub fn chunks(&self) -> impl Iterator<Item = (ChunkPos, &Held)> {
        self.chunks.iter().map(|(p, h)| (*p, h))
    }

    pub fn len(&self) -> usize {
        self.chunks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.chunks.is_empty()
    }

    /// Sequence number of the last tick end seen.
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// The first [`MAX_MESH_MISMATCHES_KEPT`] mesh mismatches
    /// (`stats.mesh_mismatches` counts them all).
    pub fn mesh_mismatches(&self) -> &[MeshMismatch] {
        &self.mismatches
    }

    /// Mesh mismatches found past [`MAX_MESH_MISMATCHES_KEPT`], not kept.
    pub fn mesh_mismatches_dropped(&self) -> u64 {
        self.mismatches_dropped
    }

    fn hold(&mut self, pos: ChunkPos, chunk: Arc<Chunk>, version: u64, hash: u64) {
        if let Some(h) = self.history.as_mut() {
            let seen = h.entry(pos).or_default();
            if seen.last() != Some(&version) {
                seen.push(version);
            }
        }
        if let Some(h) = self.version_hashes.as_mut() {
            h.insert((pos, version), hash);
        }
        self.chunks.insert(
            pos,
            Held {
                chunk,
                version,
                hash,
            },
        );
    }

    /// The generator's chunk, shared through the pool.
    fn generated(&self, g: &Arc<dyn ChunkGenerator>, pos: ChunkPos) -> (Arc<Chunk>, u64) {
        self.pool.get(pos, 0).unwrap_or_else(|| {
            let chunk = g.generate(pos);
            let hash = chunk_hash(&chunk);
            (self.pool.intern(pos, 0, hash, chunk), hash)
        })
    }

    /// Whether `update` keeps within the limits ([`Self::limit`]): every
    /// chunk it names lies inside the world, and a chunk it would newly
    /// hold fits under the cap. Unsubscribes always pass.
    pub fn admit(&self, update: &WorldUpdate) -> Result<(), Violation> {
        let Some(limits) = &self.limits else {
            return Ok(());
        };
        match update {
            WorldUpdate::Delta(d) => limits.check(d.delta.pos)?,
            WorldUpdate::Op(op) => {
                for c in &op.chunks {
                    limits.check(c.pos)?;
                }
            }
            _ => {}
        }
        if let Some(pos) = whole_chunk_pos(update) {
            limits.check(pos)?;
            let new = !self.chunks.contains_key(&pos) && !self.dropped.contains(&pos);
            let max = limits.max_held();
            if new && self.chunks.len() >= max {
                return Err(Violation::TooManyChunks { pos, max });
            }
        }
        Ok(())
    }

    /// Applies one update if it keeps within the limits ([`Self::admit`]);
    /// returns what must be requested from the server.
    pub fn try_apply(&mut self, update: WorldUpdate) -> Result<Option<Request>, Violation> {
        self.admit(&update)?;
        Ok(self.apply_admitted(update))
    }

    /// Applies one update; returns what must be requested from the server.
    /// An update past the limits changes nothing ([`Self::try_apply`] says
    /// why).
    pub fn apply(&mut self, update: WorldUpdate) -> Option<Request> {
        self.try_apply(update).unwrap_or(None)
    }

    fn apply_admitted(&mut self, update: WorldUpdate) -> Option<Request> {
        // A whole chunk the server sent before it handled our `Forget`: it
        // would be held at a version the server no longer takes forward.
        if let Some(pos) = whole_chunk_pos(&update) {
            if self.dropped.contains(&pos) {
                return None;
            }
        }
        match update {
            WorldUpdate::Generated { pos } => match self.generator.clone() {
                Some(g) => {
                    self.check(pos, 0, None);
                    let (chunk, hash) = self.generated(&g, pos);
                    self.stats.generated += 1;
                    self.hold(pos, chunk, 0, hash);
                    self.resyncing.remove(&pos);
                    self.asked.remove(&pos);
                    None
                }
                None => Some(Request::FullSnapshot(pos)),
            },
            WorldUpdate::Snapshot {
                pos,
                version,
                hash,
                mesh_hash,
                data,
            } => {
                let chunk = self.snapshot_chunk(pos, version, hash, &data);
                self.take_whole(pos, version, hash, mesh_hash, chunk)
            }
            WorldUpdate::Patched { delta, mesh_hash } => {
                let Some(g) = self.generator.clone() else {
                    return Some(Request::FullSnapshot(delta.pos));
                };
                let (pos, version, hash) = (delta.pos, delta.to_version, delta.target_hash);
                let chunk = self.patched_chunk(&g, &delta);
                self.stats.patched += u64::from(chunk.is_some());
                self.take_whole(pos, version, hash, mesh_hash, chunk)
            }
            WorldUpdate::Delta(d) => self.apply_delta(d),
            WorldUpdate::Op(op) => self.apply_op(&op),
            WorldUpdate::Unsubscribed { pos } => {
                self.forget(pos);
                None
            }
            WorldUpdate::UnsubscribedMany { chunks } => {
                for pos in chunks {
                    self.forget(pos);
                }
                None
            }
            WorldUpdate::TickEnd { last_seq } => {
                self.last_seq = self.last_seq.max(last_seq);
                if !self.defer_checks {
                    self.verify_meshes();
                }
                None
            }
            WorldUpdate::InterestComplete { .. } => None,
        }
    }

    /// Asks for `pos` again, remembering so until its whole copy comes.
    fn ask_again(&mut self, pos: ChunkPos) -> Option<Request> {
        self.remember_asked(pos);
        Some(Request::Resync(pos))
    }

    fn remember_asked(&mut self, pos: ChunkPos) {
        if self.asked.len() < MAX_ASKED_AGAIN {
            self.asked.insert(pos);
        }
    }

    fn apply_delta(&mut self, d: DeltaUpdate) -> Option<Request> {
        let pos = d.delta.pos;
        let Some(held) = self.chunks.get(&pos) else {
            if self.dropped.contains(&pos) || self.asked.contains(&pos) {
                return None;
            }
            self.stats.gaps += 1;
            return self.ask_again(pos);
        };
        if held.version != d.delta.from_version {
            self.stats.gaps += 1;
            self.chunks.remove(&pos);
            return self.ask_again(pos);
        }
        match self.apply_checked(&d, held) {
            Ok(chunk) => {
                self.stats.deltas += 1;
                self.stats.delta_payload_bytes += d.delta.payload.len() as u64;
                let (version, hash) = (d.delta.to_version, d.delta.target_hash);
                self.hold(pos, chunk, version, hash);
                self.neighbour_changed(pos, Some(d.seq));
                let p = PendingMesh {
                    version,
                    hash: d.mesh_hash,
                    seq: Some(d.seq),
                };
                self.pending_mesh.insert(pos, p);
                None
            }
            Err(_) => {
                self.stats.hash_mismatches += 1;
                self.chunks.remove(&pos);
                self.ask_again(pos)
            }
        }
    }

    /// Replays an op on the held chunks (see [`crate::replay`]); chunks it
    /// could not take forward are dropped and asked for again.
    fn apply_op(&mut self, op: &OpUpdate) -> Option<Request> {
        self.stats.ops += 1;
        let results = replay(op, |p| self.chunks.get(&p).cloned());
        let mut resync = Vec::new();
        for (c, result) in results {
            match result {
                Ok(chunk) => {
                    self.stats.op_chunks += 1;
                    let chunk = self.pool.intern(c.pos, c.version, c.hash, chunk);
                    self.hold(c.pos, chunk, c.version, c.hash);
                    self.neighbour_changed(c.pos, Some(op.seq));
                    let p = PendingMesh {
                        version: c.version,
                        hash: c.mesh_hash,
                        seq: Some(op.seq),
                    };
                    self.pending_mesh.insert(c.pos, p);
                }
                // Forgotten, or asked for again already: no resync, as
                // for a delta.
                Err(_) if self.dropped.contains(&c.pos) || self.asked.contains(&c.pos) => {}
                Err(f) => {
                    match f {
                        ReplayFailure::MissingBase => self.stats.op_gaps += 1,
                        ReplayFailure::Mismatch => self.stats.op_mismatches += 1,
                    }
                    self.chunks.remove(&c.pos);
                    self.pending_mesh.remove(&c.pos);
                    self.remember_asked(c.pos);
                    resync.push(c.pos);
                }
            }
        }
        (!resync.is_empty()).then_some(Request::ResyncMany(resync))
    }

    /// Holds a whole chunk sent by the server (a snapshot or a patch), or
    /// asks for it again if it failed its checks (`None`).
    fn take_whole(
        &mut self,
        pos: ChunkPos,
        version: u64,
        hash: u64,
        mesh_hash: u64,
        chunk: Option<Arc<Chunk>>,
    ) -> Option<Request> {
        // The answer to an earlier request, good or not.
        self.asked.remove(&pos);
        let Some(chunk) = chunk else {
            self.stats.hash_mismatches += 1;
            self.chunks.remove(&pos);
            return self.ask_again(pos);
        };
        self.stats.snapshots += 1;
        self.resyncing.remove(&pos);
        self.check(pos, version, Some(hash));
        if self.chunks.get(&pos).is_none_or(|h| h.version != version) {
            self.neighbour_changed(pos, None);
        }
        self.hold(pos, chunk, version, hash);
        if version > 0 {
            let p = PendingMesh {
                version,
                hash: mesh_hash,
                seq: None,
            };
            self.pending_mesh.insert(pos, p);
        }
        None
    }

    /// The chunk a patch makes of the generated chunk, if the patch starts
    /// at version 0 and passes the delta's hash checks; a copy another
    /// replica of this process checked is shared instead.
    fn patched_chunk(&self, g: &Arc<dyn ChunkGenerator>, delta: &ChunkDelta) -> Option<Arc<Chunk>> {
        if delta.from_version != 0 {
            return None;
        }
        if let Some((chunk, h)) = self.pool.get(delta.pos, delta.to_version) {
            if h == delta.target_hash {
                return Some(chunk);
            }
        }
        let (base, base_hash) = self.generated(g, delta.pos);
        if base_hash != delta.base_hash {
            return None;
        }
        let chunk = delta.apply_to_checked_base(&base).ok()?;
        Some(
            self.pool
                .intern(delta.pos, delta.to_version, delta.target_hash, chunk),
        )
    }

    /// The chunk a snapshot carries, if it decodes and hashes to `hash`; a
    /// copy another replica of this process checked is shared instead.
    fn snapshot_chunk(
        &self,
        pos: ChunkPos,
        version: u64,
        hash: u64,
        data: &[u8],
    ) -> Option<Arc<Chunk>> {
        if let Some((chunk, h)) = self.pool.get(pos, version) {
            if h == hash {
                return Some(chunk);
            }
        }
        let chunk = decode_chunk(data).ok().filter(|c| chunk_hash(c) == hash)?;
        Some(self.pool.intern(pos, version, hash, chunk))
    }

    /// The chunk `d` makes of `held`. When another replica of this process
    /// already took the same base (by hash) to the same target (version and
    /// hash), its checked result is shared instead of decoded again: the
    /// delta and both hashes are identical, so the result would be too.
    fn apply_checked(&self, d: &DeltaUpdate, held: &Held) -> Result<Arc<Chunk>, DeltaError> {
        let delta = &d.delta;
        if held.hash != delta.base_hash {
            return Err(DeltaError::BaseMismatch {
                expected: delta.base_hash,
                actual: held.hash,
            });
        }
        if let Some((chunk, hash)) = self.pool.get(delta.pos, delta.to_version) {
            if hash == delta.target_hash {
                return Ok(chunk);
            }
        }
        let chunk = delta.apply_to_checked_base(&held.chunk)?;
        Ok(self
            .pool
            .intern(delta.pos, delta.to_version, delta.target_hash, chunk))
    }

    /// `pos` changed (by edit `seq`, or to a snapshot): a pending check of
    /// a neighbour expects the mesh before this change unless the same edit
    /// made both, so it is dropped. (The server hashes meshes at its tick's
    /// end, but a lost `TickEnd` or a snapshot can let a later change in.)
    fn neighbour_changed(&mut self, pos: ChunkPos, seq: Option<u64>) {
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(n) = pos.offset(dx, dy, dz).filter(|n| *n != pos) else {
                        continue;
                    };
                    if let Some(p) = self.pending_mesh.get(&n) {
                        if seq.is_none() || p.seq != seq {
                            self.pending_mesh.remove(&n);
                            self.stats.meshes_unverifiable += 1;
                        }
                    }
                }
            }
        }
    }

    /// Meshes every chunk that changed this tick and compares hashes
    /// (unless [`Self::defer_mesh_checks`]). A chunk is checked only when
    /// the client holds its 26 neighbours, since the mesh reads them.
    fn verify_meshes(&mut self) {
        let mut checks = self.take_mesh_checks();
        checks.run();
        self.finish_mesh_checks(checks);
    }

    /// A tick's end leaves its mesh checks for the caller to take
    /// ([`Self::take_mesh_checks`]), mesh without holding the replica, and
    /// record ([`Self::finish_mesh_checks`]).
    pub fn defer_mesh_checks(&mut self) {
        self.defer_checks = true;
    }

    /// The checks of the chunks changed since the last ones taken: those
    /// still held at the version the server hashed, with every neighbour
    /// held (the others are counted unverifiable); hashes the pool knows
    /// already come filled in.
    pub fn take_mesh_checks(&mut self) -> MeshChecks {
        let pending: Vec<_> = self.pending_mesh.drain().collect();
        let mut items = Vec::with_capacity(pending.len());
        for (pos, p) in pending {
            match self.chunks.get(&pos) {
                Some(h) if h.version == p.version => {}
                _ => continue,
            }
            let check = match self.reads_resyncing(pos) {
                true => None,
                false => self.check_of(pos, p.version, p.hash),
            };
            let Some(check) = check else {
                self.stats.meshes_unverifiable += 1;
                continue;
            };
            items.push(check);
        }
        MeshChecks {
            items,
            pool: self.pool.clone(),
        }
    }

    /// Records checks [`MeshChecks::run`] completed: each compared with
    /// the server's hash, mismatches kept (the first
    /// [`MAX_MESH_MISMATCHES_KEPT`]).
    pub fn finish_mesh_checks(&mut self, checks: MeshChecks) {
        for c in checks.items {
            let Some(client) = c.client else {
                continue;
            };
            self.stats.meshes_checked += 1;
            if client != c.server {
                self.stats.mesh_mismatches += 1;
                if self.mismatches.len() < MAX_MESH_MISMATCHES_KEPT {
                    self.mismatches.push(MeshMismatch {
                        pos: c.pos,
                        version: c.version,
                        server: c.server,
                        client,
                    });
                } else {
                    self.mismatches_dropped += 1;
                }
            }
        }
    }

    /// Whether a mesh of `pos` reads a chunk whose fresh copy is awaited
    /// ([`Self::expect_resync`]).
    fn reads_resyncing(&self, pos: ChunkPos) -> bool {
        !self.resyncing.is_empty()
            && (-1..=1).any(|dz| {
                (-1..=1).any(|dy| {
                    (-1..=1).any(|dx| {
                        pos.offset(dx, dy, dz)
                            .is_some_and(|n| self.resyncing.contains(&n))
                    })
                })
            })
    }

    /// The 27 chunks around `pos` (x fastest then y then z), when every
    /// one is held.
    fn around(&self, pos: ChunkPos) -> Option<[&Held; 27]> {
        let mut held: [Option<&Held>; 27] = [None; 27];
        let mut i = 0;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    held[i] = Some(self.chunks.get(&pos.offset(dx, dy, dz)?)?);
                    i += 1;
                }
            }
        }
        let all: Vec<&Held> = held.into_iter().flatten().collect();
        all.try_into().ok()
    }

    /// The check of `pos` at `version` (the server's hash `server`):
    /// filled in from the pool, or holding the chunks to mesh.
    fn check_of(&self, pos: ChunkPos, version: u64, server: u64) -> Option<MeshCheck> {
        let around = self.around(pos)?;
        let key = (pos, around.map(|h| h.version));
        let client = self.pool.mesh_hash(&key);
        Some(MeshCheck {
            pos,
            version,
            server,
            key,
            around: client
                .is_none()
                .then(|| Box::new(around.map(|h| h.chunk.clone()))),
            client,
        })
    }

    /// The LOD-0 mesh hash of a chunk from held chunks only (memoized in
    /// the pool by the 27 chunk versions it reads).
    pub fn mesh_hash(&self, pos: ChunkPos) -> Option<u64> {
        let mut checks = MeshChecks {
            items: vec![self.check_of(pos, 0, 0)?],
            pool: self.pool.clone(),
        };
        checks.run();
        checks.items[0].client
    }

    /// One held voxel; `None` when its chunk is not held.
    pub fn voxel(&self, p: VoxelPos) -> Option<Voxel> {
        let (x, y, z) = p.local();
        self.chunks.get(&p.chunk()).map(|h| h.chunk.get(x, y, z))
    }
}

/// The chunk a whole-chunk update (`Generated`, `Snapshot`, `Patched`) carries.
fn whole_chunk_pos(update: &WorldUpdate) -> Option<ChunkPos> {
    match update {
        WorldUpdate::Generated { pos } | WorldUpdate::Snapshot { pos, .. } => Some(*pos),
        WorldUpdate::Patched { delta, .. } => Some(delta.pos),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::chunk_codec::encode_chunk;
    use strata_terrain::material::ids;
    use strata_terrain::world::FlatGenerator;

    fn flat() -> Arc<dyn ChunkGenerator> {
        Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        })
    }

    fn generated(x: i32, y: i32, z: i32) -> WorldUpdate {
        WorldUpdate::Generated {
            pos: ChunkPos::new(x, y, z),
        }
    }

    fn snapshot(pos: ChunkPos, version: u64, chunk: &Chunk, mesh_hash: u64) -> WorldUpdate {
        WorldUpdate::Snapshot {
            pos,
            version,
            hash: chunk_hash(chunk),
            mesh_hash,
            data: encode_chunk(chunk),
        }
    }

    #[test]
    fn chunks_outside_the_world_are_refused_before_any_is_generated() {
        let mut r = Replica::new(Some(flat()));
        r.limit(ChunkLimits::new(2, Some((-4, 7))));
        let far = ChunkPos::new(1 << 26, 0, 0);
        let max = crate::bounds::MAX_CHUNK_COORD;
        let outside = Violation::OutsideWorld { pos: far, max };
        assert_eq!(r.try_apply(generated(1 << 26, 0, 0)), Err(outside.clone()));
        let air = Chunk::uniform(Voxel::AIR);
        assert_eq!(r.try_apply(snapshot(far, 3, &air, 0)), Err(outside));
        let delta = ChunkDelta::encode(far, 0, 1, &air, &Chunk::uniform(Voxel::solid(1))).unwrap();
        let d = WorldUpdate::Delta(DeltaUpdate {
            delta,
            mesh_hash: 0,
            seq: 1,
        });
        assert!(matches!(
            r.try_apply(d),
            Err(Violation::OutsideWorld { .. })
        ));
        // A row the world does not have.
        assert!(matches!(
            r.try_apply(generated(0, 8, 0)),
            Err(Violation::OutsideRows { lo: -4, hi: 7, .. })
        ));
        // `apply` drops them too.
        assert_eq!(r.apply(generated(-(1 << 26), 0, 0)), None);
        assert!(r.is_empty());
        assert_eq!(r.stats.generated, 0, "nothing was generated");
        assert_eq!(r.stats.gaps, 0, "nor asked for");
        // Inside the world they are taken in.
        assert_eq!(r.try_apply(generated(0, 7, 0)), Ok(None));
        assert_eq!(r.len(), 1);
    }

    /// A chunk forgotten while not held (withdrawn already, or never in
    /// view) is taken in when the server sends it later: the server
    /// withdraws only chunks it sent, so nothing would ever clear a mark.
    #[test]
    fn a_chunk_forgotten_while_not_held_is_taken_in_when_sent() {
        let mut r = Replica::new(Some(flat()));
        let pos = ChunkPos::new(3, 0, 0);
        r.drop_chunk(pos);
        assert!(!r.is_dropped(pos));
        r.apply(generated(3, 0, 0));
        assert!(r.get(pos).is_some());
        // Held, it is dropped: what the server sent before it took the
        // `Forget` is ignored until the withdrawal.
        r.drop_chunk(pos);
        assert!(r.is_dropped(pos));
        r.apply(generated(3, 0, 0));
        assert!(r.get(pos).is_none());
        r.apply(WorldUpdate::UnsubscribedMany { chunks: vec![pos] });
        r.apply(generated(3, 0, 0));
        assert!(r.get(pos).is_some());
    }

    #[test]
    fn a_check_the_servers_withdrawal_cancels_is_reported_lost() {
        let mut r = Replica::new(Some(flat()));
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        r.apply(generated(0, 0, 0));
        r.apply(generated(1, 0, 0));
        r.expect_check(a);
        r.expect_check(b);
        // a's copy is withdrawn before the server answers; b's is answered.
        r.apply(WorldUpdate::UnsubscribedMany { chunks: vec![a] });
        r.apply(generated(1, 0, 0));
        assert_eq!(r.checks_pending(), 0);
        assert_eq!((r.stats.checks_ok, r.stats.checks_failed), (1, 0));
        assert_eq!(r.take_lost_checks(), vec![a]);
        assert!(r.take_lost_checks().is_empty(), "taken once");
        // A chunk left without a check pending is no lost check.
        r.apply(WorldUpdate::Unsubscribed { pos: b });
        assert!(r.take_lost_checks().is_empty());
    }

    #[test]
    fn held_chunks_are_capped_at_what_any_view_covers() {
        let mut r = Replica::new(Some(flat()));
        // Radius 0, one row: 33 x 33 chunks at most.
        let limits = ChunkLimits::new(0, Some((0, 0)));
        r.limit(limits);
        let max = limits.max_held();
        assert_eq!(max, 33 * 33);
        for z in -16..=16 {
            for x in -16..=16 {
                assert_eq!(r.try_apply(generated(x, 0, z)), Ok(None));
            }
        }
        assert_eq!(r.len(), max);
        // One more is a violation, and changes nothing.
        let pos = ChunkPos::new(17, 0, 0);
        assert_eq!(
            r.try_apply(generated(17, 0, 0)),
            Err(Violation::TooManyChunks { pos, max })
        );
        assert!(r.get(pos).is_none());
        // A chunk held already may come again.
        assert_eq!(r.try_apply(generated(0, 0, 0)), Ok(None));
        // A forgotten one is dropped, not counted.
        r.drop_chunk(ChunkPos::new(16, 0, 16));
        assert_eq!(r.try_apply(generated(16, 0, 16)), Ok(None));
        assert!(r.get(ChunkPos::new(16, 0, 16)).is_none());
        // Room again: the new chunk fits.
        assert_eq!(r.try_apply(generated(17, 0, 0)), Ok(None));
        assert_eq!(r.len(), max);
        // A replica without limits (fed by its caller) holds anything.
        let mut free = Replica::new(Some(flat()));
        assert_eq!(free.try_apply(generated(1 << 26, 0, 0)), Ok(None));
    }

    /// A replica deferring its checks leaves them at a tick's end; taken,
    /// meshed apart and finished, they count as checks made at the tick
    /// (a right hash, then a wrong one).
    #[test]
    fn deferred_mesh_checks_count_as_checks_at_the_tick() {
        let feed = |r: &mut Replica| {
            for dz in -1..=1 {
                for dy in -2..=0 {
                    for dx in -1..=1 {
                        r.apply(generated(dx, dy, dz));
                    }
                }
            }
        };
        let pos = ChunkPos::new(0, -1, 0);
        let stone = Chunk::uniform(Voxel::solid(ids::STONE));
        let mut probe = Replica::new(Some(flat()));
        feed(&mut probe);
        probe.apply(snapshot(pos, 1, &stone, 0));
        let right = probe.mesh_hash(pos).unwrap();
        let mut direct = Replica::new(Some(flat()));
        let mut deferred = Replica::new(Some(flat()));
        deferred.defer_mesh_checks();
        for (v, server) in [(1, right), (2, !right)] {
            for r in [&mut direct, &mut deferred] {
                if v == 1 {
                    feed(r);
                }
                r.apply(snapshot(pos, v, &stone, server));
                r.apply(WorldUpdate::TickEnd { last_seq: v });
            }
            assert_eq!(deferred.stats.meshes_checked, v - 1, "left for the caller");
            let mut checks = deferred.take_mesh_checks();
            assert!(!checks.is_empty());
            checks.run();
            deferred.finish_mesh_checks(checks);
            assert!(deferred.take_mesh_checks().is_empty(), "taken once");
        }
        assert_eq!(direct.stats.meshes_checked, 2, "{:?}", direct.stats);
        assert_eq!(direct.stats.mesh_mismatches, 1);
        assert_eq!(deferred.stats.meshes_checked, 2);
        assert_eq!(deferred.stats.mesh_mismatches, 1);
        assert_eq!(deferred.mesh_mismatches(), direct.mesh_mismatches());
    }

    /// While a held chunk's fresh copy is awaited, meshes reading it are
    /// not checked (the server sends no delta of it meanwhile: a
    /// neighbour's change meshed against it would mismatch); once the
    /// copy comes, they are again.
    #[test]
    fn meshes_reading_a_chunk_being_resynced_are_not_checked() {
        let mut r = Replica::new(Some(flat()));
        for dz in -1..=1 {
            for dy in -2..=0 {
                for dx in -1..=1 {
                    r.apply(generated(dx, dy, dz));
                }
            }
        }
        let (pos, beside) = (ChunkPos::new(0, -1, 0), ChunkPos::new(1, -1, 0));
        let stone = Chunk::uniform(Voxel::solid(ids::STONE));
        r.expect_resync(beside);
        // The server meshed `pos` against a newer `beside`: no mismatch
        // counted, only an unverifiable mesh.
        r.apply(snapshot(pos, 1, &stone, 12345));
        r.apply(WorldUpdate::TickEnd { last_seq: 1 });
        assert_eq!((r.stats.meshes_checked, r.stats.mesh_mismatches), (0, 0));
        assert_eq!(r.stats.meshes_unverifiable, 1);
        // The fresh copy of `beside` ends it.
        r.apply(snapshot(beside, 1, &stone, 0));
        r.apply(WorldUpdate::TickEnd { last_seq: 2 });
        r.apply(snapshot(pos, 2, &stone, 12345));
        r.apply(WorldUpdate::TickEnd { last_seq: 3 });
        assert_eq!(r.stats.mesh_mismatches, 1, "checked again");
    }

    #[test]
    fn mesh_mismatches_kept_are_capped_and_the_rest_counted() {
        let mut r = Replica::new(Some(flat()));
        let pos = ChunkPos::new(0, -1, 0);
        for dz in -1..=1 {
            for dy in -2..=0 {
                for dx in -1..=1 {
                    r.apply(generated(dx, dy, dz));
                }
            }
        }
        let stone = Chunk::uniform(Voxel::solid(ids::STONE));
        let real = r.mesh_hash(pos).unwrap();
        let extra = 5;
        let rounds = MAX_MESH_MISMATCHES_KEPT + extra;
        for v in 1..=rounds as u64 {
            // The server's mesh hash is wrong every time.
            assert_eq!(r.apply(snapshot(pos, v, &stone, !real)), None);
            r.apply(WorldUpdate::TickEnd { last_seq: v });
        }
        assert_eq!(r.stats.mesh_mismatches, rounds as u64);
        assert_eq!(r.mesh_mismatches().len(), MAX_MESH_MISMATCHES_KEPT);
        assert_eq!(r.mesh_mismatches_dropped(), extra as u64);
        assert_eq!(r.mesh_mismatches()[0].version, 1, "the first ones are kept");
    }

    /// After a gap, the deltas still in flight from before the request are
    /// late, not more gaps: the chunk is asked for once, until its whole
    /// copy comes; a gap after that asks again.
    #[test]
    fn a_gap_asks_once_until_the_whole_copy_comes() {
        let mut r = Replica::new(Some(flat()));
        let pos = ChunkPos::new(0, 0, 0);
        let v = |n: u8| Chunk::uniform(Voxel::new(n, ids::STONE));
        let delta = |from: u64, a: u8, b: u8, seq: u64| {
            WorldUpdate::Delta(DeltaUpdate {
                delta: ChunkDelta::encode(pos, from, from + 1, &v(a), &v(b)).unwrap(),
                mesh_hash: 0,
                seq,
            })
        };
        assert_eq!(r.apply(snapshot(pos, 1, &v(10), 0)), None);
        // Version 2 went missing: 2 -> 3 is a gap, then 3 -> 4 is late.
        assert_eq!(r.apply(delta(2, 20, 30, 2)), Some(Request::Resync(pos)));
        assert_eq!(r.apply(delta(3, 30, 40, 3)), None);
        assert_eq!(r.stats.gaps, 1);
        // An op of the chunk, late as well, asks nothing.
        let op = WorldUpdate::Op(OpUpdate {
            seq: 4,
            edit: strata_terrain::Edit::ClearBox {
                min: VoxelPos::new(0, 0, 0),
                max: VoxelPos::new(0, 0, 0),
            },
            chunks: vec![strata_protocol::OpChunk {
                pos,
                version: 5,
                hash: 0,
                mesh_hash: 0,
            }],
        });
        assert_eq!(r.apply(op), None);
        // The copy comes; the next gap asks again.
        assert_eq!(r.apply(snapshot(pos, 5, &v(50), 0)), None);
        assert_eq!(r.apply(delta(6, 60, 70, 6)), Some(Request::Resync(pos)));
        assert_eq!(r.stats.gaps, 2);
        // A chunk that leaves the view is not remembered as asked.
        r.apply(WorldUpdate::Unsubscribed { pos });
        assert_eq!(r.apply(delta(7, 70, 80, 7)), Some(Request::Resync(pos)));
    }
}
