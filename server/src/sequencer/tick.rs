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
use crate::collision::CollisionCache;
use strata_terrain::Chunk;

/// Where a change's mesh hash goes once the meshes are built.
struct MeshJob {
    applied: usize,
    change: usize,
}

impl Sequencer {
    /// Applies up to `max_edits_per_tick` queued edits in order. Each gets
    /// the next sequence number; each changed chunk gets a delta from its
    /// previous version, so two edits on one chunk make a two-step chain.
    /// `now_ms` stamps the edit-log entries.
    pub fn tick(&mut self, now_ms: u64) -> TickOutput {
        let mut out = TickOutput::default();
        let mut jobs: Vec<(ChunkPos, u64, Neighborhood)> = Vec::new();
        let mut slots: Vec<MeshJob> = Vec::new();
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
            let seq = self.next_seq;
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
                self.collision.invalidate_around(c.pos);
                self.residency.mark_present(c.pos);
                // Neighbours feed the mesh apron; they are resident (submit checked).
                self.world.load(with_neighbours(c.pos));
                jobs.push((
                    c.pos,
                    c.to_version,
                    Neighborhood::from_world(&self.world, c.pos),
                ));
                slots.push(MeshJob {
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
            });
        }
        let mut meshes = CollisionCache::mesh_chunks(&jobs);
        let mut current = still_current(&jobs);
        // Clients compare mesh hashes at the tick's end: a chunk whose
        // neighbour changed later in the tick is meshed again from the world
        // as it now stands (its last change carries that hash).
        let mut last: BTreeMap<ChunkPos, usize> = BTreeMap::new();
        for (i, (pos, _, _)) in jobs.iter().enumerate() {
            last.insert(*pos, i);
        }
        let stale: Vec<usize> = last.into_values().filter(|&i| !current[i]).collect();
        let redo: Vec<_> = stale
            .iter()
            .map(|&i| {
                let (pos, version, _) = &jobs[i];
                (*pos, *version, Neighborhood::from_world(&self.world, *pos))
            })
            .collect();
        for (&i, mesh) in stale.iter().zip(CollisionCache::mesh_chunks(&redo)) {
            meshes[i] = mesh;
            current[i] = true;
        }
        for ((slot, mesh), keep) in slots.iter().zip(meshes).zip(current) {
            out.applied[slot.applied].changes[slot.change].mesh_hash = mesh.hash;
            if keep {
                self.collision.insert(mesh);
            }
        }
        out.batch.chunks = finals.into_iter().map(|(p, (v, c))| (p, v, c)).collect();
        out.batch.last_seq = self.last_seq();
        out
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
