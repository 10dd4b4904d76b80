//! `Sequencer::tick`: apply queued edits in order, number them, build deltas.

use std::collections::hash_map::Entry;
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::sync::Arc;
use std::time::Instant;

use strata_protocol::RejectReason;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::ChunkPos;

use rayon::prelude::*;
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, VoxelBox, World};

use super::batch::*;
use super::reach::TickReach;
use super::regions::{self, RegionSpan};
use super::residency::{edit_reads, with_neighbours};
use super::{LogEntry, Queued, Sequencer};
use crate::collision::{Base, CollisionCache, CollisionMesh, LayerCounts, MeshJob};
use crate::mesh_buffers;

/// Where a change's mesh hash comes from once the meshes are built.
#[derive(Debug)]
struct MeshSlot {
    applied: usize,
    change: usize,
    job: usize,
}

/// The collision meshes one tick's changes need: one per changed chunk, of
/// its state at the tick's end, which is what clients compare at `TickEnd`
/// (every change of the chunk in the tick carries that mesh's hash), and
/// one per cached neighbour mesh the changes made stale (`rewarm`).
/// Building them is pure ([`Self::build`]), so the shell runs it on the
/// rayon pool while the store commits, then hands the result to
/// [`Sequencer::finish_tick`].
#[derive(Debug, Default)]
pub struct PendingMeshes {
    jobs: Vec<MeshJob>,
    slots: Vec<MeshSlot>,
    /// How many of `jobs` (the last ones) rewarm stale neighbour meshes.
    rewarmed: usize,
}

/// Meshes built from a [`PendingMeshes`].
#[derive(Debug)]
pub struct BuiltMeshes {
    meshes: Vec<CollisionMesh>,
    slots: Vec<MeshSlot>,
    /// How many of `meshes` (the last ones) are rewarms.
    rewarmed: usize,
    /// Cell layers meshed, and copied from the meshes built before.
    pub layers: LayerCounts,
}

impl PendingMeshes {
    pub fn is_empty(&self) -> bool {
        self.jobs.is_empty()
    }

    /// Meshes of changed chunks.
    pub fn changed(&self) -> usize {
        self.jobs.len() - self.rewarmed
    }

    /// Meshes of unchanged neighbours rebuilt because a change made them stale.
    pub fn rewarmed(&self) -> usize {
        self.rewarmed
    }

    /// Meshes every job in parallel on the current rayon pool; with no
    /// jobs, touches no pool (rayon would start its global one).
    pub fn build(self) -> BuiltMeshes {
        let (meshes, layers) = if self.jobs.is_empty() {
            (Vec::new(), LayerCounts::default())
        } else {
            CollisionCache::mesh_chunks(&self.jobs)
        };
        mesh_buffers::recycle(self.jobs.into_iter().map(|j| j.nb));
        BuiltMeshes {
            meshes,
            slots: self.slots,
            rewarmed: self.rewarmed,
            layers,
        }
    }
}

impl Sequencer {
    /// Applies up to `max_edits_per_tick` queued edits in order. Each gets
    /// the next sequence number; each changed chunk gets a delta from its
    /// previous version, so two edits on one chunk make a two-step chain.
    /// `now_ms` stamps the edit-log entries. Builds the collision meshes
    /// on this thread; the engine uses [`Self::tick_apply`] instead.
    pub fn tick(&mut self, now_ms: u64) -> TickOutput {
        let (mut out, pending) = self.tick_apply(now_ms);
        self.finish_tick(&mut out, pending.build(), &HashSet::new());
        out
    }

    /// [`Self::tick`] without the meshes: every `mesh_hash` is 0 until
    /// [`Self::finish_tick`] gets the built [`PendingMeshes`].
    ///
    /// The edits are grouped into lanes of joined regions (`regions.rs`);
    /// each lane applies its edits in queue order to its own chunks, moved
    /// out of the world, on the current rayon pool. Seqs are then given in
    /// queue order, so the output is the same for any number of threads.
    /// A lane holds what its edits read and write, not their mesh aprons:
    /// with the aprons, neighbouring regions' edits joined into one lane
    /// so often that thousands of players applied on about one thread.
    /// The meshes' neighbourhoods are copied once every lane is back.
    pub fn tick_apply(&mut self, now_ms: u64) -> (TickOutput, PendingMeshes) {
        let started = Instant::now();
        self.prune_limits(now_ms);
        // No seq past the limit (a cluster node's block's end, or
        // `MAX_SEQ`, which only a stored seq near it, hostile bytes, comes
        // near): the rest wait, and the queue fills.
        let seqs_left = self.seqs_left();
        let take = self
            .queue
            .len()
            .min(self.cfg.max_edits_per_tick)
            .min(usize::try_from(seqs_left).unwrap_or(usize::MAX));
        let queued: Vec<Queued> = self.queue.drain(..take).collect();
        let ctx = strata_terrain::EditContext {
            materials: &self.materials,
            structures: &self.structures,
        };
        let side = self.cfg.region_chunks;
        // What applying each edit reads: its box grown by the read margin.
        // An invalid edit reads nothing.
        let footprints: Vec<Option<VoxelBox>> = queued
            .iter()
            .map(|q| {
                let e = &q.request.edit;
                e.validate(&ctx)
                    .ok()
                    .map(|b| edit_reads(&b, e.read_margin()))
            })
            .collect();
        let spans: Vec<Option<RegionSpan>> = footprints
            .iter()
            .map(|f| f.map(|b| RegionSpan::of_chunks(b.min.chunk(), b.max.chunk(), side)))
            .collect();
        let parts: Vec<(Vec<usize>, World)> = regions::lanes(&spans)
            .into_iter()
            .map(|members| {
                let chunks: Vec<ChunkPos> = members
                    .iter()
                    .filter_map(|&i| footprints[i])
                    .flat_map(|b| b.chunks())
                    .collect();
                let part = self.world.extract(chunks);
                (members, part)
            })
            .collect();
        let prepared = Instant::now();
        let lanes: Vec<Lane> = if parts.len() > 1 {
            parts
                .into_par_iter()
                .map(|(members, part)| Lane::run(&queued, members, part, &ctx))
                .collect()
        } else {
            parts
                .into_iter()
                .map(|(members, part)| Lane::run(&queued, members, part, &ctx))
                .collect()
        };
        let count = lanes.len();
        let laned = Instant::now();
        let (mut out, pending) = self.merge(queued, lanes, now_ms);
        out.lanes = count;
        out.split = ApplySplit {
            prepare: prepared - started,
            lanes: laned - prepared,
            merge: laned.elapsed(),
            ..ApplySplit::default()
        };
        (out, pending)
    }

    /// Numbers the lanes' edits in queue order and gathers the tick's
    /// output, commit batch and mesh jobs; puts the lanes' chunks back.
    fn merge(
        &mut self,
        queued: Vec<Queued>,
        lanes: Vec<Lane>,
        now_ms: u64,
    ) -> (TickOutput, PendingMeshes) {
        let mut out = TickOutput::default();
        let mut results: Vec<Option<LaneResult>> = (0..queued.len()).map(|_| None).collect();
        let mut lane_slots = Vec::new();
        let mut stored = Vec::new();
        let mut generated = Vec::new();
        let mut finals: BTreeMap<ChunkPos, (u64, Arc<Chunk>)> = BTreeMap::new();
        let mut versions: BTreeMap<ChunkPos, u64> = BTreeMap::new();
        for lane in lanes {
            for (i, r) in lane.results {
                results[i] = Some(r);
            }
            lane_slots.extend(lane.slots);
            finals.extend(lane.finals);
            generated.extend(lane.generated);
            stored.extend(lane.stored);
            versions.extend(lane.versions);
            self.world.absorb(lane.world);
        }
        let changed: BTreeSet<ChunkPos> = versions.keys().copied().collect();
        let reach = TickReach::of(results.iter().filter_map(|r| match r {
            Some(Ok((bbox, changes))) => Some((*bbox, changes.as_slice())),
            _ => None,
        }));
        let mut jobs = self.changed_jobs(&versions, &reach);
        let job_of: HashMap<ChunkPos, usize> =
            versions.keys().enumerate().map(|(j, &p)| (p, j)).collect();
        let job_slots = lane_slots
            .into_iter()
            .map(|(i, c, pos)| (i, c, job_of[&pos]));
        let mut applied_at = vec![usize::MAX; queued.len()];
        // Cached meshes the tick's changes made stale.
        let mut dropped: BTreeMap<ChunkPos, Base> = BTreeMap::new();
        for (i, (q, r)) in queued.into_iter().zip(results).enumerate() {
            let (bbox, changes) = match r.expect("every queued edit is in one lane") {
                Ok(done) => done,
                Err(message) => {
                    out.rejected.push(RejectedEdit {
                        session_id: q.session_id,
                        client_edit_id: q.request.client_edit_id,
                        reason: RejectReason::Invalid { message },
                    });
                    continue;
                }
            };
            let seq = self.next_seq;
            self.next_seq += 1;
            for c in &changes {
                for m in self.collision.invalidate_touched(c.pos, bbox) {
                    dropped.insert(m.0.pos, m);
                }
                self.residency.mark_present(c.pos);
            }
            out.batch.entries.push(LogEntry {
                seq,
                player: q.player.clone(),
                time_ms: now_ms,
                edit: q.request.edit.clone(),
                changes: changes.iter().map(|c| (c.pos, c.to_version)).collect(),
            });
            applied_at[i] = out.applied.len();
            out.applied.push(AppliedEdit {
                seq,
                session_id: q.session_id,
                client_edit_id: q.request.client_edit_id,
                player: q.player,
                edit: q.request.edit,
                changes,
                queued_at: q.queued_at,
            });
        }
        // The cached meshes the changes did not reach are right for the
        // chunks' new versions.
        for (&pos, &version) in &versions {
            self.collision.moved_on(pos, version);
        }
        let slots = job_slots
            .into_iter()
            .map(|(i, change, job)| MeshSlot {
                applied: applied_at[i],
                change,
                job,
            })
            .collect();
        let before = jobs.len();
        self.rewarm(dropped, &changed, &reach, &mut jobs);
        let rewarmed = jobs.len() - before;
        out.batch.chunks = finals.into_iter().map(|(p, (v, c))| (p, v, c)).collect();
        out.batch.deltas = stored;
        // In position order, as `chunks`, whatever the lanes.
        generated.sort_unstable_by_key(|d: &ChunkDelta| d.pos);
        out.batch.generated = generated;
        out.batch.last_seq = self.last_seq();
        (
            out,
            PendingMeshes {
                jobs,
                slots,
                rewarmed,
            },
        )
    }

    /// One mesh job per changed chunk (in `versions` order), of the world as
    /// the tick leaves it: every lane's changes are in, neighbours included.
    /// Missing neighbours are generated first (on the pool when several),
    /// then the neighbourhoods are copied in parallel. Each job's base is
    /// the chunk's cached mesh, if any (`CollisionMesh::rebuild`).
    fn changed_jobs(
        &mut self,
        versions: &BTreeMap<ChunkPos, u64>,
        reach: &TickReach,
    ) -> Vec<MeshJob> {
        let missing: BTreeSet<ChunkPos> = versions
            .keys()
            .flat_map(|&p| with_neighbours(p))
            .filter(|&p| self.world.peek(p).is_none())
            .collect();
        self.generate_into_world(missing.into_iter().collect());
        let (world, cache) = (&self.world, &self.collision);
        let copy = |(&pos, &version): (&ChunkPos, &u64)| {
            reach.job(world, pos, version, cache.peek_base(pos))
        };
        if versions.len() > 1 {
            versions.par_iter().map(copy).collect()
        } else {
            versions.iter().map(copy).collect()
        }
    }

    /// Adds a job for each unchanged chunk whose cached mesh the tick made
    /// stale (its apron changed): otherwise the next line-of-sight check
    /// through it would mesh it before its batch applies, not while a
    /// commit runs. (Rebuilding only meshes looked up since they were
    /// built cut these by 63 % but moved the work to the premesher and to
    /// on-demand builds: see BENCHMARKS.md, session 31.)
    /// Only chunks whose 27 chunks are all resident: anything else would be
    /// meshed from generated stand-ins. (Every such chunk is within reach of
    /// the edit's author, so filtering by players' eyes keeps them all.)
    /// The neighbourhoods are copied on the current rayon pool when there
    /// are several: the world is only read here.
    fn rewarm(
        &self,
        dropped: BTreeMap<ChunkPos, Base>,
        changed: &BTreeSet<ChunkPos>,
        reach: &TickReach,
        jobs: &mut Vec<MeshJob>,
    ) {
        let stale: Vec<(ChunkPos, u64, Base)> = dropped
            .into_iter()
            .filter(|&(pos, _)| {
                !changed.contains(&pos)
                    && self
                        .residency
                        .missing(&self.world, with_neighbours(pos))
                        .is_empty()
            })
            .map(|(pos, old)| (pos, self.world.peek(pos).map_or(0, |c| c.version), old))
            .collect();
        let copy = |(pos, version, old): &(ChunkPos, u64, Base)| {
            reach.job(&self.world, *pos, *version, Some(old.clone()))
        };
        if stale.len() > 1 {
            jobs.par_extend(stale.par_iter().map(copy));
        } else {
            jobs.extend(stale.iter().map(copy));
        }
    }

    /// Fills in the mesh hashes of `out` and caches the built meshes,
    /// except those that read a chunk in `ahead` (changed since, by a tick
    /// already applied): their version keys would no longer say what they
    /// were built from.
    pub fn finish_tick(
        &mut self,
        out: &mut TickOutput,
        built: BuiltMeshes,
        ahead: &HashSet<ChunkPos>,
    ) {
        let BuiltMeshes {
            meshes,
            slots,
            rewarmed,
            ..
        } = built;
        for slot in &slots {
            out.applied[slot.applied].changes[slot.change].mesh_hash = meshes[slot.job].hash;
        }
        let first_rewarm = meshes.len() - rewarmed;
        for (i, mesh) in meshes.into_iter().enumerate() {
            if ahead.is_empty() || !with_neighbours(mesh.pos).any(|p| ahead.contains(&p)) {
                if i < first_rewarm {
                    self.collision.insert(mesh);
                } else {
                    self.collision.insert_rewarmed(mesh);
                }
            }
        }
    }
}

/// An applied edit's box and chunk updates, or why it failed.
type LaneResult = Result<(VoxelBox, Vec<ChunkUpdate>), String>;

/// The union of two increasing lists, increasing, without repeats.
fn merge_sorted(a: &[u16], b: &[u16]) -> Vec<u16> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (x, y) = (a[i], b[j]);
        out.push(x.min(y));
        i += usize::from(x <= y);
        j += usize::from(y <= x);
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// A changed chunk's state before its first change in a lane.
struct FirstChange {
    from_version: u64,
    base_hash: u64,
    before: Arc<Chunk>,
    /// Every voxel the lane's changes of the chunk so far changed
    /// (increasing): where `before` and the chunk's last state may differ.
    voxels: Vec<u16>,
    /// The change's delta while it is the chunk's only one.
    only: Option<ChunkDelta>,
}

/// One lane's edits applied in order to its own chunks.
struct Lane {
    /// By queue index.
    results: Vec<(usize, LaneResult)>,
    /// Each changed chunk's final version.
    versions: BTreeMap<ChunkPos, u64>,
    /// Each change's (queue index, change index, chunk).
    slots: Vec<(usize, usize, ChunkPos)>,
    /// Final version and state of each changed chunk the store does not
    /// hold yet (version 0 before the tick): stored whole, the others as
    /// their deltas.
    finals: BTreeMap<ChunkPos, (u64, Arc<Chunk>)>,
    /// The same chunks' change from their generated state to `finals`.
    generated: Vec<ChunkDelta>,
    /// The store's record of every other changed chunk: one delta from its
    /// version before the lane to its last, in position order.
    stored: Vec<ChunkDelta>,
    /// The lane's chunks, to be put back in the world.
    world: World,
}

impl Lane {
    fn run(
        queued: &[Queued],
        members: Vec<usize>,
        mut world: World,
        ctx: &strata_terrain::EditContext<'_>,
    ) -> Lane {
        let mut lane = Lane {
            results: Vec::with_capacity(members.len()),
            versions: BTreeMap::new(),
            slots: Vec::new(),
            finals: BTreeMap::new(),
            generated: Vec::new(),
            stored: Vec::new(),
            world: World::new(world.generator().clone()),
        };
        let mut changed: Vec<(usize, usize, ChunkPos)> = Vec::new();
        let mut versions: BTreeMap<ChunkPos, u64> = BTreeMap::new();
        let mut new_in_store: BTreeSet<ChunkPos> = BTreeSet::new();
        // Each chunk's hash after its last change in this lane: the base
        // hash of its next change, which need not be hashed again.
        let mut hashes: HashMap<ChunkPos, u64> = HashMap::new();
        let mut firsts: HashMap<ChunkPos, FirstChange> = HashMap::new();
        for i in members {
            let edit = &queued[i].request.edit;
            let outcome = match edit.apply(&mut world, ctx) {
                Ok(o) => o,
                Err(e) => {
                    lane.results.push((i, Err(e.to_string())));
                    continue;
                }
            };
            let mut changes = Vec::with_capacity(outcome.changed.len());
            for c in outcome.changed {
                let delta = {
                    let now = world.peek(c.pos).map(|v| &v.chunk);
                    let now = now.expect("apply leaves changed chunks loaded");
                    let base_hash = match hashes.get(&c.pos) {
                        Some(&h) => h,
                        None => chunk_hash(&c.before),
                    };
                    // `apply` raised the version, so the order check cannot fail.
                    ChunkDelta::encode_changed(
                        c.pos,
                        c.from_version,
                        c.to_version,
                        &c.before,
                        base_hash,
                        now,
                        &c.voxels,
                    )
                    .expect("apply raises the version")
                };
                hashes.insert(c.pos, delta.target_hash);
                match firsts.entry(c.pos) {
                    Entry::Occupied(mut first) => {
                        let first = first.get_mut();
                        first.only = None;
                        first.voxels = merge_sorted(&first.voxels, &c.voxels);
                    }
                    Entry::Vacant(slot) => {
                        slot.insert(FirstChange {
                            from_version: c.from_version,
                            base_hash: delta.base_hash,
                            before: c.before,
                            voxels: c.voxels,
                            only: Some(delta.clone()),
                        });
                    }
                }
                // Meshed once, after the lane's last edit.
                changed.push((i, changes.len(), c.pos));
                versions.insert(c.pos, c.to_version);
                if c.from_version == 0 {
                    new_in_store.insert(c.pos);
                }
                changes.push(ChunkUpdate {
                    pos: c.pos,
                    from_version: c.from_version,
                    to_version: c.to_version,
                    delta,
                    mesh_hash: 0,
                });
            }
            lane.results.push((i, Ok((outcome.bbox, changes))));
        }
        // The store's copy of each new chunk's final state. Meshes are
        // built once every lane is back (`Sequencer::changed_jobs`).
        for (&pos, &version) in &versions {
            let state = world.peek(pos).expect("changed chunks are loaded");
            let first = firsts
                .remove(&pos)
                .expect("every changed chunk had a first change");
            // A chunk changed several times is stored as one delta across
            // them all (one record a tick, whatever the edits per chunk),
            // built from the voxels any of them changed.
            let delta = match first.only {
                Some(delta) => delta,
                None => ChunkDelta::encode_changed(
                    pos,
                    first.from_version,
                    version,
                    &first.before,
                    first.base_hash,
                    &state.chunk,
                    &first.voxels,
                )
                .expect("the lane raised the version"),
            };
            if new_in_store.contains(&pos) {
                // Whole, or from its generated state where the store can.
                lane.finals.insert(pos, (version, state.chunk.clone()));
                lane.generated.push(delta);
            } else {
                lane.stored.push(delta);
            }
        }
        lane.versions = versions;
        lane.slots = changed;
        lane.world = world;
        lane
    }
}

#[cfg(test)]
mod tests {
    use super::merge_sorted;

    #[test]
    fn merged_lists_are_the_sorted_union() {
        assert_eq!(merge_sorted(&[], &[]), Vec::<u16>::new());
        assert_eq!(merge_sorted(&[1, 5, 9], &[]), [1, 5, 9]);
        assert_eq!(merge_sorted(&[], &[0, 65535]), [0, 65535]);
        assert_eq!(
            merge_sorted(&[1, 5, 9], &[2, 5, 10, 11]),
            [1, 2, 5, 9, 10, 11]
        );
        assert_eq!(merge_sorted(&[3, 4], &[3, 4]), [3, 4]);
    }
}
