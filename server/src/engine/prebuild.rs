//! Snapshot and patch frames built ahead of the streaming loop, on the
//! workers. The loop (`stream.rs`) then finds them in the snapshot cache
//! and only sends: the engine thread no longer generates, meshes and
//! compresses chunks one after another for joining sessions.
//!
//! A tick plans, for each session whose batch stopped at a frame not
//! built, the frames it is due next; loads what the store holds;
//! generates each missing neighbour once, in parallel, and meshes; then
//! builds the frames in parallel. How many it plans follows what a frame
//! has cost lately, so that building takes about the tick's streaming
//! time (`[engine] stream_us`).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::Bytes;
use rayon::prelude::*;
use rustc_hash::FxHashSet;
use strata_protocol::WorldUpdate;
use strata_terrain::{Chunk, ChunkPos};
use tracing::error;

use super::fanout::encode_update;
use super::frame_cache::FrameKey;
use super::stream::{frame_update, SNAPSHOT_ERRORS};
use super::unreadable::near_any;
use super::Engine;
use crate::metrics as m;
use crate::sequencer::residency::with_neighbours;

/// Most frames planned for one session per tick.
pub const PREBUILD_PER_SESSION: usize = 32;
/// Queued chunks looked at per session when planning (most need no build:
/// an unmodified chunk goes as a one-line `Generated`).
pub const PLAN_SCAN_PER_SESSION: usize = 1024;
/// Most frames built ahead in one tick.
pub const MAX_PREBUILD_FRAMES: usize = 1024;
/// The first guess at a frame's wall time, before any was measured.
const FIRST_GUESS_US: f64 = 100.0;
/// Weight of the newest tick in the running average.
const NEWEST_WEIGHT: f64 = 0.25;

/// What building a frame ahead has cost lately: wall time of a tick's
/// building over its frames (the workers' parallelism included).
#[derive(Debug, Clone, Copy)]
pub struct PrebuildCost {
    wall_us_per_frame: f64,
}

impl Default for PrebuildCost {
    fn default() -> Self {
        Self {
            wall_us_per_frame: FIRST_GUESS_US,
        }
    }
}

impl PrebuildCost {
    /// Frames that fit in `budget_us`: at least one per worker, at most
    /// [`MAX_PREBUILD_FRAMES`].
    pub fn frames_within(&self, budget_us: u64, workers: usize) -> usize {
        let fit = budget_us as f64 / self.wall_us_per_frame;
        (fit as usize).clamp(workers.max(1), MAX_PREBUILD_FRAMES)
    }

    /// Folds in a tick that built `frames` in `took`.
    pub fn record(&mut self, took: Duration, frames: usize) {
        if frames == 0 {
            return;
        }
        let per = (took.as_secs_f64() * 1e6 / frames as f64).max(1.0);
        self.wall_us_per_frame += NEWEST_WEIGHT * (per - self.wall_us_per_frame);
    }
}

/// The frames a tick will build ahead: distinct, in the order planned, at
/// most a cap.
#[derive(Debug)]
pub struct Due {
    cap: usize,
    keys: Vec<FrameKey>,
    seen: FxHashSet<FrameKey>,
}

impl Due {
    fn new(cap: usize) -> Self {
        Self {
            cap,
            keys: Vec::new(),
            seen: FxHashSet::default(),
        }
    }

    /// Adds `key` unless it is planned already; false once full.
    fn add(&mut self, key: FrameKey) -> bool {
        if self.is_full() {
            return false;
        }
        if self.seen.insert(key) {
            metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "miss").increment(1);
            self.keys.push(key);
        }
        true
    }

    pub fn contains(&self, key: FrameKey) -> bool {
        self.seen.contains(&key)
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    pub fn is_full(&self) -> bool {
        self.keys.len() >= self.cap
    }
}

impl Engine {
    /// An empty plan, as large as the tick's streaming time allows at what
    /// frames have cost lately.
    pub(super) fn prebuild_plan(&self) -> Due {
        let workers = self.pool.current_num_threads();
        Due::new(
            self.prebuild_cost
                .frames_within(self.cfg.stream_us, workers),
        )
    }

    /// Plans the frames session `id` is due next that need building: from
    /// the front of its queue, [`PREBUILD_PER_SESSION`] at most, looking at
    /// [`PLAN_SCAN_PER_SESSION`] chunks at most.
    pub(super) fn plan_frames(&self, id: u64, due: &mut Due) {
        let Some(p) = self.peers.get(&id).filter(|_| !due.is_full()) else {
            return;
        };
        let mut taken = 0;
        for pos in p.pending.iter().take(PLAN_SCAN_PER_SESSION) {
            if taken == PREBUILD_PER_SESSION {
                return;
            }
            if !p.interest.covers(pos) {
                continue;
            }
            let key = self.frame_key(pos, p.wants_full(pos));
            if !self.needs_building(key) {
                continue;
            }
            if !due.add(key) {
                return;
            }
            taken += 1;
        }
    }

    /// Builds the frames of `due` on the workers and puts them in the
    /// snapshot cache. False when the store failed (not a bad record: the
    /// store itself), and nothing was built.
    pub(super) fn prebuild_frames(&mut self, due: &Due) -> bool {
        let began = Instant::now();
        // Frames that read a chunk found unreadable lately wait for its
        // retry (`unreadable.rs`): the engine thread reports them.
        let mut due: Vec<FrameKey> = due
            .keys
            .iter()
            .copied()
            .filter(|k| !self.unreadable.blocks(k.0, began))
            .collect();
        let mut chunks: Vec<ChunkPos> = due.iter().map(|k| k.0).collect();
        chunks.sort_unstable();
        chunks.dedup();
        let mut around: Vec<ChunkPos> = chunks.iter().flat_map(|&p| with_neighbours(p)).collect();
        around.sort_unstable();
        around.dedup();
        // A bad record costs the frames that need it, not the tick's.
        let bad = match self.make_resident_readable(&around, began) {
            Ok(bad) => bad,
            Err(e) => {
                crate::log_every::store_error("read", "cannot load chunks to stream", &e);
                return false;
            }
        };
        let found_bad = !bad.is_empty();
        if found_bad {
            due.retain(|k| !near_any(k.0, &bad));
            chunks.retain(|&p| !near_any(p, &bad));
        }
        let due = &due;
        let pool = self.pool.clone();
        let seq = &mut self.seq;
        pool.install(|| seq.prepare_meshes(&chunks));
        // A chunk is planned at most once as a patch.
        let patched: Vec<ChunkPos> = due.iter().filter(|k| !k.2).map(|k| k.0).collect();
        let generator = self.seq.world().generator().clone();
        let patch_bases = &mut self.patch_bases;
        let bases = pool.install(|| patch_bases.get_many(&patched, &*generator));
        let bases: HashMap<ChunkPos, Arc<Chunk>> = patched.into_iter().zip(bases).collect();
        let (world, collision) = (self.seq.world(), self.seq.collision());
        let build = |&key: &FrameKey| -> Option<(FrameKey, WorldUpdate, Bytes)> {
            let (pos, version, full) = key;
            let chunk = world.peek(pos)?;
            let mesh_hash = collision.get(pos, chunk.version)?.hash;
            let base = match full {
                true => None,
                false => Some(&**bases.get(&pos)?),
            };
            match frame_update(pos, version, mesh_hash, &chunk.chunk, base) {
                Ok(update) => {
                    let frame = encode_update(&update);
                    Some((key, update, frame))
                }
                Err(e) => {
                    if let Some(folded) = SNAPSHOT_ERRORS.event() {
                        error!(error = %e, ?pos, folded, "cannot build a snapshot");
                    }
                    None
                }
            }
        };
        let built: Vec<(FrameKey, WorldUpdate, Bytes)> =
            pool.install(|| due.par_iter().filter_map(build).collect());
        metrics::counter!(m::SNAPSHOT_FRAMES_BUILT, "on" => "workers")
            .increment(built.len() as u64);
        self.snapshots
            .make_room(built.iter().map(|(key, _, _)| key));
        for (key, update, frame) in built {
            self.snapshots.put(key, update, frame);
        }
        // Finding bad records is not a frame's usual cost: the plan's
        // size is not judged by it.
        if !found_bad {
            self.prebuild_cost.record(began.elapsed(), due.len());
        }
        true
    }

    /// Whether sending `key` would build something: not a `Generated`
    /// line, and not cached with its mesh (whose hash it carries) current.
    pub(super) fn needs_building(&self, key: FrameKey) -> bool {
        let (_, version, full) = key;
        (version > 0 || full) && self.cached_frame_mesh(key).is_none()
    }

    /// The hash of the current mesh of a cached frame's chunk, if both are
    /// cached. The world need not hold the chunk: the mesh cache drops a
    /// chunk's mesh whenever the chunk or a neighbour changes.
    pub(super) fn cached_frame_mesh(&self, key: FrameKey) -> Option<u64> {
        let (pos, version, _) = key;
        let mesh = self.seq.collision().lookup(pos, version)?;
        self.snapshots.has(key).then_some(mesh.hash)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_what_the_budget_held_lately_within_bounds() {
        let mut cost = PrebuildCost::default();
        assert_eq!(cost.frames_within(2_000, 2), 20, "the first guess");
        assert_eq!(cost.frames_within(1, 4), 4, "a frame per worker at least");
        assert_eq!(cost.frames_within(u64::MAX, 1), MAX_PREBUILD_FRAMES);
        // Frames turn out to take 1 ms each: the plan shrinks towards 2.
        for _ in 0..40 {
            cost.record(Duration::from_millis(10), 10);
        }
        assert_eq!(cost.frames_within(2_000, 1), 2);
        cost.record(Duration::from_millis(5), 0);
        assert_eq!(
            cost.frames_within(2_000, 1),
            2,
            "an empty tick says nothing"
        );
        // And grows again when they get cheap.
        for _ in 0..40 {
            cost.record(Duration::from_micros(100), 10);
        }
        assert!((195..=200).contains(&cost.frames_within(2_000, 1)));
    }

    #[test]
    fn a_plan_holds_each_frame_once_up_to_its_cap() {
        let key = |x: i32| (ChunkPos::new(x, 0, 0), 1, false);
        let mut due = Due::new(2);
        assert!(due.is_empty());
        assert!(due.add(key(1)));
        assert!(due.add(key(1)), "planned already: not full");
        assert!(due.add(key(2)));
        assert!(!due.add(key(3)) && due.is_full(), "full");
        assert_eq!(due.keys, [key(1), key(2)]);
        assert!(due.contains(key(2)) && !due.contains(key(3)));
    }
}
