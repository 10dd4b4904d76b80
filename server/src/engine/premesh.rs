//! Collision meshes for the chunks around players, built in the background
//! so line-of-sight checks rarely mesh on the engine thread.
//!
//! When a player enters a new chunk, the engine queues jobs for the chunks
//! within `premesh_radius` that have no current mesh. A job shares the
//! world's modified chunks it reads (the world holds each as an `Arc`, and
//! never writes one in place) and regenerates the rest, so the engine
//! thread copies nothing. Jobs run on threads of their
//! own (`engine.premesh_threads`) that sleep while they have none (a rayon
//! pool spins between jobs); they share one cache of generated chunks.
//! A finished mesh is cached
//! only if none of the 27 chunks it read changed version meanwhile.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, FixedVec3};

use super::generated::{GeneratedCache, Use};
use crate::collision::CollisionMesh;
use crate::mesh_buffers;
use crate::metrics as m;
use crate::sequencer::residency::with_neighbours;
use crate::validate::position::feet_voxel;

/// Chunks around a player's chunk meshed ahead of need (0 disables).
pub const DEFAULT_PREMESH_RADIUS: u8 = 1;
/// Largest allowed premesh radius.
pub const MAX_PREMESH_RADIUS: u8 = 3;
/// Chunks being meshed in the background at most; the rest wait in the backlog.
pub const DEFAULT_PREMESH_INFLIGHT: usize = 64;
/// Default player chunks whose surroundings wait for room in the background
/// mesher (`[engine] premesh_backlog`); past it, the oldest are dropped
/// (they are meshed on demand instead).
pub const DEFAULT_PREMESH_BACKLOG: usize = 4096;
/// Default generated chunks the background mesher keeps for reuse (about
/// 64 KiB each at most; `[engine] premesh_generated_chunks`).
pub const DEFAULT_PREMESH_GENERATED_CHUNKS: usize = 8192;
/// Default background mesher threads (`[engine] premesh_threads`).
pub const DEFAULT_PREMESH_THREADS: usize = 1;
/// Most background mesher threads allowed.
pub const MAX_PREMESH_THREADS: usize = 64;

/// The background mesher's bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PremeshLimits {
    /// Chunks queued or being meshed at most.
    pub inflight: usize,
    /// Player chunks waiting for room at most.
    pub backlog: usize,
    /// Generated chunks kept for reuse.
    pub generated_chunks: usize,
    /// Threads meshing jobs.
    pub threads: usize,
}

impl Default for PremeshLimits {
    fn default() -> Self {
        Self {
            inflight: DEFAULT_PREMESH_INFLIGHT,
            backlog: DEFAULT_PREMESH_BACKLOG,
            generated_chunks: DEFAULT_PREMESH_GENERATED_CHUNKS,
            threads: DEFAULT_PREMESH_THREADS,
        }
    }
}

/// One chunk to mesh and what it reads.
pub struct PremeshTarget {
    pub pos: ChunkPos,
    pub version: u64,
    /// Version of each of the 27 chunks the mesh reads, when queued.
    pub stamp: Vec<(ChunkPos, u64)>,
}

/// Chunks to mesh off the engine thread, together.
pub struct PremeshJob {
    pub targets: Vec<PremeshTarget>,
    /// The modified chunks they read, shared with the world; the rest are
    /// generated.
    pub modified: HashMap<ChunkPos, Arc<Chunk>>,
    pub generator: Arc<dyn ChunkGenerator>,
    /// [`Premesher::epoch`] when the job was built: a result of an older
    /// epoch may have read content that was put back since.
    pub epoch: u64,
}

impl PremeshJob {
    /// Meshes every target exactly as [`CollisionMesh::build`] on the world would.
    pub fn build(self, cache: &SharedGenerated) -> Vec<PremeshResult> {
        self.targets
            .into_iter()
            .map(|t| {
                let reads: HashMap<ChunkPos, Arc<Chunk>> = t
                    .stamp
                    .iter()
                    .map(|(p, _)| match self.modified.get(p) {
                        Some(c) => (*p, c.clone()),
                        None => (*p, cache.get(*p, &*self.generator)),
                    })
                    .collect();
                let nb = mesh_buffers::from_chunks(t.pos, |p| reads.get(&p).map(|c| &**c));
                let generated = reads
                    .into_iter()
                    .filter(|(p, _)| !self.modified.contains_key(p))
                    .collect();
                let mesh = CollisionMesh::build(t.pos, t.version, &nb);
                mesh_buffers::recycle([nb]);
                PremeshResult {
                    mesh,
                    stamp: t.stamp,
                    generated,
                    epoch: self.epoch,
                }
            })
            .collect()
    }
}

/// The mesher threads' one cache of generated chunks. A miss generates
/// outside the lock, so threads wait only for lookups, and for a chunk
/// another thread is generating: each chunk is generated once.
#[derive(Debug)]
pub struct SharedGenerated {
    state: Mutex<Generating>,
    /// Signalled whenever a chunk being generated is done.
    done: Condvar,
}

#[derive(Debug)]
struct Generating {
    cache: GeneratedCache,
    /// Chunks a thread is generating now (one per thread at most).
    underway: HashSet<ChunkPos>,
}

impl SharedGenerated {
    pub fn new(capacity: usize) -> Self {
        Self {
            state: Mutex::new(Generating {
                cache: GeneratedCache::new(capacity, Use::Premesh),
                underway: HashSet::new(),
            }),
            done: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, Generating> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The generated chunk at `pos`, from the cache or the generator.
    pub fn get(&self, pos: ChunkPos, generator: &dyn ChunkGenerator) -> Arc<Chunk> {
        let mut state = self.lock();
        loop {
            if let Some(c) = state.cache.lookup(pos) {
                return c;
            }
            if !state.underway.contains(&pos) {
                break;
            }
            state = self.done.wait(state).unwrap_or_else(|e| e.into_inner());
        }
        state.underway.insert(pos);
        drop(state);
        // Taken off the list whatever happens, so no thread waits forever.
        let finished = Finished { shared: self, pos };
        let c = Arc::new(generator.generate(pos));
        self.lock().cache.keep_generated(pos, c.clone());
        drop(finished);
        c
    }
}

/// Ends a chunk's generation in a [`SharedGenerated`] when dropped.
struct Finished<'a> {
    shared: &'a SharedGenerated,
    pos: ChunkPos,
}

impl Drop for Finished<'_> {
    fn drop(&mut self) {
        self.shared.lock().underway.remove(&self.pos);
        self.shared.done.notify_all();
    }
}

/// A built mesh and the chunk versions it was built from.
pub struct PremeshResult {
    pub mesh: CollisionMesh,
    pub stamp: Vec<(ChunkPos, u64)>,
    /// The unmodified chunks it generated: the engine keeps those it does
    /// not hold, so the first edits near a player need not generate them.
    pub generated: Vec<(ChunkPos, Arc<Chunk>)>,
    /// The job's [`PremeshJob::epoch`].
    pub epoch: u64,
}

impl PremeshResult {
    /// Whether the job was built in `epoch` (nothing it read was put back
    /// since) and every chunk the mesh read still has the version it had.
    pub fn is_current(&self, epoch: u64, version_of: impl Fn(ChunkPos) -> u64) -> bool {
        self.epoch == epoch && self.stamp.iter().all(|(p, v)| version_of(*p) == *v)
    }
}

/// Bounded background meshing: queue jobs, collect results.
pub struct Premesher {
    /// Jobs for the worker thread; it ends when this is dropped.
    jobs: SyncSender<PremeshJob>,
    inflight: HashSet<ChunkPos>,
    max_inflight: usize,
    max_backlog: usize,
    rx: Receiver<PremeshResult>,
    /// Centers waiting for room, oldest first.
    backlog: VecDeque<ChunkPos>,
    /// The same centers, for the duplicate check (the backlog may be long).
    waiting: HashSet<ChunkPos>,
    /// Raised whenever the world's content goes back or is replaced
    /// outside a commit ([`Self::invalidate`]).
    epoch: u64,
}

impl std::fmt::Debug for Premesher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Premesher")
            .field("inflight", &self.inflight())
            .finish_non_exhaustive()
    }
}

impl Premesher {
    pub fn new(limits: PremeshLimits) -> std::io::Result<Self> {
        let max_inflight = limits.inflight.max(1);
        let cache = Arc::new(SharedGenerated::new(limits.generated_chunks));
        // One slot per job in flight, so neither side ever blocks on send.
        let (results, rx) = sync_channel(max_inflight);
        let (jobs, queued) = sync_channel::<PremeshJob>(max_inflight);
        let queued = Arc::new(Mutex::new(queued));
        for i in 0..limits.threads.max(1) {
            let (queued, results, cache) = (queued.clone(), results.clone(), cache.clone());
            std::thread::Builder::new()
                .name(format!("strata-premesh-{i}"))
                .spawn(move || loop {
                    // The lock is held only while waiting for the next job;
                    // the threads end when the `Premesher` (the sender) goes.
                    let job = match queued.lock() {
                        Ok(rx) => rx.recv(),
                        Err(_) => return,
                    };
                    let Ok(job) = job else { return };
                    for r in job.build(&cache) {
                        let _ = results.send(r);
                    }
                })?;
        }
        Ok(Self {
            jobs,
            inflight: HashSet::new(),
            max_inflight,
            max_backlog: limits.backlog.max(1),
            rx,
            backlog: VecDeque::new(),
            waiting: HashSet::new(),
            epoch: 0,
        })
    }

    /// The epoch new jobs carry.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Chunks were put back to their stored state (a fenced batch), or
    /// reloaded from the store (a region claimed): a job in flight may have
    /// read content that will never be durable at the version it stamped,
    /// so every result of an older epoch is dropped.
    pub fn invalidate(&mut self) {
        self.epoch += 1;
    }

    /// Whether a job for `pos` is running or queued.
    pub fn is_inflight(&self, pos: ChunkPos) -> bool {
        self.inflight.contains(&pos)
    }

    /// Room for `n` more chunks.
    pub fn has_room(&self, n: usize) -> bool {
        self.inflight.len() + n <= self.max_inflight
    }

    /// Chunks that can still be queued.
    pub fn room(&self) -> usize {
        self.max_inflight.saturating_sub(self.inflight.len())
    }

    /// Remembers `center` until there is room; false if the backlog was
    /// full and its oldest center was dropped.
    pub fn defer(&mut self, center: ChunkPos) -> bool {
        if !self.waiting.insert(center) {
            return true;
        }
        let dropped = self.backlog.len() >= self.max_backlog;
        if dropped {
            if let Some(old) = self.backlog.pop_front() {
                self.waiting.remove(&old);
            }
        }
        self.backlog.push_back(center);
        !dropped
    }

    /// Centers waiting for room.
    pub fn backlog_len(&self) -> usize {
        self.backlog.len()
    }

    /// The oldest center waiting for room.
    pub fn next_deferred(&mut self) -> Option<ChunkPos> {
        let center = self.backlog.pop_front()?;
        self.waiting.remove(&center);
        Some(center)
    }

    /// Queues `job`; false (and nothing queued) if it does not fit or a
    /// target is already queued.
    pub fn submit(&mut self, job: PremeshJob) -> bool {
        if !self.has_room(job.targets.len())
            || job.targets.iter().any(|t| self.inflight.contains(&t.pos))
        {
            return false;
        }
        let targets: Vec<ChunkPos> = job.targets.iter().map(|t| t.pos).collect();
        // Jobs in flight hold at least one target each, so the queue has room.
        if self.jobs.try_send(job).is_err() {
            return false;
        }
        self.inflight.extend(targets);
        true
    }

    /// Results finished so far, without waiting.
    pub fn drain(&mut self) -> Vec<PremeshResult> {
        let done: Vec<PremeshResult> = self.rx.try_iter().collect();
        for r in &done {
            self.inflight.remove(&r.mesh.pos);
        }
        done
    }

    /// Jobs not yet drained.
    pub fn inflight(&self) -> usize {
        self.inflight.len()
    }
}

/// The chunks within `radius` of `center`, nearest first.
pub fn around(center: ChunkPos, radius: u8) -> Vec<ChunkPos> {
    let r = i32::from(radius);
    let mut v: Vec<(i32, ChunkPos)> = Vec::new();
    for dz in -r..=r {
        for dy in -r..=r {
            for dx in -r..=r {
                if let Some(p) = center.offset(dx, dy, dz) {
                    v.push((dx * dx + dy * dy + dz * dz, p));
                }
            }
        }
    }
    v.sort();
    v.into_iter().map(|(_, p)| p).collect()
}

/// The 27 chunks a mesh of `pos` reads, with their versions.
pub fn stamp(pos: ChunkPos, version_of: impl Fn(ChunkPos) -> u64) -> Vec<(ChunkPos, u64)> {
    with_neighbours(pos).map(|p| (p, version_of(p))).collect()
}

impl super::Engine {
    /// Queues background meshes around a player who entered a new chunk.
    pub(super) fn premesh_around(&mut self, session: u64, feet: FixedVec3) {
        let radius = self.cfg.premesh_radius;
        let center = feet_voxel(feet).chunk();
        let Some(peer) = self.peers.get_mut(&session) else {
            return;
        };
        if radius == 0 || peer.premeshed == Some(center) {
            return;
        }
        peer.premeshed = Some(center);
        self.premesh_center(center);
    }

    /// Queues meshes for the chunks around `center` that have none, nearest
    /// first, as many as there is room for; the rest wait in the backlog.
    fn premesh_center(&mut self, center: ChunkPos) {
        let durable = |p: ChunkPos| self.versions.get(&p).copied().unwrap_or(0);
        let now = Instant::now();
        let mut positions: Vec<ChunkPos> = around(center, self.cfg.premesh_radius)
            .into_iter()
            .filter(|p| !self.premesh.is_inflight(*p))
            .filter(|p| !self.unreadable.blocks(*p, now))
            .filter(|p| self.seq.collision().get(*p, durable(*p)).is_none())
            .collect();
        if positions.is_empty() {
            return;
        }
        let room = self.premesh.room();
        if room < positions.len() {
            positions.truncate(room);
            if !self.premesh.defer(center) {
                metrics::counter!(m::PREMESH_SKIPPED).increment(1);
            }
            if positions.is_empty() {
                return;
            }
        }
        let mut reads: Vec<ChunkPos> = positions
            .iter()
            .flat_map(|t| with_neighbours(*t))
            .filter(|p| self.versions.contains_key(p))
            .collect();
        reads.sort();
        reads.dedup();
        // A bad record costs the meshes that read it (their chunks are
        // left out of `positions` below), not the whole view's.
        match self.make_resident_readable(&reads, now) {
            Ok(bad) => positions.retain(|p| !super::unreadable::near_any(*p, &bad)),
            Err(e) => {
                crate::log_every::store_error("read", "store read failed (premesh)", &e);
                return;
            }
        }
        // Each chunk read is stamped with the world's version of it, not the
        // durable one: during a commit the world may hold a batch's
        // uncommitted content, which goes back if the batch is fenced; the
        // mesh of it must then be found stale. Chunks not read are generated
        // (version 0).
        let read: HashMap<ChunkPos, (Arc<Chunk>, u64)> = reads
            .iter()
            // Shared with the world: the engine thread copies nothing.
            .filter_map(|p| {
                let c = self.seq.world().peek(*p)?;
                Some((*p, (c.chunk.clone(), c.version)))
            })
            .collect();
        let version_of = |p: ChunkPos| read.get(&p).map_or(0, |(_, v)| *v);
        let targets = positions
            .into_iter()
            .map(|pos| PremeshTarget {
                pos,
                version: version_of(pos),
                stamp: stamp(pos, version_of),
            })
            .collect();
        let modified = read.into_iter().map(|(p, (c, _))| (p, c)).collect();
        self.premesh.submit(PremeshJob {
            targets,
            modified,
            generator: self.seq.world().generator().clone(),
            epoch: self.premesh.epoch(),
        });
    }

    /// Caches finished background meshes that are still current.
    pub(super) fn collect_premeshed(&mut self) {
        for r in self.premesh.drain() {
            for (p, chunk) in &r.generated {
                if !self.versions.contains_key(p) {
                    self.seq.adopt_generated(*p, chunk);
                }
            }
            let versions = &self.versions;
            if r.is_current(self.premesh.epoch(), |p| {
                versions.get(&p).copied().unwrap_or(0)
            }) {
                metrics::counter!(m::PREMESH_BUILT).increment(1);
                self.seq.insert_collision_mesh(r.mesh);
            } else {
                metrics::counter!(m::PREMESH_STALE).increment(1);
            }
        }
        // Refill from the backlog; a center not fully queued goes back.
        let mut waiting = self.premesh.backlog_len();
        while waiting > 0 && self.premesh.room() > 0 {
            waiting -= 1;
            match self.premesh.next_deferred() {
                Some(center) => self.premesh_center(center),
                None => break,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use super::*;
    use strata_terrain::gen::{GenParams, Generator};
    use strata_terrain::mesh::Neighborhood;
    use strata_terrain::World;

    fn generator() -> Arc<dyn ChunkGenerator> {
        Arc::new(Generator::fractal(GenParams::default()).expect("default params are valid"))
    }

    /// A job meshing `pos` in a world nobody edited.
    fn generated_job(pos: ChunkPos, g: &Arc<dyn ChunkGenerator>) -> PremeshJob {
        PremeshJob {
            targets: vec![PremeshTarget {
                pos,
                version: 0,
                stamp: stamp(pos, |_| 0),
            }],
            modified: HashMap::new(),
            generator: g.clone(),
            epoch: 0,
        }
    }

    fn wait_for(p: &mut Premesher, n: usize) -> Vec<PremeshResult> {
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut out = Vec::new();
        while out.len() < n && Instant::now() < deadline {
            out.extend(p.drain());
            std::thread::sleep(Duration::from_millis(2));
        }
        out
    }

    #[test]
    fn background_mesh_equals_world_mesh_and_goes_stale_on_change() {
        let g = generator();
        let mut world = World::new(g.clone());
        let surface = (0..16)
            .map(|y| ChunkPos::new(0, y - 8, 0))
            .find(|p| !matches!(*world.chunk(*p).chunk, Chunk::Uniform(_)))
            .expect("a surface chunk near the origin");
        // One modified neighbour: its copy must be what the job meshes.
        let above = surface.offset(0, 1, 0).unwrap();
        let mut edited = Chunk::clone(&world.chunk(above).chunk);
        edited.set(3, 0, 3, strata_terrain::Voxel::solid(3));
        let v = world.commit(above, edited.clone());
        let version_of = |p: ChunkPos| world.peek(p).map_or(0, |c| c.version);
        let mut pm = Premesher::new(PremeshLimits {
            inflight: 4,
            ..PremeshLimits::default()
        })
        .unwrap();
        let job = PremeshJob {
            targets: vec![PremeshTarget {
                pos: surface,
                version: 0,
                stamp: stamp(surface, version_of),
            }],
            modified: HashMap::from([(above, Arc::new(edited))]),
            generator: g.clone(),
            epoch: pm.epoch(),
        };
        assert!(pm.submit(job));
        assert!(pm.is_inflight(surface));
        let done = wait_for(&mut pm, 1);
        assert_eq!(done.len(), 1, "the job finishes");
        assert_eq!(pm.inflight(), 0);
        let expected = CollisionMesh::build(surface, 0, &Neighborhood::from_world(&world, surface));
        assert_eq!(done[0].mesh.hash, expected.hash);
        assert!(!done[0].mesh.mesh.indices.is_empty());
        assert!(done[0].is_current(pm.epoch(), version_of));
        // It hands back the 26 chunks it generated (not the modified one).
        assert_eq!(done[0].generated.len(), 26);
        for (p, c) in &done[0].generated {
            assert_ne!(*p, above);
            assert_eq!(**c, g.generate(*p));
        }
        // The neighbour moves on: the result is stale.
        let moved_on = |p| if p == above { v + 1 } else { version_of(p) };
        assert!(!done[0].is_current(pm.epoch(), moved_on));
        // As it is once content went back (a fenced batch), versions alike.
        pm.invalidate();
        assert!(!done[0].is_current(pm.epoch(), version_of));
    }

    #[test]
    fn submit_is_bounded_and_deduplicated() {
        let g = generator();
        let mut pm = Premesher::new(PremeshLimits {
            inflight: 2,
            ..PremeshLimits::default()
        })
        .unwrap();
        let job = |pos: ChunkPos| generated_job(pos, &g);
        let (a, b, c) = (
            ChunkPos::new(0, 0, 0),
            ChunkPos::new(1, 0, 0),
            ChunkPos::new(2, 0, 0),
        );
        assert!(pm.submit(job(a)));
        assert!(!pm.submit(job(a)), "already in flight");
        assert!(pm.submit(job(b)));
        assert!(!pm.submit(job(c)), "full");
        assert_eq!(wait_for(&mut pm, 2).len(), 2);
        assert!(pm.submit(job(c)), "room again after draining");
        assert_eq!(wait_for(&mut pm, 1).len(), 1);
    }

    #[test]
    fn several_threads_mesh_as_the_world_does() {
        let g = generator();
        let world = World::new(g.clone());
        let threads = 3;
        let mut pm = Premesher::new(PremeshLimits {
            inflight: 64,
            threads,
            ..PremeshLimits::default()
        })
        .unwrap();
        // Overlapping surroundings, one job per column: the threads share
        // the generated chunks between them.
        let targets: Vec<ChunkPos> = (0..4)
            .flat_map(|x| (-2..2).map(move |y| ChunkPos::new(x, y, 0)))
            .collect();
        for &pos in &targets {
            assert!(pm.submit(generated_job(pos, &g)));
        }
        let done = wait_for(&mut pm, targets.len());
        assert_eq!(done.len(), targets.len(), "every job finishes");
        for r in &done {
            let expected =
                CollisionMesh::build(r.mesh.pos, 0, &Neighborhood::from_world(&world, r.mesh.pos));
            assert_eq!(r.mesh.hash, expected.hash, "at {:?}", r.mesh.pos);
            assert_eq!(r.generated.len(), 27);
            for (p, c) in &r.generated {
                assert_eq!(**c, g.generate(*p));
            }
        }
    }

    /// Generates as `inner` does, except that its first two calls wait
    /// for each other: a mesher with one thread never gets past them.
    #[derive(Debug)]
    struct Rendezvous {
        inner: Arc<dyn ChunkGenerator>,
        calls: std::sync::atomic::AtomicUsize,
        barrier: std::sync::Barrier,
    }

    impl ChunkGenerator for Rendezvous {
        fn generate(&self, pos: ChunkPos) -> Chunk {
            if self.calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst) < 2 {
                self.barrier.wait();
            }
            self.inner.generate(pos)
        }
    }

    #[test]
    fn two_threads_mesh_two_jobs_at_once() {
        let g: Arc<dyn ChunkGenerator> = Arc::new(Rendezvous {
            inner: generator(),
            calls: Default::default(),
            barrier: std::sync::Barrier::new(2),
        });
        let mut pm = Premesher::new(PremeshLimits {
            threads: 2,
            ..PremeshLimits::default()
        })
        .unwrap();
        // Far apart: neither job finds the other's chunks in the cache.
        for pos in [ChunkPos::new(0, 0, 0), ChunkPos::new(40, 0, 0)] {
            assert!(pm.submit(generated_job(pos, &g)));
        }
        assert_eq!(wait_for(&mut pm, 2).len(), 2, "both jobs ran at once");
    }

    /// Generates as `inner` does, counting its calls, slowly.
    #[derive(Debug)]
    struct Counting {
        inner: Arc<dyn ChunkGenerator>,
        calls: std::sync::atomic::AtomicUsize,
    }

    impl ChunkGenerator for Counting {
        fn generate(&self, pos: ChunkPos) -> Chunk {
            self.calls.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            std::thread::sleep(Duration::from_millis(50));
            self.inner.generate(pos)
        }
    }

    #[test]
    fn threads_missing_one_chunk_at_once_generate_it_once() {
        let g = Counting {
            inner: generator(),
            calls: Default::default(),
        };
        let shared = SharedGenerated::new(16);
        let pos = ChunkPos::new(3, 0, 3);
        let start = std::sync::Barrier::new(4);
        let got: Vec<Arc<Chunk>> = std::thread::scope(|s| {
            let tasks: Vec<_> = (0..4)
                .map(|_| {
                    s.spawn(|| {
                        start.wait();
                        shared.get(pos, &g)
                    })
                })
                .collect();
            tasks.into_iter().map(|t| t.join().unwrap()).collect()
        });
        assert_eq!(g.calls.load(std::sync::atomic::Ordering::SeqCst), 1);
        assert!(got.iter().all(|c| Arc::ptr_eq(c, &got[0])));
        assert_eq!(*got[0], g.inner.generate(pos));
    }

    #[test]
    fn backlog_holds_the_configured_number_of_newest_centers() {
        let mut pm = Premesher::new(PremeshLimits {
            backlog: 3,
            ..PremeshLimits::default()
        })
        .unwrap();
        let c = |x: i32| ChunkPos::new(x, 0, 0);
        for x in 0..3 {
            assert!(pm.defer(c(x)), "room for {x}");
        }
        assert!(pm.defer(c(1)), "already waiting: nothing dropped");
        assert_eq!(pm.backlog_len(), 3);
        assert!(!pm.defer(c(3)), "full: the oldest goes");
        assert_eq!(pm.backlog_len(), 3);
        let left: Vec<ChunkPos> = std::iter::from_fn(|| pm.next_deferred()).collect();
        assert_eq!(left, vec![c(1), c(2), c(3)]);
        assert!(pm.defer(c(0)), "the dropped one may wait again");
        assert!(pm.defer(c(1)), "and so may one taken out");
        assert_eq!(pm.backlog_len(), 2);
    }

    #[test]
    fn around_is_nearest_first() {
        let c = ChunkPos::new(5, 5, 5);
        let v = around(c, 1);
        assert_eq!(v.len(), 27);
        assert_eq!(v[0], c);
        assert!(around(c, 0) == vec![c]);
    }
}
