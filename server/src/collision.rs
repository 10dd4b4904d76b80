//! LOD-0 collision meshes by chunk, and raycasts against them.
//!
//! The cache holds one mesh per chunk, tagged with the chunk version it was
//! built from, and drops the least recently used mesh past its capacity. A
//! mesh also depends on the neighbours' voxels (the apron), so whoever changes
//! a chunk calls [`CollisionCache::invalidate_touched`] to drop the meshes of
//! the chunk and of the neighbours whose apron holds a changed voxel. Meshes build in parallel on the rayon
//! pool ([`CollisionCache::mesh_chunks`]); each chunk's mesh is a pure function
//! of its neighbourhood, so the output does not depend on the thread count.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use rayon::prelude::*;

use crate::mesh_buffers;
use std::ops::RangeInclusive;

use strata_terrain::mesh::{
    mesh_chunk_layered, remesh_chunk_layered, remesh_chunk_layered_known, Mesh, MeshLayers,
    Neighborhood, LOCAL_MIN, LOD0_LOCAL_MAX,
};
use strata_terrain::{ChunkPos, VoxelBox, World, CHUNK_SIZE};

/// Meshes kept by default (a LOD-0 chunk mesh is tens of KiB). 2048 was
/// too few for 1000 players and more: evicted meshes were built again by
/// premesh and on the engine thread (BENCHMARKS.md, session 17).
pub const DEFAULT_COLLISION_CACHE_CAPACITY: usize = 8192;
/// Least `[sequencer] collision_cache_capacity`: a line-of-sight batch
/// needs the meshes of each ray at once (`Sequencer::check_sighted`
/// groups rays into half the cache), and half of this holds the longest
/// ray ([`MAX_RAY_CHUNKS`]).
pub const MIN_COLLISION_CACHE_CAPACITY: usize = 2 * MAX_RAY_CHUNKS;
/// Most `[sequencer] collision_cache_capacity` (about 5–10 GiB of meshes).
pub const MAX_COLLISION_CACHE_CAPACITY: usize = 262_144;
/// Most chunks one raycast walks through; bounds the work of a long ray.
pub const MAX_RAY_CHUNKS: usize = 256;
/// Hits closer than this to the origin are ignored (the ray starts on a surface).
const MIN_HIT_T: f64 = 1e-9;

/// Largest difference, on any axis, between two vertices of one LOD-0
/// triangle: Marching Cubes puts a triangle's vertices on the edges of one
/// unit cell (checked for every mesh in debug builds).
pub const TRIANGLE_SPAN: f64 = 1.0;
/// How far from a ray's box a triangle's first vertex may lie and the ray
/// still hit it: the span plus room, far more than the rounding of a hit.
const NEAR: f64 = TRIANGLE_SPAN + 1e-3;

/// A chunk's LOD-0 mesh with the version it was built from and its hash.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionMesh {
    pub pos: ChunkPos,
    pub version: u64,
    /// [`Mesh::hash`], sent to clients so they can check their own meshes.
    pub hash: u64,
    pub mesh: Mesh,
    /// Where the mesh's layers start, and what its neighbourhood held: what
    /// [`Self::rebuild`] needs of a base.
    layers: MeshLayers,
    /// The versions of the 27 chunks its neighbourhood was copied from,
    /// when the builder knew them: lets the next tick tell which layers its
    /// changes reach without copying and fingerprinting every layer
    /// (`sequencer/reach.rs`).
    sources: Option<Sources>,
    /// Chunk-local bounding box of the vertices (`None` for an empty mesh).
    bounds: Option<([f64; 3], [f64; 3])>,
}

/// The versions of the 27 chunks of a neighbourhood, in [`with_sources`]'
/// order (z slowest, then y, then x).
pub type Sources = [u64; 27];

/// A cached mesh and the chunk versions it is right for, when known.
pub type Base = (Arc<CollisionMesh>, Option<Sources>);

/// The 27 chunks around `pos` (itself included), in [`Sources`] order.
pub fn with_sources(pos: ChunkPos) -> [Option<ChunkPos>; 27] {
    std::array::from_fn(|i| {
        let d = |k: usize| (k % 3) as i32 - 1;
        pos.offset(d(i), d(i / 3), d(i / 9))
    })
}

/// The versions of the 27 chunks around `pos` in `world`; `None` unless all
/// are loaded (a missing one would be meshed as generated on the fly).
pub fn sources_of(world: &World, pos: ChunkPos) -> Option<Sources> {
    let around = with_sources(pos);
    let mut out = [0; 27];
    for (v, p) in out.iter_mut().zip(around) {
        *v = world.peek(p?)?.version;
    }
    Some(out)
}

/// One mesh to build: a chunk, its version, its neighbourhood and, when the
/// cache had one, an earlier mesh of it to copy unchanged layers from.
#[derive(Debug)]
pub struct MeshJob {
    pub pos: ChunkPos,
    pub version: u64,
    /// The whole neighbourhood, or with `known`, only the sample layers
    /// [`strata_terrain::mesh::remesh_reads`] names.
    pub nb: Neighborhood,
    pub base: Option<Arc<CollisionMesh>>,
    /// The sample layers (local z) that may differ from `base`'s
    /// neighbourhood, when the job's maker knows them; only with a base of
    /// the same chunk.
    pub known: Option<RangeInclusive<i32>>,
    /// The versions `nb` was copied from, when known.
    pub sources: Option<Sources>,
}

/// Cell layers meshed and copied from a base by a batch of builds, and how
/// many of its jobs copied only some layers of their neighbourhood.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct LayerCounts {
    pub meshed: u64,
    pub reused: u64,
    pub partial_copies: u64,
    pub whole_copies: u64,
}

impl CollisionMesh {
    /// Meshes one chunk at LOD 0.
    pub fn build(pos: ChunkPos, version: u64, nb: &Neighborhood) -> Self {
        let (mesh, layers) = mesh_chunk_layered(nb);
        Self::new(pos, version, mesh, layers)
    }

    /// What [`Self::rebuild`] makes of a whole neighbourhood, from a
    /// neighbourhood holding only the layers `known` reaches (see
    /// [`remesh_chunk_layered_known`]); `base` must be of the same chunk.
    pub fn rebuild_known(
        pos: ChunkPos,
        version: u64,
        nb: &Neighborhood,
        base: &Self,
        known: RangeInclusive<i32>,
    ) -> (Self, u32) {
        let r = remesh_chunk_layered_known(nb, (&base.mesh, &base.layers), known)
            .expect("a known job's base is of its own chunk (reach.rs checks)");
        (Self::new(pos, version, r.mesh, r.layers), r.reused)
    }

    /// The versions of the chunks its neighbourhood was copied from, when
    /// its builder knew them.
    pub fn sources(&self) -> Option<&Sources> {
        self.sources.as_ref()
    }

    /// [`Self::build`], copying from `base` (an earlier mesh of the same
    /// chunk) the layers the difference between the two neighbourhoods
    /// cannot reach; the result is the same bit for bit. Also returns how
    /// many of the 32 cell layers were copied.
    pub fn rebuild(pos: ChunkPos, version: u64, nb: &Neighborhood, base: &Self) -> (Self, u32) {
        let r = remesh_chunk_layered(nb, (&base.mesh, &base.layers));
        (Self::new(pos, version, r.mesh, r.layers), r.reused)
    }

    fn new(pos: ChunkPos, version: u64, mesh: Mesh, layers: MeshLayers) -> Self {
        debug_assert!(
            mesh.indices.chunks_exact(3).all(|t| {
                let v = |k: usize| mesh.positions[t[k] as usize];
                (0..3).all(|i| {
                    let (x, y, z) = (v(0)[i], v(1)[i], v(2)[i]);
                    f64::from(x.max(y).max(z) - x.min(y).min(z)) <= TRIANGLE_SPAN
                })
            }),
            "a triangle wider than TRIANGLE_SPAN"
        );
        let bounds = mesh.positions.first().map(|first| {
            let f = first.map(f64::from);
            mesh.positions.iter().fold((f, f), |(lo, hi), p| {
                (
                    std::array::from_fn(|i| lo[i].min(p[i] as f64)),
                    std::array::from_fn(|i| hi[i].max(p[i] as f64)),
                )
            })
        });
        Self {
            pos,
            version,
            hash: mesh.hash(),
            mesh,
            layers,
            sources: None,
            bounds,
        }
    }

    /// Nearest triangle hit in chunk-local coordinates: `(t, triangle index)`;
    /// of equally near ones, the last. A triangle the ray hits has its first
    /// vertex within [`TRIANGLE_SPAN`] of the box of the part of the ray
    /// inside the mesh's bounds, so only those triangles are tested.
    fn raycast_local(&self, o: [f64; 3], d: [f64; 3], max_t: f64) -> Option<(f64, u32)> {
        let (lo, hi) = self.ray_box(o, d, max_t)?;
        let (lo, hi) = (lo.map(|v| v - NEAR), hi.map(|v| v + NEAR));
        let near = |n: &u32| {
            let v = self.mesh.positions[self.mesh.indices[3 * *n as usize] as usize];
            (0..3).all(|i| (lo[i]..=hi[i]).contains(&f64::from(v[i])))
        };
        let all = 0..(self.mesh.indices.len() / 3) as u32;
        self.nearest_hit(o, d, max_t, all.filter(near))
    }

    /// The box of the part of the ray within `max_t` inside the mesh's
    /// bounds, or `None` if it misses them.
    fn ray_box(&self, o: [f64; 3], d: [f64; 3], max_t: f64) -> Option<([f64; 3], [f64; 3])> {
        let (lo, hi) = self.bounds?;
        let (t0, t1) = slab(o, d, lo, hi).filter(|(t0, _)| *t0 <= max_t)?;
        let (a, b) = (at(o, d, t0), at(o, d, t1.min(max_t)));
        Some((
            std::array::from_fn(|i| a[i].min(b[i])),
            std::array::from_fn(|i| a[i].max(b[i])),
        ))
    }

    /// [`Self::raycast_local`] over the given triangles, in the order given.
    fn nearest_hit(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        max_t: f64,
        triangles: impl Iterator<Item = u32>,
    ) -> Option<(f64, u32)> {
        let p = |i: u32| self.mesh.positions[i as usize].map(f64::from);
        let mut best: Option<(f64, u32)> = None;
        for n in triangles {
            let tri = &self.mesh.indices[3 * n as usize..3 * n as usize + 3];
            let limit = best.map_or(max_t, |b| b.0);
            if let Some(t) = moller_trumbore(o, d, p(tri[0]), p(tri[1]), p(tri[2])) {
                if t <= limit && t > MIN_HIT_T {
                    best = Some((t, n));
                }
            }
        }
        best
    }
}

/// Where a ray first hit terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance from the origin along the (normalized) direction, in voxels.
    pub t: f64,
    pub chunk: ChunkPos,
    /// Triangle index in that chunk's mesh.
    pub triangle: u32,
}

#[derive(Debug)]
struct Entry {
    mesh: Arc<CollisionMesh>,
    /// Versions of the 27 chunks the mesh is right for: those it was copied
    /// from, moved on past each neighbour change that did not reach it.
    sources: Option<Sources>,
    stamp: u64,
    /// Rebuilt ahead of need (a rewarm).
    rewarm: bool,
    /// Looked up since it was built ([`CollisionCache::ensure`] or
    /// [`CollisionCache::lookup`]): in use. Atomic so that a lookup needs
    /// only `&self`.
    looked_up: AtomicBool,
}

impl Entry {
    fn looked_up(&self) -> bool {
        self.looked_up.load(Ordering::Relaxed)
    }

    /// Marks the mesh in use; a rewarm's first use counts in `used`.
    fn mark_looked_up(&self, used: &AtomicU64) {
        if !self.looked_up.swap(true, Ordering::Relaxed) && self.rewarm {
            used.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// LRU-bounded cache of collision meshes by chunk.
#[derive(Debug)]
pub struct CollisionCache {
    capacity: usize,
    entries: HashMap<ChunkPos, Entry>,
    /// Use stamp -> chunk, oldest first.
    lru: BTreeMap<u64, ChunkPos>,
    clock: u64,
    /// See [`Self::built_on_demand`].
    built_on_demand: u64,
    /// See [`Self::rewarm_outcomes`] (used: counted on a `&self` lookup).
    rewarms_used: AtomicU64,
    rewarms_wasted: u64,
}

/// What became of the meshes rebuilt ahead of need ([`CollisionCache::insert_rewarmed`]).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct RewarmOutcomes {
    /// Looked up ([`CollisionCache::ensure`], [`CollisionCache::lookup`])
    /// before being dropped.
    pub used: u64,
    /// Dropped (stale, replaced or evicted) without a lookup.
    pub wasted: u64,
}

impl Default for CollisionCache {
    fn default() -> Self {
        Self::new(DEFAULT_COLLISION_CACHE_CAPACITY)
    }
}

impl CollisionCache {
    /// A cache holding at most `capacity` meshes (at least one).
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            entries: HashMap::new(),
            lru: BTreeMap::new(),
            clock: 0,
            built_on_demand: 0,
            rewarms_used: AtomicU64::new(0),
            rewarms_wasted: 0,
        }
    }

    /// Builds meshes in parallel on the current rayon pool, in input order
    /// (from a job's base where it has one), and counts the cell layers
    /// meshed and copied.
    pub fn mesh_chunks(jobs: &[MeshJob]) -> (Vec<CollisionMesh>, LayerCounts) {
        let built: Vec<(CollisionMesh, u32)> = jobs
            .par_iter()
            .map(|j| {
                let (mut m, reused) = match (&j.base, &j.known) {
                    (Some(base), Some(known)) => {
                        CollisionMesh::rebuild_known(j.pos, j.version, &j.nb, base, known.clone())
                    }
                    (Some(base), None) => CollisionMesh::rebuild(j.pos, j.version, &j.nb, base),
                    (None, _) => (CollisionMesh::build(j.pos, j.version, &j.nb), 0),
                };
                m.sources = j.sources;
                (m, reused)
            })
            .collect();
        let layers = (CHUNK_SIZE as u64) * built.len() as u64;
        let reused: u64 = built.iter().map(|(_, r)| u64::from(*r)).sum();
        let partial = jobs.iter().filter(|j| j.known.is_some()).count() as u64;
        let counts = LayerCounts {
            meshed: layers - reused,
            reused,
            partial_copies: partial,
            whole_copies: jobs.len() as u64 - partial,
        };
        (built.into_iter().map(|(m, _)| m).collect(), counts)
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// [`Self::get`] for a caller that uses the mesh (a snapshot frame its
    /// hash): marks it in use, as [`Self::rewarm_outcomes`] counts.
    pub fn lookup(&self, pos: ChunkPos, version: u64) -> Option<&Arc<CollisionMesh>> {
        let e = self
            .entries
            .get(&pos)
            .filter(|e| e.mesh.version == version)?;
        e.mark_looked_up(&self.rewarms_used);
        Some(&e.mesh)
    }

    /// The cached mesh of `pos`, whatever version it was built from (a base
    /// for [`CollisionMesh::rebuild`]); does not count as a use.
    pub fn peek(&self, pos: ChunkPos) -> Option<&Arc<CollisionMesh>> {
        self.entries.get(&pos).map(|e| &e.mesh)
    }

    /// [`Self::peek`] with the chunk versions the mesh is right for, when
    /// known: a base for a job that copies only the layers a change reaches.
    pub fn peek_base(&self, pos: ChunkPos) -> Option<Base> {
        self.entries.get(&pos).map(|e| (e.mesh.clone(), e.sources))
    }

    /// The cached mesh of `pos` if it was built from `version`.
    pub fn get(&self, pos: ChunkPos, version: u64) -> Option<&Arc<CollisionMesh>> {
        self.entries
            .get(&pos)
            .map(|e| &e.mesh)
            .filter(|m| m.version == version)
    }

    /// Adds (or replaces) a mesh as the most recently used; evicts the oldest past capacity.
    pub fn insert(&mut self, mesh: CollisionMesh) -> Arc<CollisionMesh> {
        self.insert_entry(mesh, false)
    }

    /// [`Self::insert`] for a mesh rebuilt before anything asked for it;
    /// whether something then does is counted ([`Self::rewarm_outcomes`]).
    pub fn insert_rewarmed(&mut self, mesh: CollisionMesh) -> Arc<CollisionMesh> {
        self.insert_entry(mesh, true)
    }

    fn insert_entry(&mut self, mesh: CollisionMesh, rewarm: bool) -> Arc<CollisionMesh> {
        let pos = mesh.pos;
        let mesh = Arc::new(mesh);
        self.clock += 1;
        let entry = Entry {
            mesh: mesh.clone(),
            sources: mesh.sources,
            stamp: self.clock,
            rewarm,
            looked_up: AtomicBool::new(false),
        };
        if let Some(old) = self.entries.insert(pos, entry) {
            self.lru.remove(&old.stamp);
            self.count_dropped(&old);
        }
        self.lru.insert(self.clock, pos);
        while self.entries.len() > self.capacity {
            let Some((_, oldest)) = self.lru.pop_first() else {
                break;
            };
            if let Some(old) = self.entries.remove(&oldest) {
                self.count_dropped(&old);
            }
        }
        mesh
    }

    fn count_dropped(&mut self, e: &Entry) {
        if e.rewarm && !e.looked_up() {
            self.rewarms_wasted += 1;
        }
    }

    /// How many rewarmed meshes were used, and how many dropped unused,
    /// since the cache was made.
    pub fn rewarm_outcomes(&self) -> RewarmOutcomes {
        RewarmOutcomes {
            used: self.rewarms_used.load(Ordering::Relaxed),
            wasted: self.rewarms_wasted,
        }
    }

    fn touch(&mut self, pos: ChunkPos) {
        if let Some(e) = self.entries.get_mut(&pos) {
            e.mark_looked_up(&self.rewarms_used);
            self.clock += 1;
            self.lru.remove(&e.stamp);
            e.stamp = self.clock;
            self.lru.insert(self.clock, pos);
        }
    }

    /// Drops the mesh of `pos`; returns it if there was one.
    pub fn invalidate(&mut self, pos: ChunkPos) -> Option<Arc<CollisionMesh>> {
        self.invalidate_base(pos).map(|(mesh, _)| mesh)
    }

    /// [`Self::invalidate`], with the versions the mesh was right for.
    fn invalidate_base(&mut self, pos: ChunkPos) -> Option<Base> {
        let e = self.entries.remove(&pos)?;
        self.lru.remove(&e.stamp);
        self.count_dropped(&e);
        Some((e.mesh, e.sources))
    }

    /// Drops the meshes of `pos` and its 26 neighbours: all of them read
    /// `pos`'s voxels (their aprons), so a change to `pos` may change them.
    pub fn invalidate_around(&mut self, pos: ChunkPos) {
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(p) = pos.offset(dx, dy, dz) {
                        self.invalidate(p);
                    }
                }
            }
        }
    }

    /// Drops the meshes that read any voxel of `pos` inside `changed` (world
    /// coordinates): `pos`'s own, and each neighbour's whose apron overlaps
    /// the box. A small edit in a chunk's middle keeps every neighbour's
    /// mesh. Returns the meshes dropped, with the versions they were right
    /// for.
    pub fn invalidate_touched(&mut self, pos: ChunkPos, changed: VoxelBox) -> Vec<Base> {
        let mut dropped = Vec::new();
        let o = pos.origin();
        let lo = [
            changed.min.x - o.x,
            changed.min.y - o.y,
            changed.min.z - o.z,
        ];
        let hi = [
            changed.max.x - o.x,
            changed.max.y - o.y,
            changed.max.z - o.z,
        ];
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    // An LOD-0 mesh reads its local LOCAL_MIN..=LOD0_LOCAL_MAX on every
                    // axis (not the surface-scan rows above); in `pos`'s local frame
                    // that range moves by one chunk per step.
                    let reads =
                        [dx, dy, dz]
                            .iter()
                            .zip(lo.iter().zip(&hi))
                            .all(|(&d, (&l, &h))| {
                                let shift = d * CHUNK_SIZE;
                                l <= LOD0_LOCAL_MAX + shift && h >= LOCAL_MIN + shift
                            });
                    if let Some(p) = pos.offset(dx, dy, dz).filter(|_| reads) {
                        dropped.extend(self.invalidate_base(p));
                    }
                }
            }
        }
        dropped
    }

    /// Notes that `pos` is now at `version` in the meshes of its neighbours
    /// still cached: call it once a tick's changes of `pos` have dropped
    /// every mesh they reach ([`Self::invalidate_touched`]), so the meshes
    /// left are right for the new version too.
    pub fn moved_on(&mut self, pos: ChunkPos, version: u64) {
        for (i, p) in with_sources(pos).into_iter().enumerate() {
            let Some(s) = p
                .and_then(|p| self.entries.get_mut(&p))
                .and_then(|e| e.sources.as_mut())
            else {
                continue;
            };
            // `pos` seen from `p`: the opposite offset, the mirrored slot.
            s[26 - i] = version;
        }
    }

    /// Makes sure each listed chunk has a mesh for its current version in
    /// `world` (unloaded chunks count as generated, version 0), building the
    /// missing ones (their neighbourhood copies too) in parallel on the
    /// current rayon pool. Load the chunks and their neighbours first:
    /// unloaded voxels are generated on the fly, which is slow.
    pub fn ensure(&mut self, world: &World, chunks: &[ChunkPos]) {
        let version = |p: ChunkPos| world.peek(p).map_or(0, |c| c.version);
        let mut missing: Vec<(ChunkPos, u64)> = Vec::new();
        // A set, not a scan of `missing`: a batch of rays lists thousands.
        let mut listed: rustc_hash::FxHashSet<ChunkPos> = Default::default();
        for &p in chunks {
            if self.get(p, version(p)).is_some() {
                self.touch(p);
            } else if listed.insert(p) {
                missing.push((p, version(p)));
            }
        }
        let copy = |&(pos, version): &(ChunkPos, u64)| MeshJob {
            pos,
            version,
            nb: mesh_buffers::from_world(world, pos),
            base: self.peek(pos).cloned(),
            known: None,
            sources: sources_of(world, pos),
        };
        let jobs: Vec<MeshJob> = if missing.len() > 1 {
            missing.par_iter().map(copy).collect()
        } else {
            missing.iter().map(copy).collect()
        };
        self.built_on_demand += jobs.len() as u64;
        for m in Self::mesh_chunks(&jobs).0 {
            self.insert(m);
        }
        mesh_buffers::recycle(jobs.into_iter().map(|j| j.nb));
    }

    /// Meshes [`Self::ensure`] has built since the cache was made: each one
    /// a line-of-sight check (or a caller) waited for.
    pub fn built_on_demand(&self) -> u64 {
        self.built_on_demand
    }

    /// The first terrain hit along the ray within `max_dist` voxels, looking
    /// only at cached meshes (call [`Self::ensure`] with [`ray_chunks`] first).
    /// `dir` need not be normalized; a zero direction hits nothing.
    pub fn raycast(&self, origin: [f64; 3], dir: [f64; 3], max_dist: f64) -> Option<Hit> {
        let d = normalize(dir)?;
        for step in ChunkWalk::new(origin, d, max_dist) {
            let Some(e) = self.entries.get(&step.chunk) else {
                continue;
            };
            let o = step.chunk.origin();
            let local = [
                origin[0] - o.x as f64,
                origin[1] - o.y as f64,
                origin[2] - o.z as f64,
            ];
            if let Some((t, triangle)) = e.mesh.raycast_local(local, d, max_dist) {
                // A chunk's triangles lie inside its box, so a hit here is
                // nearer than anything in the chunks the ray enters later.
                return Some(Hit {
                    t,
                    chunk: step.chunk,
                    triangle,
                });
            }
        }
        None
    }
}

/// Chunks a ray passes through within `max_dist`, in the order it enters them.
pub fn ray_chunks(origin: [f64; 3], dir: [f64; 3], max_dist: f64) -> Vec<ChunkPos> {
    match normalize(dir) {
        Some(d) => ChunkWalk::new(origin, d, max_dist)
            .map(|s| s.chunk)
            .collect(),
        None => vec![chunk_of(origin)],
    }
}

fn normalize(d: [f64; 3]) -> Option<[f64; 3]> {
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    (len.is_finite() && len > 0.0).then(|| d.map(|v| v / len))
}

fn chunk_of(p: [f64; 3]) -> ChunkPos {
    let c = |v: f64| (v / CHUNK_SIZE as f64).floor() as i32;
    ChunkPos::new(c(p[0]), c(p[1]), c(p[2]))
}

#[derive(Debug)]
struct WalkStep {
    chunk: ChunkPos,
}

/// Amanatides–Woo 3D DDA over 32-voxel cells.
#[derive(Debug)]
struct ChunkWalk {
    cell: [i32; 3],
    step: [i32; 3],
    t_max: [f64; 3],
    t_delta: [f64; 3],
    max_dist: f64,
    visited: usize,
    done: bool,
}

impl ChunkWalk {
    fn new(origin: [f64; 3], d: [f64; 3], max_dist: f64) -> Self {
        let size = CHUNK_SIZE as f64;
        let c = chunk_of(origin);
        let cell = [c.x, c.y, c.z];
        let mut step = [0; 3];
        let mut t_max = [f64::INFINITY; 3];
        let mut t_delta = [f64::INFINITY; 3];
        for i in 0..3 {
            if d[i] > 0.0 {
                step[i] = 1;
                t_max[i] = ((cell[i] as f64 + 1.0) * size - origin[i]) / d[i];
                t_delta[i] = size / d[i];
            } else if d[i] < 0.0 {
                step[i] = -1;
                t_max[i] = (cell[i] as f64 * size - origin[i]) / d[i];
                t_delta[i] = -size / d[i];
            }
        }
        let valid = origin.iter().all(|v| v.is_finite()) && max_dist >= 0.0;
        Self {
            cell,
            step,
            t_max,
            t_delta,
            max_dist,
            visited: 0,
            done: !valid,
        }
    }
}

impl Iterator for ChunkWalk {
    type Item = WalkStep;

    fn next(&mut self) -> Option<WalkStep> {
        if self.done || self.visited >= MAX_RAY_CHUNKS {
            return None;
        }
        self.visited += 1;
        let chunk = ChunkPos::new(self.cell[0], self.cell[1], self.cell[2]);
        // Advance along the axis whose boundary comes first.
        let axis = (0..3)
            .min_by(|&a, &b| self.t_max[a].total_cmp(&self.t_max[b]))
            .unwrap_or(0);
        if self.t_max[axis] > self.max_dist || self.step[axis] == 0 {
            self.done = true;
        } else {
            match self.cell[axis].checked_add(self.step[axis]) {
                Some(c) => self.cell[axis] = c,
                None => self.done = true,
            }
            self.t_max[axis] += self.t_delta[axis];
        }
        Some(WalkStep { chunk })
    }
}

/// Ray/box slab test: the `[t_enter, t_exit]` range inside the box, if any (t >= 0).
fn slab(o: [f64; 3], d: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for i in 0..3 {
        if d[i] == 0.0 {
            if o[i] < lo[i] || o[i] > hi[i] {
                return None;
            }
        } else {
            let a = (lo[i] - o[i]) / d[i];
            let b = (hi[i] - o[i]) / d[i];
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
    }
    (t0 <= t1).then_some((t0, t1))
}

/// The point `o + t d`.
fn at(o: [f64; 3], d: [f64; 3], t: f64) -> [f64; 3] {
    std::array::from_fn(|i| o[i] + t * d[i])
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Möller–Trumbore ray/triangle intersection, both faces; returns `t`.
#[inline(always)]
fn moller_trumbore(o: [f64; 3], d: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> Option<f64> {
    const EPS: f64 = 1e-12;
    let e1 = sub(b, a);
    let e2 = sub(c, a);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < EPS {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, a);
    let u = dot(s, p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t >= 0.0).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use strata_terrain::material::ids;
    use strata_terrain::world::FlatGenerator;
    use strata_terrain::Voxel;
    use strata_terrain::VoxelPos;

    fn flat() -> World {
        World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        }))
    }

    #[test]
    fn casts_near_the_ray_find_what_testing_every_triangle_finds() {
        use strata_terrain::gen::{GenParams, Generator};
        let world = World::new(Arc::new(Generator::fractal(GenParams::default()).unwrap()));
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut unit = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut meshes, mut hits) = (0, 0);
        let flat = flat();
        let cases = [(0, -1, 0), (0, 0, 0), (3, -1, -2), (-4, 0, 5), (7, 1, 7)]
            .map(|p| (p, &world))
            .into_iter()
            .chain([((3, -1, 3), &flat)]);
        for ((x, y, z), world) in cases {
            let pos = ChunkPos::new(x, y, z);
            let m = CollisionMesh::build(pos, 0, &Neighborhood::from_world(world, pos));
            if m.mesh.indices.is_empty() {
                continue;
            }
            meshes += 1;
            let all = || 0..(m.mesh.indices.len() / 3) as u32;
            for k in 0..3000 {
                // Origins in and around the chunk, some on whole voxels;
                // some directions along an axis or in a plane.
                let mut o: [f64; 3] = std::array::from_fn(|_| unit() * 48.0 - 8.0);
                if k % 5 == 0 {
                    o = o.map(|v| (v / 4.0).round() * 4.0);
                }
                let mut d: [f64; 3] = std::array::from_fn(|_| unit() * 2.0 - 1.0);
                if k % 7 == 0 {
                    d[k % 3] = 0.0;
                }
                if k % 11 == 0 {
                    d = [0.0, -1.0, 0.0];
                }
                let Some(d) = normalize(d) else { continue };
                let max_t = unit() * 60.0;
                let near = m.raycast_local(o, d, max_t);
                assert_eq!(
                    near,
                    m.nearest_hit(o, d, max_t, all()),
                    "{pos:?} {o:?} {d:?}"
                );
                hits += usize::from(near.is_some());
            }
        }
        assert!(meshes >= 2, "the sample needs surface chunks");
        assert!(hits > 500, "the rays must hit terrain often: {hits}");
    }

    #[test]
    fn triangle_hit_and_miss() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        let t = moller_trumbore([0.2, 5.0, 0.2], [0.0, -1.0, 0.0], a, b, c);
        assert_eq!(t, Some(5.0));
        assert_eq!(
            moller_trumbore([0.9, 5.0, 0.9], [0.0, -1.0, 0.0], a, b, c),
            None
        );
    }

    #[test]
    fn dda_visits_chunks_in_order() {
        let c = ray_chunks([1.0, 1.0, 1.0], [1.0, 0.0, 0.0], 70.0);
        assert_eq!(
            c,
            vec![
                ChunkPos::new(0, 0, 0),
                ChunkPos::new(1, 0, 0),
                ChunkPos::new(2, 0, 0)
            ]
        );
        let diag = ray_chunks([31.0, 31.0, 0.5], [1.0, 1.0, 0.0], 4.0);
        assert_eq!(diag.first(), Some(&ChunkPos::new(0, 0, 0)));
        assert!(diag.contains(&ChunkPos::new(1, 1, 0)));
        assert_eq!(ray_chunks([0.0; 3], [0.0; 3], 5.0).len(), 1);
        assert!(ray_chunks([0.0; 3], [1.0, 0.0, 0.0], 1e12).len() <= MAX_RAY_CHUNKS);
    }

    #[test]
    fn ray_hits_flat_ground_across_chunks() {
        let world = flat();
        let mut cache = CollisionCache::new(64);
        // Straight down from y = 10 onto the surface at y = -0.5.
        let origin = [40.5, 10.0, 3.5];
        let chunks = ray_chunks(origin, [0.0, -1.0, 0.0], 20.0);
        cache.ensure(&world, &chunks);
        let hit = cache.raycast(origin, [0.0, -1.0, 0.0], 20.0).unwrap();
        assert!((hit.t - 10.5).abs() < 1e-6, "t = {}", hit.t);
        assert_eq!(hit.chunk, ChunkPos::new(1, -1, 0));
        assert!(cache.raycast(origin, [0.0, 1.0, 0.0], 20.0).is_none());
        assert!(cache.raycast(origin, [0.0, -1.0, 0.0], 10.0).is_none());
    }

    #[test]
    fn lru_evicts_oldest_and_versions_gate_hits() {
        let world = flat();
        let mut cache = CollisionCache::new(2);
        let (a, b, c) = (
            ChunkPos::new(0, -1, 0),
            ChunkPos::new(1, -1, 0),
            ChunkPos::new(2, -1, 0),
        );
        cache.ensure(&world, &[a, b]);
        cache.ensure(&world, &[a]); // a becomes most recent
        assert_eq!(cache.built_on_demand(), 2, "a cached mesh is not rebuilt");
        cache.ensure(&world, &[c]);
        assert_eq!(cache.built_on_demand(), 3);
        assert_eq!(cache.len(), 2);
        assert!(cache.get(a, 0).is_some());
        assert!(cache.get(b, 0).is_none());
        assert!(cache.get(a, 1).is_none(), "other version is a miss");
        cache.invalidate_around(ChunkPos::new(1, 0, 0));
        assert!(cache.is_empty());
    }

    #[test]
    fn rewarm_outcomes_count_lookups_and_unused_drops() {
        let world = flat();
        let mesh = |x: i32| {
            let p = ChunkPos::new(x, -1, 0);
            CollisionMesh::build(p, 0, &Neighborhood::from_world(&world, p))
        };
        let mut cache = CollisionCache::new(3);
        cache.insert_rewarmed(mesh(0));
        cache.insert_rewarmed(mesh(1));
        cache.insert(mesh(2));
        assert_eq!(cache.rewarm_outcomes(), RewarmOutcomes::default());
        // Looked up: used, once however often.
        cache.ensure(&world, &[ChunkPos::new(0, -1, 0)]);
        cache.ensure(&world, &[ChunkPos::new(0, -1, 0)]);
        assert_eq!(cache.built_on_demand(), 0);
        let counts = |used, wasted| RewarmOutcomes { used, wasted };
        assert_eq!(cache.rewarm_outcomes(), counts(1, 0));
        // Dropped unused: stale, replaced or evicted.
        assert!(cache.invalidate(ChunkPos::new(1, -1, 0)).is_some());
        assert_eq!(cache.rewarm_outcomes(), counts(1, 1));
        cache.insert_rewarmed(mesh(3));
        cache.insert(mesh(3));
        assert_eq!(cache.rewarm_outcomes(), counts(1, 2));
        cache.insert_rewarmed(mesh(4)); // evicts the plain 2
        cache.insert(mesh(5)); // evicts the used 0: not counted
        cache.insert(mesh(6)); // evicts 3, plain since its replacement
        cache.insert(mesh(7)); // evicts the unused rewarm 4
        assert_eq!(cache.rewarm_outcomes(), counts(1, 3));
        // Invalidating a used one counts nothing.
        cache.insert_rewarmed(mesh(8));
        cache.ensure(&world, &[ChunkPos::new(8, -1, 0)]);
        assert!(cache.invalidate(ChunkPos::new(8, -1, 0)).is_some());
        assert_eq!(cache.rewarm_outcomes(), counts(2, 3));
        // A snapshot's lookup is a use too; a presence check is not.
        cache.insert_rewarmed(mesh(9));
        let p9 = ChunkPos::new(9, -1, 0);
        assert!(cache.get(p9, 0).is_some());
        assert!(cache.lookup(p9, 1).is_none(), "another version");
        assert_eq!(cache.rewarm_outcomes(), counts(2, 3));
        assert!(cache.lookup(p9, 0).is_some());
        assert!(cache.lookup(p9, 0).is_some());
        assert_eq!(cache.rewarm_outcomes(), counts(3, 3));
    }

    #[test]
    fn touched_invalidation_drops_only_neighbours_reading_the_change() {
        let world = flat();
        let mut cache = CollisionCache::new(64);
        let centre = ChunkPos::new(0, -1, 0);
        let around: Vec<ChunkPos> = (-1..=1)
            .flat_map(|dz| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dx| (dx, dy, dz))))
            .filter_map(|(dx, dy, dz)| centre.offset(dx, dy, dz))
            .collect();
        let o = centre.origin();
        let boxed = |a: [i32; 3], b: [i32; 3]| VoxelBox {
            min: VoxelPos::new(o.x + a[0], o.y + a[1], o.z + a[2]),
            max: VoxelPos::new(o.x + b[0], o.y + b[1], o.z + b[2]),
        };
        let held = |cache: &CollisionCache| {
            around
                .iter()
                .filter(|p| cache.get(**p, 0).is_some())
                .count()
        };
        // A change deep inside (y 10..=20, away from every apron) drops only the chunk.
        cache.ensure(&world, &around);
        cache.invalidate_touched(centre, boxed([10, 10, 10], [20, 20, 20]));
        assert!(cache.get(centre, 0).is_none());
        assert_eq!(held(&cache), 26);
        // Local x = 1 is in the -x neighbour's apron (its local 33), and so is
        // y = 1 in the chunk below's.
        cache.ensure(&world, &around);
        cache.invalidate_touched(centre, boxed([1, 1, 10], [5, 12, 20]));
        let dropped: Vec<_> = around
            .iter()
            .filter(|p| cache.get(**p, 0).is_none())
            .collect();
        let want = |d: (i32, i32, i32)| dropped.contains(&&centre.offset(d.0, d.1, d.2).unwrap());
        assert_eq!(dropped.len(), 4, "{dropped:?}");
        for d in [(0, 0, 0), (-1, 0, 0), (0, -1, 0), (-1, -1, 0)] {
            assert!(want(d), "{d:?} dropped");
        }
        // y = 2..=8 is beyond the reach of the chunk below: those are its
        // surface-scan rows, which LOD 0 never reads. x = 31 reaches +x.
        cache.ensure(&world, &around);
        cache.invalidate_touched(centre, boxed([31, 2, 31], [31, 8, 31]));
        assert_eq!(held(&cache), 27 - 4, "self, +x, +z, +x+z");
    }

    #[test]
    fn parallel_meshing_matches_serial_with_and_without_bases() {
        let mut world = flat();
        let at = |x| ChunkPos::new(x, -1, 0);
        let before: Vec<CollisionMesh> = (0..4)
            .map(|x| CollisionMesh::build(at(x), 0, &Neighborhood::from_world(&world, at(x))))
            .collect();
        // Dig a pit in chunk 1 near its face with chunk 2: both meshes change.
        let pit = strata_terrain::Edit::ClearBox {
            min: VoxelPos::new(60, -4, 4),
            max: VoxelPos::new(63, -1, 8),
        };
        let ctx = strata_terrain::EditContext {
            materials: &strata_terrain::MaterialTable::default(),
            structures: &Default::default(),
        };
        pit.apply(&mut world, &ctx).expect("valid edit");
        let jobs: Vec<MeshJob> = (0..4)
            .map(|x| MeshJob {
                pos: at(x),
                version: 1,
                nb: Neighborhood::from_world(&world, at(x)),
                base: (x != 3).then(|| Arc::new(before[x as usize].clone())),
                known: None,
                sources: None,
            })
            .collect();
        let (par, layers) = CollisionCache::mesh_chunks(&jobs);
        assert_eq!(layers.meshed + layers.reused, 4 * 32);
        assert!(layers.reused > 2 * 32, "{layers:?}");
        for (j, m) in jobs.iter().zip(&par) {
            assert_eq!(*m, CollisionMesh::build(j.pos, j.version, &j.nb));
            assert!(m.mesh.triangle_count() > 0);
        }
        assert_ne!(par[1].hash, before[1].hash, "the pit is in chunk 1");
        assert_ne!(par[2].hash, before[2].hash, "and in chunk 2's apron");
        assert_eq!(par[0].hash, before[0].hash);
    }
}
