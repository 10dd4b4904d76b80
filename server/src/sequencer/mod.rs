//! The sequencer: the single writer that validates, orders and applies edits.
//!
//! Synchronous and I/O-free: the async shell feeds it sessions, positions
//! and edit requests, calls [`Sequencer::tick`] on its timer, writes the
//! returned [`CommitBatch`] to the store, and only then acknowledges edits
//! and broadcasts deltas. Time arrives as `now_ms` so tests are deterministic.

pub mod batch;
mod chunk_bits;
pub use crate::store::{CommitBatch, LogEntry, StoredPosition};

/// How much older than another node's stored time a ticket may be: a node
/// issues a fresh ticket every `TICKET_TTL_MS / 3` (`engine::owners`) and
/// saves positions every second, so a player that walks on and uses its
/// latest ticket at once is seen up to that much after the ticket. An
/// older ticket (a replay) is refused.
pub const STORED_TICKET_SLACK_MS: u64 = strata_protocol::limits::TICKET_TTL_MS / 3 + 2_000;

/// The most an arrival's grace may count past the time its player was
/// last seen: the issuing node's save interval (1 s) and the client's
/// connect to this one. A player silent since its ticket gets no more.
pub const ARRIVAL_HANDOFF_MS: u64 = 3_000;

pub mod config;
mod reach;
pub mod regions;
pub mod residency;
pub mod session;
mod sight;
mod submit;
mod tick;

pub use batch::{AppliedEdit, ApplySplit, ChunkUpdate, RejectedEdit, TickOutput};
pub use config::{SequencerConfig, DEFAULT_MAX_EDITS_PER_TICK, DEFAULT_QUEUE_CAPACITY};
pub use sight::SightRefusal;
pub use submit::Prechecked;
pub use tick::{BuiltMeshes, PendingMeshes};

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;

use rayon::prelude::*;

use strata_protocol::{EditRequest, PositionUpdate, Role, Start};
use strata_terrain::edit::{EditContext, FixedVec3, StructureLibrary};
use strata_terrain::{Chunk, ChunkPos, MaterialTable, Voxel, VoxelPos, VoxelRead, World};

use crate::collision::{CollisionCache, CollisionMesh};
use crate::sequencer::regions::RegionId;
use crate::validate::position::{self, Placement, PositionReject, ValidatedPosition};
use crate::validate::zones::{self, Zone, ZoneError};
use crate::validate::ValidationConfig;
use chunk_bits::ChunkBits;
use residency::{with_neighbours, Residency};
use session::{PlayerLimits, Session};

/// An accepted edit waiting for the next tick.
#[derive(Debug, Clone)]
struct Queued {
    session_id: u64,
    player: String,
    request: EditRequest,
    /// The volume tokens it took, given back if it is taken out unapplied.
    volume_cost: u64,
    /// When the engine took the request, for the edit latency metric.
    queued_at: std::time::Instant,
    /// The chunks its sight ray crossed, checked on this node's copies
    /// (none for an edit without a sight check).
    ray: Vec<ChunkPos>,
}

/// Edits taken out unapplied: each one's player and volume tokens.
type Refunds = Vec<(String, u64)>;

/// A player's last validated position, kept after its sessions end.
#[derive(Debug, Clone, Copy)]
struct Remembered {
    feet: FixedVec3,
    /// [`ValidatedPosition::known_ms`] (as stored, for positions read from
    /// the store; 0 for those stored before the time was kept).
    known_ms: u64,
}

/// Owns the authoritative world and everything edits are checked against.
#[derive(Debug)]
pub struct Sequencer {
    world: World,
    cfg: SequencerConfig,
    validation: ValidationConfig,
    materials: MaterialTable,
    structures: StructureLibrary,
    zones: Vec<Zone>,
    sessions: HashMap<u64, Session>,
    /// Live sessions by player (`sessions`' ids, indexed), so a join or a
    /// ticket looks at the player's sessions, not at everyone's.
    by_player: HashMap<String, Vec<u64>>,
    limits: HashMap<String, PlayerLimits>,
    queue: VecDeque<Queued>,
    /// Edits that passed every rule but line of sight, for
    /// [`Self::check_sighted`]; counted with `queue` against its capacity.
    sighting: Vec<sight::Sighted>,
    next_seq: u64,
    /// The last seq a tick may hand out ([`Self::limit_seqs`]).
    seq_limit: u64,
    collision: CollisionCache,
    residency: Residency,
    /// Sessions to disconnect for too many refused edits (see `submit`).
    disconnect: Vec<u64>,
    /// Each player's last validated feet position, kept after its sessions
    /// end (at most `validation.remembered_players`): a new session starts
    /// from it, so the speed check spans reconnects, and no older ticket
    /// moves it ([`Self::arrive`]).
    last_positions: HashMap<String, Remembered>,
    /// Players whose position changed since [`Self::take_moved`].
    moved: HashSet<String>,
    /// See [`Self::set_swept_regions`].
    swept_regions: Option<HashSet<RegionId>>,
}

impl Sequencer {
    /// A sequencer continuing after `last_seq` (the store's last durable edit).
    /// Chunks it has not been given are unknown until the shell either
    /// inserts them ([`Self::insert_stored_chunk`]) or marks them absent
    /// ([`Self::mark_absent`]); see [`Self::chunks_needed`].
    pub fn new(
        world: World,
        cfg: SequencerConfig,
        validation: ValidationConfig,
        last_seq: u64,
        materials: MaterialTable,
        structures: StructureLibrary,
        zones: Vec<Zone>,
    ) -> Self {
        Self {
            world,
            collision: CollisionCache::new(cfg.collision_cache_capacity),
            cfg,
            validation,
            materials,
            structures,
            zones,
            sessions: HashMap::new(),
            by_player: HashMap::new(),
            limits: HashMap::new(),
            queue: VecDeque::new(),
            sighting: Vec::new(),
            next_seq: last_seq.saturating_add(1),
            seq_limit: crate::store::MAX_SEQ,
            residency: Residency::default(),
            disconnect: Vec::new(),
            last_positions: HashMap::new(),
            moved: Default::default(),
            swept_regions: None,
        }
    }

    /// Treats every chunk not loaded as generated: for worlds without a
    /// store (tests, offline tools).
    pub fn without_store(mut self) -> Self {
        self.residency = Residency::storeless();
        self
    }

    /// The default zones for a world with none stored: spawn protection,
    /// or none when `spawn_protection_radius` is 0.
    pub fn default_zones(validation: &ValidationConfig) -> Vec<Zone> {
        if validation.spawn_protection_radius == 0 {
            return Vec::new();
        }
        vec![Zone::spawn(validation.spawn_protection_radius)]
    }

    /// The chunk's current state; a chunk never loaded is generated
    /// (make stored chunks resident first).
    pub fn chunk(&mut self, pos: ChunkPos) -> Arc<Chunk> {
        self.world.chunk(pos).chunk.clone()
    }

    /// Hash of the chunk's LOD-0 mesh at its current version, built and
    /// cached if missing. Its neighbours must be resident.
    pub fn mesh_hash(&mut self, pos: ChunkPos) -> u64 {
        let version = self.world.chunk(pos).version;
        self.collision.ensure(&self.world, &[pos]);
        self.collision.get(pos, version).map_or(0, |m| m.hash)
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn config(&self) -> &SequencerConfig {
        &self.cfg
    }

    pub fn validation(&self) -> &ValidationConfig {
        &self.validation
    }

    /// The sequence number the next applied edit gets.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Numbers the next edits from `next` on, if that is higher: a cluster
    /// node moved to a new seq block (`store/pg/seqs.rs`). Between ticks.
    pub fn raise_next_seq(&mut self, next: u64) {
        self.next_seq = self.next_seq.max(next);
    }

    /// Hands out no seq past `last` (a cluster node's seq block ends
    /// there; never past [`crate::store::MAX_SEQ`]): edits past it wait
    /// in the queue for a higher limit. Between ticks.
    pub fn limit_seqs(&mut self, last: u64) {
        self.seq_limit = last.min(crate::store::MAX_SEQ);
    }

    /// Seqs left to hand out below the limit.
    pub fn seqs_left(&self) -> u64 {
        (self.seq_limit + 1).saturating_sub(self.next_seq)
    }

    /// Region side in chunks (`[sequencer] region_chunks`).
    pub fn region_chunks(&self) -> u32 {
        self.cfg.region_chunks
    }

    /// The regions a move's path is swept through (`None`: every one, a
    /// single server's). A cluster node names its own and those it read
    /// as free: its copies of another node's chunks may be behind their
    /// writer's (a tunnel dug there would refuse honest players), and of
    /// a region whose holder it does not know, so may they.
    pub fn set_swept_regions(&mut self, regions: Option<HashSet<RegionId>>) {
        self.swept_regions = regions;
    }

    fn sweeps(&self, chunk: ChunkPos) -> bool {
        self.swept_regions
            .as_ref()
            .is_none_or(|s| s.contains(&RegionId::of(chunk, self.cfg.region_chunks)))
    }

    /// The regions `edit` writes or reads, or whose collision meshes it
    /// changes ([`residency::edit_mesh_reach`]: box, read margin and the
    /// meshes' apron of two voxels), or `None` if the terrain core refuses
    /// it. An edit further than that from a region border needs only its
    /// own region, whoever writes the neighbour.
    pub fn edit_regions(
        &self,
        edit: &strata_terrain::Edit,
    ) -> Option<std::collections::BTreeSet<regions::RegionId>> {
        let bbox = edit.validate(&self.ctx()).ok()?;
        let fp = residency::edit_mesh_reach(&bbox, edit.read_margin());
        let span =
            regions::RegionSpan::of_chunks(fp.min.chunk(), fp.max.chunk(), self.cfg.region_chunks);
        Some(span.regions().collect())
    }

    /// Whether `edit` (its box, read margin and mesh apron) or its sight
    /// `ray` reaches into any of `regions`.
    fn reaches(
        &self,
        edit: &strata_terrain::Edit,
        ray: &[ChunkPos],
        regions: &std::collections::BTreeSet<regions::RegionId>,
    ) -> bool {
        let side = self.cfg.region_chunks;
        ray.iter()
            .any(|&p| regions.contains(&regions::RegionId::of(p, side)))
            || self
                .edit_regions(edit)
                .is_some_and(|rs| !rs.is_disjoint(regions))
    }

    /// Takes the edits whose box or sight ray reaches into any of
    /// `regions` out of the queue and out of those awaiting their sight
    /// check (a cluster node's regions whose reload failed: a batch
    /// writing them would be fenced, and chunks already reloaded moved
    /// under their sight); returns each one's session and client edit id,
    /// to be refused `Busy`. Like any `Busy`, that costs the player
    /// nothing: the edit and volume tokens go back.
    pub fn unqueue_in(
        &mut self,
        regions: &std::collections::BTreeSet<regions::RegionId>,
        now_ms: u64,
    ) -> Vec<(u64, u64)> {
        let (mut out, mut refunds) =
            self.unqueue_queued(|s, q| s.reaches(&q.request.edit, &q.ray, regions));
        for s in std::mem::take(&mut self.sighting) {
            if self.reaches(&s.request.edit, &s.ray, regions) {
                out.push((s.session_id, s.request.client_edit_id));
                refunds.push((s.player.clone(), s.volume_cost));
            } else {
                self.sighting.push(s);
            }
        }
        self.refund_busy(refunds, now_ms);
        out
    }

    /// Takes every queued edit back out (a cluster node's fenced batch:
    /// their sight may have been checked on the world that batch left,
    /// which is gone); returns each one's session and client edit id, to be
    /// refused `Busy`, which costs nothing. Edits still awaiting their sight
    /// check stay: it runs on the world put back.
    pub fn unqueue_sighted(&mut self, now_ms: u64) -> Vec<(u64, u64)> {
        let (out, refunds) = self.unqueue_queued(|_, _| true);
        self.refund_busy(refunds, now_ms);
        out
    }

    /// Takes the queued edits whose sight was checked on chunks of any of
    /// `regions` (their boxes, or their sight rays, reach into them) out of
    /// the queue: a cluster node's regions reloaded with chunks another
    /// node moved. Returns each one's session and client edit id, to be
    /// refused `Busy` (free) and sent again against the world as it is.
    /// Edits still awaiting their sight check stay: it runs on the
    /// reloaded chunks.
    pub fn unqueue_seen_in(
        &mut self,
        regions: &std::collections::BTreeSet<regions::RegionId>,
        now_ms: u64,
    ) -> Vec<(u64, u64)> {
        let (out, refunds) =
            self.unqueue_queued(|s, q| s.reaches(&q.request.edit, &q.ray, regions));
        self.refund_busy(refunds, now_ms);
        out
    }

    /// The queued edits `hits` picks, taken out: their ids and what each
    /// player is owed.
    fn unqueue_queued(
        &mut self,
        hits: impl Fn(&Self, &Queued) -> bool,
    ) -> (Vec<(u64, u64)>, Refunds) {
        let mut out = Vec::new();
        let mut refunds = Vec::new();
        for q in std::mem::take(&mut self.queue) {
            if hits(self, &q) {
                out.push((q.session_id, q.request.client_edit_id));
                refunds.push((q.player, q.volume_cost));
            } else {
                self.queue.push_back(q);
            }
        }
        (out, refunds)
    }

    /// Gives back what edits refused `Busy` took: an edit token and their
    /// volume.
    fn refund_busy(&mut self, refunds: Refunds, now_ms: u64) {
        for (player, volume) in refunds {
            if let Some(limits) = self.limits.get_mut(&player) {
                limits.refill(now_ms);
                limits.edits.give(1);
                limits.volume.give(volume);
            }
        }
    }

    /// Takes the queued edit `client_edit_id` of `session` back out of the
    /// queue, refused after it was queued (a cluster node could not claim
    /// its regions). Its volume goes back; so does its edit token unless
    /// the refusal is `charged`, which costs a rejection token instead.
    /// False when it was not in the queue (answered already).
    pub fn take_back(
        &mut self,
        session_id: u64,
        client_edit_id: u64,
        charged: bool,
        now_ms: u64,
    ) -> bool {
        let Some(i) = self.queue.iter().rposition(|q| {
            (q.session_id, q.request.client_edit_id) == (session_id, client_edit_id)
        }) else {
            return false;
        };
        let Some(q) = self.queue.remove(i) else {
            return false;
        };
        let live = self.sessions.contains_key(&session_id);
        let Some(limits) = self.limits.get_mut(&q.player) else {
            return true;
        };
        limits.refill(now_ms);
        limits.volume.give(q.volume_cost);
        if !charged {
            limits.edits.give(1);
        } else if live && !limits.rejections.take(1) && !self.disconnect.contains(&session_id) {
            self.disconnect.push(session_id);
        }
        true
    }

    /// The last sequence number handed out (or loaded from the store).
    pub fn last_seq(&self) -> u64 {
        self.next_seq - 1
    }

    /// Accepted edits waiting for the next tick.
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    pub fn collision(&self) -> &CollisionCache {
        &self.collision
    }

    /// Caches a mesh built elsewhere; the caller checked it is current.
    pub fn insert_collision_mesh(&mut self, mesh: CollisionMesh) {
        self.collision.insert(mesh);
    }

    fn ctx(&self) -> EditContext<'_> {
        EditContext {
            materials: &self.materials,
            structures: &self.structures,
        }
    }

    // ------------------------------------------------------------ chunks

    /// A chunk loaded from the store. Drops collision meshes that read it.
    pub fn insert_stored_chunk(&mut self, pos: ChunkPos, chunk: Chunk, version: u64) {
        self.world.insert(pos, chunk, version);
        self.residency.mark_present(pos);
        self.collision.invalidate_around(pos);
    }

    /// Drops the collision meshes that read `pos` (it changed in the store
    /// while not loaded here: another cluster node wrote it).
    pub fn forget_meshes_around(&mut self, pos: ChunkPos) {
        self.collision.invalidate_around(pos);
    }

    /// Holds `chunk`, generated off this thread, as the version-0 chunk at
    /// `pos` unless a chunk is loaded there. The caller has checked that
    /// the store has no version of `pos`. The chunk is shared, not copied.
    pub fn adopt_generated(&mut self, pos: ChunkPos, chunk: &Arc<Chunk>) {
        if self.world.peek(pos).is_none() {
            self.world.insert(pos, chunk.clone(), 0);
            self.residency.mark_absent(pos);
        }
    }

    /// Makes sure each listed chunk has a collision mesh for its current
    /// version, built on the current rayon pool. Their neighbours that the
    /// store lacks and the world has not loaded are generated first, each
    /// once and in parallel, and kept (version 0): else every mesh would
    /// generate its missing neighbours again on its own. The chunks and
    /// their neighbours must be resident.
    pub fn prepare_meshes(&mut self, chunks: &[ChunkPos]) {
        let mut missing: Vec<ChunkPos> = chunks
            .iter()
            .flat_map(|&p| with_neighbours(p))
            .filter(|&p| self.world.peek(p).is_none() && self.residency.may_generate(p))
            .collect();
        missing.sort_unstable();
        missing.dedup();
        self.generate_into_world(missing);
        self.collision.ensure(&self.world, chunks);
    }

    /// Generates `positions` (none of them loaded) and holds them at
    /// version 0; on the current rayon pool when there are several.
    fn generate_into_world(&mut self, positions: Vec<ChunkPos>) {
        let generator = self.world.generator().clone();
        let generate = |&p: &ChunkPos| (p, generator.generate(p));
        let made: Vec<(ChunkPos, Chunk)> = if positions.len() > 1 {
            positions.par_iter().map(generate).collect()
        } else {
            positions.iter().map(generate).collect()
        };
        for (p, chunk) in made {
            self.world.insert(p, chunk, 0);
        }
    }

    /// The store has no such chunk: it is generated (version 0).
    pub fn mark_absent(&mut self, pos: ChunkPos) {
        self.residency.mark_absent(pos);
    }

    /// Whether the sequencer may read `pos` without asking the store.
    pub fn is_resident(&self, pos: ChunkPos) -> bool {
        self.residency.is_resident(&self.world, pos)
    }

    /// Chunks the shell must load (or mark absent) before submitting
    /// `edit` for `session_id`: the chunks the edit reads plus their
    /// neighbours, and those the line-of-sight check meshes. Empty when the
    /// edit is invalid (it will be rejected without reading anything).
    pub fn chunks_needed(&self, session_id: u64, edit: &strata_terrain::Edit) -> Vec<ChunkPos> {
        let eye = self
            .sessions
            .get(&session_id)
            .and_then(|s| s.position)
            .map(|p| position::eye(p.feet, &self.validation));
        match self.read_set(edit, eye) {
            Some(set) => self.residency.missing(&self.world, set),
            None => Vec::new(),
        }
    }

    /// Those of `chunks` the shell must load (or mark absent) first.
    pub fn missing(&self, chunks: &[ChunkPos]) -> Vec<ChunkPos> {
        self.residency.missing(&self.world, chunks.iter().copied())
    }

    /// Chunks the shell must load before [`Self::update_position`] can check `upd`.
    pub fn chunks_needed_for_position(
        &self,
        session_id: u64,
        upd: &PositionUpdate,
    ) -> Vec<ChunkPos> {
        self.residency
            .missing(&self.world, self.position_reads(session_id, upd))
    }

    /// The chunks a report's check reads: the body's at the new spot, and
    /// those along the ways from the last accepted position (none for a
    /// first position). A spot whose body is known to be in solid terrain
    /// is refused before its way is read: none of the way's chunks.
    fn position_reads(&self, session_id: u64, upd: &PositionUpdate) -> Vec<ChunkPos> {
        let cfg = &self.validation;
        let body = position::body_reads(upd.pos, cfg);
        let mut chunks: Vec<ChunkPos> = body.iter().map(|v| v.chunk()).collect();
        let buried = body.iter().all(|v| self.is_resident(v.chunk()))
            && position::body_blocked(&self.world, upd.pos, cfg).is_some();
        if buried {
            return chunks;
        }
        let prev = self.sessions.get(&session_id).and_then(|s| s.position);
        if let Some(p) = prev {
            for c in crate::validate::sweep::chunks(p.feet, upd.pos, cfg) {
                if self.sweeps(c) && !chunks.contains(&c) {
                    chunks.push(c);
                }
            }
        } else {
            // A first report: the column above, up to the sky.
            for c in position::sky_chunks(upd.pos, cfg) {
                if self.sweeps(c) && !chunks.contains(&c) {
                    chunks.push(c);
                }
            }
        }
        if self.held_to_ground(session_id) {
            // The ground under the new feet, and under the last ones when
            // their state is not settled yet (a resume, an arrival).
            use crate::validate::gravity;
            let unsettled = prev.filter(|p| p.air == gravity::Air::Unsettled);
            let spots = std::iter::once(upd.pos).chain(unsettled.map(|p| p.feet));
            // And the ground a report above the step may have walked.
            let walked = prev
                .filter(|p| gravity::may_walk(p.air, p.feet, upd.pos, &cfg.gravity))
                .map(|p| gravity::walk_chunks(p.feet, upd.pos, cfg.eye_height));
            for c in spots
                .flat_map(gravity::chunks)
                .chain(walked.into_iter().flatten())
            {
                if self.sweeps(c) && !chunks.contains(&c) {
                    chunks.push(c);
                }
            }
        }
        chunks
    }

    /// Whether `[validation.gravity]` holds the session's player: on, and
    /// not an admin.
    fn held_to_ground(&self, session_id: u64) -> bool {
        self.validation.gravity.enabled
            && self
                .sessions
                .get(&session_id)
                .is_some_and(|s| s.role != Role::Admin)
    }

    /// Drops unmodified chunks for which `keep` is false (they regenerate).
    pub fn evict_generated(&mut self, keep: impl Fn(ChunkPos) -> bool) {
        drop(self.world.evict_generated(keep));
    }

    /// Chunks held in memory: loaded ones plus absent marks.
    pub fn resident(&self) -> usize {
        self.world.loaded() + self.residency.absent_len()
    }

    /// Drops chunks and absent marks for which `keep` is false. Modified
    /// chunks go too when there is a store (it holds them durably; they are
    /// loaded again before use). Queued edits rely on what was resident
    /// when they were submitted: the chunks they read and those around
    /// them (their meshes' aprons) are kept whatever `keep` says, so a
    /// server whose queue never empties still evicts; so are those of edits
    /// awaiting their line-of-sight check, rays included. Returns the
    /// dropped chunks (the engine frees them on a worker).
    pub fn evict_cold(
        &mut self,
        keep: impl Fn(ChunkPos) -> bool,
    ) -> Vec<strata_terrain::world::VersionedChunk> {
        let queued = self.queued_reads();
        self.evict_unless(|p| keep(p) || queued.contains(p))
    }

    /// [`Self::evict_cold`], keeping every chunk within `radius` chunks of
    /// a player (a cube around the chunk the player stands in).
    pub fn evict_far_from_players(
        &mut self,
        radius: u8,
    ) -> Vec<strata_terrain::world::VersionedChunk> {
        let mut keep = self.queued_reads();
        for c in self.player_chunks() {
            keep.insert_cube(c, radius);
        }
        self.evict_unless(|p| keep.contains(p))
    }

    /// The chunks queued edits and those awaiting line of sight read, and
    /// the 26 around each: [`Self::read_set`]'s box grown by one chunk, and
    /// each chunk of the line of sight grown by two.
    fn queued_reads(&self) -> ChunkBits {
        let mut keep = ChunkBits::default();
        let queued = self.queue.iter().map(|q| (&q.request.edit, None));
        let sighting = self.sighting.iter().map(|s| (&s.request.edit, Some(s.eye)));
        for (edit, eye) in queued.chain(sighting) {
            let Some((lo, hi, ray)) = self.read_bounds(edit, eye) else {
                continue;
            };
            let grown = |v: i32, d: i32| v.saturating_add(d);
            keep.insert_box(
                ChunkPos::new(grown(lo.x, -1), grown(lo.y, -1), grown(lo.z, -1)),
                ChunkPos::new(grown(hi.x, 1), grown(hi.y, 1), grown(hi.z, 1)),
            );
            for r in ray {
                keep.insert_cube(r, 2);
            }
        }
        keep
    }

    fn evict_unless(
        &mut self,
        keep: impl Fn(ChunkPos) -> bool,
    ) -> Vec<strata_terrain::world::VersionedChunk> {
        let dropped = if self.residency.is_storeless() {
            self.world.evict_generated(&keep)
        } else {
            self.world.evict(&keep)
        };
        self.residency.retain_absent(keep);
        dropped
    }

    /// Chunks each session stands in (sessions with a validated position).
    pub fn player_chunks(&self) -> impl Iterator<Item = ChunkPos> + '_ {
        self.sessions
            .values()
            .filter_map(|s| s.position)
            .map(|p| position::feet_voxel(p.feet).chunk())
    }

    // ------------------------------------------------------------ sessions

    pub fn session_joined(&mut self, session_id: u64, player: String, role: Role) {
        if let Some(old) = self.sessions.remove(&session_id) {
            self.unindex(&old.player, session_id);
            self.release_limits(&old.player);
        }
        self.limits
            .entry(player.clone())
            .or_insert_with(|| PlayerLimits::new(&self.validation, 0))
            .sessions += 1;
        self.by_player
            .entry(player.clone())
            .or_default()
            .push(session_id);
        self.sessions.insert(
            session_id,
            Session {
                player,
                role,
                position: None,
                judged: None,
                seen_ms: 0,
                seen_feet: None,
            },
        );
    }

    /// Forgets the session. Its queued edits still apply at the next tick.
    pub fn session_left(&mut self, session_id: u64) {
        if let Some(old) = self.sessions.remove(&session_id) {
            self.unindex(&old.player, session_id);
            self.remember_position(&old.player, old.judged);
            self.release_limits(&old.player);
        }
    }

    /// Takes `session_id` out of `player`'s live sessions.
    fn unindex(&mut self, player: &str, session_id: u64) {
        if let Some(ids) = self.by_player.get_mut(player) {
            ids.retain(|&id| id != session_id);
            if ids.is_empty() {
                self.by_player.remove(player);
            }
        }
    }

    /// The live sessions of `player`, oldest join first.
    pub fn sessions_of(&self, player: &str) -> &[u64] {
        self.by_player.get(player).map_or(&[], |ids| ids.as_slice())
    }

    /// The validated positions of `player`'s live sessions.
    fn positions_of<'a>(
        &'a self,
        player: &str,
    ) -> impl Iterator<Item = (u64, ValidatedPosition)> + 'a {
        self.sessions_of(player)
            .iter()
            .filter_map(|id| Some((*id, self.sessions.get(id)?.position?)))
    }

    fn remember_position(&mut self, player: &str, position: Option<ValidatedPosition>) {
        let Some(p) = position else { return };
        let cap = self.validation.remembered_players.max(1);
        if !self.last_positions.contains_key(player) && self.last_positions.len() >= cap {
            self.forget_oldest_positions(cap);
        }
        let remembered = Remembered {
            feet: p.feet,
            known_ms: p.known_ms,
        };
        self.last_positions.insert(player.to_string(), remembered);
        self.moved.insert(player.to_string());
    }

    /// Full at `cap`: forgets the players known longest ago, a 64th of
    /// them (at least one), so that the one who left a moment ago is not
    /// the one forgotten (it would come back at the spawn) and the scan is
    /// paid once per 64th of the map's players joining.
    fn forget_oldest_positions(&mut self, cap: usize) {
        let n = (cap / 64).max(1).min(self.last_positions.len());
        if n == 0 {
            return;
        }
        let mut ages: Vec<(u64, &String)> = self
            .last_positions
            .iter()
            .map(|(player, r)| (r.known_ms, player))
            .collect();
        ages.select_nth_unstable(n - 1);
        let oldest: Vec<String> = ages[..n].iter().map(|(_, p)| (*p).clone()).collect();
        for player in oldest {
            self.last_positions.remove(&player);
        }
    }

    /// Starts a new session of a known player where the player last was:
    /// its first report must be a legal move from there, timed from
    /// `now_ms` (a reconnect teleports nowhere). A player the server does
    /// not remember starts in the spawn area. Returns where it starts.
    /// `stored`: the player's stored position, which a cluster node reads
    /// at each join (another node may have had the player since).
    pub fn resume_position(
        &mut self,
        session_id: u64,
        now_ms: u64,
        stored: Option<StoredPosition>,
    ) -> Start {
        let spawn = self.validation.spawn.start();
        let Some(player) = self.sessions.get(&session_id).map(|s| s.player.clone()) else {
            return spawn;
        };
        // Another live session of the player (sessions_per_player > 1) knows
        // a newer position than the remembered one: the one it judged (a
        // spot taken on trust in another node's region is not taken over).
        let others: Vec<ValidatedPosition> = self
            .sessions_of(&player)
            .iter()
            .filter(|&&id| id != session_id)
            .filter_map(|id| self.sessions.get(id)?.judged)
            .collect();
        let local = self.last_positions.get(&player).map(|r| StoredPosition {
            feet: r.feet,
            known_ms: r.known_ms,
        });
        // Another node's clock may run ahead: its times are at most now
        // (and the store lets any node overwrite a row dated ahead).
        let stored = stored.map(|p| StoredPosition {
            known_ms: p.known_ms.min(now_ms),
            ..p
        });
        // Of the remembered and the stored position, the newer.
        let remembered = local.into_iter().chain(stored).max_by_key(|r| r.known_ms);
        let feet = others
            .iter()
            .max_by_key(|p| p.at_ms)
            .map(|p| p.feet)
            .or(remembered.map(|r| r.feet));
        // The newest time the player is known anywhere bounds its tickets;
        // another node's, less the age a ticket it issued may have when
        // used ([`STORED_TICKET_SLACK_MS`]).
        let known_ms = others
            .iter()
            .map(|p| p.known_ms)
            .chain(local.map(|r| r.known_ms))
            .chain(stored.map(|r| r.known_ms.saturating_sub(STORED_TICKET_SLACK_MS)))
            .max()
            .unwrap_or(0);
        // The newest sighting, spot and time from one record.
        let seen = others
            .iter()
            .map(|p| (p.known_ms, p.feet))
            .chain(remembered.map(|r| (r.known_ms, r.feet)))
            .max_by_key(|&(t, _)| t);
        let Some(s) = self.sessions.get_mut(&session_id) else {
            return spawn;
        };
        (s.seen_ms, s.seen_feet) = match seen {
            Some((t, f)) => (t, Some(f)),
            None => (0, None),
        };
        match feet {
            Some(feet) => {
                let resumed = ValidatedPosition::resumed(feet, now_ms, known_ms, &self.validation);
                s.position = Some(resumed);
                s.judged = Some(resumed);
                Start::Resume { feet }
            }
            None => spawn,
        }
    }

    /// A verified ticket: the session continues from `feet`, timed from
    /// `issued_ms`, as a resumed one would. A ticket never moves a placed
    /// player: refused once the session reported or arrived, and when the
    /// player was seen after the ticket was issued (an older ticket would
    /// rewind it and refund the time it walked since).
    pub fn arrive(
        &mut self,
        session_id: u64,
        feet: FixedVec3,
        issued_ms: u64,
        now_ms: u64,
    ) -> Result<Start, strata_protocol::TicketRefusal> {
        let refused = Err(strata_protocol::TicketRefusal::AlreadyPlaced);
        let Some(s) = self.sessions.get(&session_id) else {
            return refused;
        };
        if s.position
            .is_some_and(|p| p.placement != Placement::Resumed)
        {
            return refused;
        }
        // The session's own resume already knows the player's newest time
        // at its join: most replayed tickets stop here, before the scan.
        if s.position.is_some_and(|p| issued_ms < p.known_ms) {
            return refused;
        }
        // When any session of the player last saw it (its own resume
        // included): an older ticket would take it back in time.
        let newest = self.positions_of(&s.player).map(|(_, p)| p.known_ms).max();
        if newest.is_some_and(|t| issued_ms < t) {
            return refused;
        }
        // Where the player starts: the ticket's spot, or where it was seen
        // since (its issuing node saves it every second; the resume found
        // it), whichever is newer. Its first move is swept from there like
        // any other: a stale ticket carries no way through a wall.
        // A sighting within the nodes' clock skew of the ticket is no
        // newer than it (a node's clock may run ahead).
        let skew = strata_protocol::limits::TICKET_SKEW_MS;
        let seen_since = s
            .seen_feet
            .filter(|_| s.seen_ms > issued_ms.saturating_add(skew));
        let (feet, at_ms) = match seen_since {
            Some(f) => (f, s.seen_ms),
            None => (feet, issued_ms),
        };
        // The walk the start's age may stand for: until the player was
        // last seen, and the hand-off after; all of it when nothing is
        // known.
        let walked = match s.seen_ms {
            0 => u64::MAX,
            seen => seen
                .saturating_sub(at_ms)
                .saturating_add(ARRIVAL_HANDOFF_MS),
        };
        let arrived = ValidatedPosition::arrived(feet, at_ms, now_ms, walked, &self.validation);
        if let Some(s) = self.sessions.get_mut(&session_id) {
            s.position = Some(arrived);
            s.judged = Some(arrived);
        }
        Ok(Start::Resume { feet })
    }

    /// A session ended. The player's buckets stay until they have refilled
    /// ([`Self::prune_limits`]), so reconnecting gives no fresh budget.
    fn release_limits(&mut self, player: &str) {
        if let Some(l) = self.limits.get_mut(player) {
            l.sessions = l.sessions.saturating_sub(1);
        }
    }

    /// Forgets the limits of players with no session whose buckets are full
    /// again at `now_ms`: they carry no information any more.
    pub fn prune_limits(&mut self, now_ms: u64) {
        self.limits
            .retain(|_, l| l.sessions > 0 || !l.is_full(now_ms));
    }

    /// Players whose rate limits are tracked (connected, or recently spent).
    pub fn tracked_players(&self) -> usize {
        self.limits.len()
    }

    pub fn session(&self, session_id: u64) -> Option<&Session> {
        self.sessions.get(&session_id)
    }

    /// The session's last validated position.
    pub fn position(&self, session_id: u64) -> Option<ValidatedPosition> {
        self.sessions.get(&session_id)?.position
    }

    /// The session's last position this node judged whole (see
    /// [`Session::judged`]): the one a ticket for another node carries.
    pub fn judged_position(&self, session_id: u64) -> Option<ValidatedPosition> {
        self.sessions.get(&session_id)?.judged
    }

    /// The session's last validated position, or `UnknownSession`.
    fn previous(&self, session_id: u64) -> Result<Option<ValidatedPosition>, PositionReject> {
        Ok(self
            .sessions
            .get(&session_id)
            .ok_or(PositionReject::UnknownSession)?
            .position)
    }

    /// The rules of [`Self::update_position`] that read no terrain (order,
    /// bounds, speed): the engine runs them before loading any chunk.
    pub fn precheck_position(
        &mut self,
        session_id: u64,
        upd: &PositionUpdate,
        now_ms: u64,
    ) -> Result<(), PositionReject> {
        let prev = self.previous(session_id)?;
        let checked = position::check_motion(prev.as_ref(), upd, now_ms, &self.validation);
        if let Err(e) = &checked {
            self.heard_refused(session_id, prev, e, now_ms);
        }
        checked.map(|_| ())
    }

    /// After a report past the order rule was refused: the session keeps
    /// its position, and the time since the last report heard is credited
    /// to its next move ([`ValidatedPosition::heard`]).
    fn heard_refused(
        &mut self,
        session_id: u64,
        prev: Option<ValidatedPosition>,
        e: &PositionReject,
        now_ms: u64,
    ) {
        let (Some(p), false) = (prev, matches!(e, PositionReject::Stale { .. })) else {
            return;
        };
        let heard = p.heard(now_ms, &self.validation);
        if let Some(s) = self.sessions.get_mut(&session_id) {
            s.position = Some(heard);
        }
    }

    /// Takes one of the player's placement tokens when the session has no
    /// position yet (its report reads and may generate the chunks around
    /// the body wherever in the spawn square it claims to be); `Err`, and
    /// nothing loaded, when none is left.
    pub fn charge_placement(&mut self, session_id: u64, now_ms: u64) -> Result<(), PositionReject> {
        let s = self
            .sessions
            .get(&session_id)
            .ok_or(PositionReject::UnknownSession)?;
        if s.position.is_some() {
            return Ok(());
        }
        let limits = self
            .limits
            .get_mut(&s.player)
            .ok_or(PositionReject::UnknownSession)?;
        limits.placements.refill(now_ms);
        if limits.placements.take(1) {
            Ok(())
        } else {
            Err(PositionReject::PlacementLimited)
        }
    }

    /// Checks and records a position report. A rejected report changes
    /// no position (only the time the next move may count: see
    /// [`ValidatedPosition::heard`]); a stale one is rejected as
    /// [`PositionReject::Stale`] and the shell should drop it silently.
    pub fn update_position(
        &mut self,
        session_id: u64,
        upd: PositionUpdate,
        now_ms: u64,
    ) -> Result<(), PositionReject> {
        let prev = self.previous(session_id)?;
        // Stale reports are dropped before anything else, even loading.
        if let Some(p) = prev.filter(|p| upd.seq <= p.seq) {
            return Err(PositionReject::Stale {
                seq: upd.seq,
                last: p.seq,
            });
        }
        let reads = self.position_reads(session_id, &upd);
        if let Some(pos) = self
            .residency
            .missing(&self.world, reads.iter().copied())
            .first()
        {
            return Err(PositionReject::ChunkNotLoaded { pos: *pos });
        }
        self.world.load(reads);
        let path = Swept {
            world: &self.world,
            regions: self.swept_regions.as_ref(),
            side: self.cfg.region_chunks,
        };
        // Another node's regions are that node's to judge (this node's
        // copies may be behind).
        let ground = self
            .held_to_ground(session_id)
            .then_some(|v: VoxelPos| path.sweeps(v).then(|| self.world.voxel(v).is_solid()));
        let checked = position::check(
            prev.as_ref(),
            &upd,
            now_ms,
            &self.validation,
            &self.world,
            &path,
            ground,
        );
        let ok = match checked {
            Ok(ok) => ok,
            Err(e) => {
                self.heard_refused(session_id, prev, &e, now_ms);
                return Err(e);
            }
        };
        // Judged whole only where its walls are checked: this node's
        // regions and free ones (not another node's, nor one whose holder
        // it has not read yet: both air to the sweep).
        let judged = self.sweeps(position::feet_voxel(ok.feet).chunk());
        if let Some(s) = self.sessions.get_mut(&session_id) {
            s.position = Some(ok);
            if judged {
                s.judged = Some(ok);
            }
            if !self.moved.contains(&s.player) {
                self.moved.insert(s.player.clone());
            }
        }
        Ok(())
    }

    /// Saves `player`'s position again at the next [`Self::take_moved`]
    /// (a save that failed): where it is then, live or remembered.
    pub fn mark_moved(&mut self, player: String) {
        self.moved.insert(player);
    }

    /// Players whose position changed since the last call, with it and
    /// when the player was last known there: the shell stores them
    /// durably.
    pub fn take_moved(&mut self) -> Vec<(String, StoredPosition)> {
        // A live session's position is newer than the remembered one; of
        // several sessions of a player, the one known there last.
        let mut live: HashMap<&str, StoredPosition> = HashMap::new();
        for s in self.sessions.values() {
            // What this node judged: a spot in another node's region it
            // took on trust (air to it) is not stored for others to resume.
            let Some(p) = s.judged.filter(|_| self.moved.contains(&s.player)) else {
                continue;
            };
            let stored = StoredPosition {
                feet: p.feet,
                known_ms: p.known_ms,
            };
            live.entry(s.player.as_str())
                .and_modify(|q| {
                    if stored.known_ms > q.known_ms {
                        *q = stored;
                    }
                })
                .or_insert(stored);
        }
        let moved = std::mem::take(&mut self.moved);
        moved
            .into_iter()
            .filter_map(|player| {
                let p = live.get(player.as_str()).copied().or_else(|| {
                    let r = self.last_positions.get(&player)?;
                    Some(StoredPosition {
                        feet: r.feet,
                        known_ms: r.known_ms,
                    })
                })?;
                Some((player, p))
            })
            .collect()
    }

    /// Last positions loaded from the store at start (at most
    /// `validation.remembered_players`), each with when the player was
    /// last known there: an older ticket does not move the player.
    pub fn restore_positions(
        &mut self,
        positions: impl IntoIterator<Item = (String, StoredPosition)>,
    ) {
        for (player, p) in positions
            .into_iter()
            .take(self.validation.remembered_players)
        {
            let remembered = Remembered {
                feet: p.feet,
                known_ms: p.known_ms,
            };
            self.last_positions.insert(player, remembered);
        }
    }

    // ------------------------------------------------------------ zones

    pub fn zones(&self) -> &[Zone] {
        &self.zones
    }

    pub fn add_zone(&mut self, zone: Zone) -> Result<(), ZoneError> {
        zones::check_new(&self.zones, &zone)?;
        self.zones.push(zone);
        Ok(())
    }

    /// Replaces the zones (as stored: each was checked when it was added).
    pub fn set_zones(&mut self, zones: Vec<Zone>) {
        self.zones = zones;
    }

    /// Removes the zone named `name`, returning it.
    pub fn remove_zone(&mut self, name: &str) -> Option<Zone> {
        let i = self.zones.iter().position(|z| z.name == name)?;
        Some(self.zones.remove(i))
    }
}

/// The terrain a move's path is swept through: this node's copy in the
/// regions it sweeps ([`Sequencer::set_swept_regions`]), air elsewhere.
struct Swept<'a> {
    world: &'a World,
    regions: Option<&'a HashSet<RegionId>>,
    side: u32,
}

impl Swept<'_> {
    /// Whether this node judges `p`: its own regions and free ones.
    fn sweeps(&self, p: VoxelPos) -> bool {
        self.regions
            .is_none_or(|s| s.contains(&RegionId::of(p.chunk(), self.side)))
    }
}

impl VoxelRead for Swept<'_> {
    fn voxel(&self, p: VoxelPos) -> Voxel {
        if self.sweeps(p) {
            self.world.voxel(p)
        } else {
            Voxel::AIR
        }
    }
}
