//! `Sequencer::tick`: apply queued edits in order, number them, build deltas.

use std::collections::BTreeMap;

use strata_protocol::RejectReason;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::mesh::Neighborhood;
use strata_terrain::ChunkPos;

use super::batch::*;
use super::residency::with_neighbours;
use super::LogEntry;
use super::Sequencer;
use crate::collision::{CollisionCache, CollisionMesh};
use strata_terrain::Chunk;

/// Where a change's mesh hash goes once the meshes are built.
#[derive(Debug)]
struct MeshSlot {
    applied: usize,
    change: usize,
}

/// The collision meshes one tick's changes need. Building them is pure
/// ([`Self::build`]), so the shell runs it on the rayon pool while the
/// store commits, then hands the result to [`Sequencer::finish_tick`].
#[derive(Debug, Default)]
pub struct PendingMeshes {
    jobs: Vec<(ChunkPos, u64, Neighborhood)>,
    slots: Vec<MeshSlot>,
    /// Whether each job's mesh matches the world at the tick's end.
    keep: Vec<bool>,
}

/// Meshes built from a [`PendingMeshes`].
#[derive(Debug)]
pub struct BuiltMeshes {
    meshes: Vec<CollisionMesh>,
    keep: Vec<bool>,
    slots: Vec<MeshSlot>,
}

impl PendingMeshes {
    pub fn is_empty(&self) -> bool {
        self.jobs.is_empty()
    }

    /// Meshes every job in parallel on the current rayon pool.
    pub fn build(self) -> BuiltMeshes {
        BuiltMeshes {
            meshes: CollisionCache::mesh_chunks(&self.jobs),
            keep: self.keep,
            slots: self.slots,
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
        self.finish_tick(&mut out, pending.build());
        out
    }

    /// [`Self::tick`] without the meshes: every `mesh_hash` is 0 until
    /// [`Self::finish_tick`] gets the built [`PendingMeshes`].
    pub fn tick_apply(&mut self, now_ms: u64) -> (TickOutput, PendingMeshes) {
        self.prune_limits(now_ms);
        let mut out = TickOutput::default();
        let mut jobs: Vec<(ChunkPos, u64, Neighborhood)> = Vec::new();
        let mut slots: Vec<MeshSlot> = Vec::new();
        let mut finals: BTreeMap<ChunkPos, (u64, Chunk)> = BTreeMap::new();
        let take = self.queue.len().min(self.cfg.max_edits_per_tick);
        for q in self.queue.drain(..take).collect::<Vec<_>>() {
            let ctx = strata_terrain::EditContext {
                materials: &self.materials,
                structures: &self.structures,
            };
            let outcome = match q.request.edit.apply(&mut self.world, &ctx) {
                Ok(o) => o,
                Err(e) => {
                    out.rejected.push(RejectedEdit {
                        session_id: q.session_id,
                        client_edit_id: q.request.client_edit_id,
                        reason: RejectReason::Invalid {
                            message: e.to_string(),
                        },
                    });
                    continue;
                }
            };
            let (seq, bbox) = (self.next_seq, outcome.bbox);
            self.next_seq += 1;
            let mut changes = Vec::with_capacity(outcome.changed.len());
            for c in outcome.changed {
                let new_chunk = self
                    .world
                    .peek(c.pos)
                    .map(|v| v.chunk.clone())
                    .unwrap_or_default();
                // `apply` raised the version, so the order check cannot fail.
                let delta =
                    ChunkDelta::encode(c.pos, c.from_version, c.to_version, &c.before, &new_chunk)
                        .expect("apply raises the version");
                self.collision.invalidate_touched(c.pos, bbox);
                self.residency.mark_present(c.pos);
                // Neighbours feed the mesh apron; they are resident (submit checked).
                self.world.load(with_neighbours(c.pos));
                jobs.push((
                    c.pos,
                    c.to_version,
                    Neighborhood::from_world(&self.world, c.pos),
                ));
                slots.push(MeshSlot {
                    applied: out.applied.len(),
                    change: changes.len(),
                });
                finals.insert(c.pos, (c.to_version, new_chunk.clone()));
                changes.push(ChunkUpdate {
                    pos: c.pos,
                    from_version: c.from_version,
                    to_version: c.to_version,
                    delta,
                    new_chunk,
                    mesh_hash: 0,
                });
            }
            out.batch.entries.push(LogEntry {
                seq,
                player: q.player.clone(),
                time_ms: now_ms,
                edit: q.request.edit.clone(),
                changes: changes.iter().map(|c| (c.pos, c.to_version)).collect(),
            });
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
        // Clients compare mesh hashes at the tick's end: a chunk whose
        // neighbour changed later in the tick is meshed from the world as it
        // now stands (its last change carries that hash).
        let mut keep = still_current(&jobs);
        let last: BTreeMap<ChunkPos, usize> =
            jobs.iter().enumerate().map(|(i, j)| (j.0, i)).collect();
        for i in last.into_values() {
            if !keep[i] {
                jobs[i].2 = Neighborhood::from_world(&self.world, jobs[i].0);
                keep[i] = true;
            }
        }
        out.batch.chunks = finals.into_iter().map(|(p, (v, c))| (p, v, c)).collect();
        out.batch.last_seq = self.last_seq();
        (out, PendingMeshes { jobs, slots, keep })
    }

    /// Fills in the mesh hashes of `out` and caches the meshes that still
    /// match the world.
    pub fn finish_tick(&mut self, out: &mut TickOutput, built: BuiltMeshes) {
        let BuiltMeshes {
            meshes,
            keep,
            slots,
        } = built;
        for ((slot, mesh), keep) in slots.iter().zip(meshes).zip(keep) {
            out.applied[slot.applied].changes[slot.change].mesh_hash = mesh.hash;
            if keep {
                self.collision.insert(mesh);
            }
        }
    }
}

/// Whether each job's mesh still matches the world at the end of the tick:
/// no later change in the tick touched its chunk or a neighbour.
fn still_current(jobs: &[(ChunkPos, u64, Neighborhood)]) -> Vec<bool> {
    let mut seen: std::collections::HashSet<ChunkPos> = std::collections::HashSet::new();
    let mut keep = vec![false; jobs.len()];
    for (i, (pos, _, _)) in jobs.iter().enumerate().rev() {
        keep[i] = !with_neighbours(*pos).any(|n| seen.contains(&n));
        seen.insert(*pos);
    }
    keep
}
