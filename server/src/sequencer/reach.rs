//! What a tick's changes reach of each mesh it rebuilds.
//!
//! A changed chunk and each neighbour whose apron a change touched are
//! meshed again against the mesh the change made stale. Which sample layers
//! (local z) of the neighbourhood differ from that mesh's is known without
//! looking at the voxels when the mesh was copied from the very versions
//! the tick started from: then only the tick's edit boxes can hold a
//! difference. Such a job copies and fingerprints only the layers its
//! re-mesh reads (`remesh_reads`), not all 35; any other job copies the
//! whole neighbourhood and compares fingerprints, as before.

use std::collections::HashMap;
use std::ops::RangeInclusive;

use std::sync::Arc;

use strata_terrain::mesh::{remesh_reads, LOCAL_MIN, LOD0_LOCAL_MAX};
use strata_terrain::{ChunkPos, VoxelBox, World, CHUNK_SIZE};

use super::batch::ChunkUpdate;
use crate::collision::{sources_of, with_sources, Base, CollisionMesh, MeshJob, Sources};
use crate::mesh_buffers;

/// The empty range of layers: no change reached the neighbourhood.
pub const NONE_REACHED: RangeInclusive<i32> = RangeInclusive::new(1, 0);

/// The tick's changes, as far as meshing against older meshes needs them.
#[derive(Debug, Default)]
pub struct TickReach {
    /// Each changed chunk's version before the tick, and the boxes of the
    /// edits that changed it: every voxel of it the tick changed lies in one.
    changed: HashMap<ChunkPos, (u64, Vec<VoxelBox>)>,
}

impl TickReach {
    /// From the tick's applied edits, in order: each one's box and changes.
    pub fn of<'a>(applied: impl IntoIterator<Item = (VoxelBox, &'a [ChunkUpdate])>) -> Self {
        let mut reach = Self::default();
        for (bbox, changes) in applied {
            for c in changes {
                // The first change of a chunk starts from its version before the tick.
                let (_, boxes) = reach
                    .changed
                    .entry(c.pos)
                    .or_insert((c.from_version, Vec::new()));
                boxes.push(bbox);
            }
        }
        reach
    }

    /// The job that meshes `pos` (at `version` in `world`) against `base`:
    /// copying only the layers its re-mesh reads when [`Self::known`] says
    /// which differ, else the whole neighbourhood.
    pub fn job(&self, world: &World, pos: ChunkPos, version: u64, base: Option<Base>) -> MeshJob {
        let sources = sources_of(world, pos);
        let known = match (&base, &sources) {
            (Some((b, Some(then))), Some(now)) => self.known(pos, b, then, now),
            _ => None,
        };
        let base: Option<Arc<CollisionMesh>> = base.map(|(b, _)| b);
        let nb = match &known {
            Some(k) if k.is_empty() => mesh_buffers::from_world_layers(world, pos, NONE_REACHED),
            Some(k) => mesh_buffers::from_world_layers(world, pos, remesh_reads(k.clone())),
            None => mesh_buffers::from_world(world, pos),
        };
        MeshJob {
            pos,
            version,
            nb,
            base,
            known,
            sources,
        }
    }

    /// The sample layers of `pos`'s neighbourhood (whose chunks are at
    /// versions `now`) that may differ from the one `base` was built from,
    /// when that is known: `base` is a mesh of `pos` right for the chunks at
    /// versions `then`, and each chunk is either at that version still or
    /// was at it when the tick started. An empty range: none differ.
    pub fn known(
        &self,
        pos: ChunkPos,
        base: &CollisionMesh,
        then: &Sources,
        now: &Sources,
    ) -> Option<RangeInclusive<i32>> {
        if base.pos != pos {
            return None;
        }
        let around = with_sources(pos);
        for i in 0..27 {
            let changed_from = around[i].and_then(|p| self.changed.get(&p)).map(|c| c.0);
            if then[i] != now[i] && changed_from != Some(then[i]) {
                // Copied from another version than the tick's start.
                return None;
            }
        }
        // The neighbourhood's LOD-0 reach, in world voxels (i64: no overflow
        // at the ends of the coordinates).
        let at = |p: ChunkPos| {
            let o = p.origin();
            [o.x, o.y, o.z].map(i64::from)
        };
        let o = at(pos);
        let (reach_lo, reach_hi) = (i64::from(LOCAL_MIN), i64::from(LOD0_LOCAL_MAX));
        let (mut first, mut last) = (i64::MAX, i64::MIN);
        for p in around.into_iter().flatten() {
            let Some((_, boxes)) = self.changed.get(&p) else {
                continue;
            };
            // A box changed `p` only inside `p`.
            let c = at(p);
            for b in boxes {
                let (bl, bh) = ([b.min.x, b.min.y, b.min.z], [b.max.x, b.max.y, b.max.z]);
                let lo: [i64; 3] =
                    std::array::from_fn(|k| i64::from(bl[k]).max(c[k]).max(o[k] + reach_lo) - o[k]);
                let hi: [i64; 3] = std::array::from_fn(|k| {
                    i64::from(bh[k])
                        .min(c[k] + i64::from(CHUNK_SIZE) - 1)
                        .min(o[k] + reach_hi)
                        - o[k]
                });
                if (0..3).all(|k| lo[k] <= hi[k]) {
                    first = first.min(lo[2]);
                    last = last.max(hi[2]);
                }
            }
        }
        Some(if first > last {
            NONE_REACHED
        } else {
            // Inside LOCAL_MIN..=LOD0_LOCAL_MAX: fits an i32.
            first as i32..=last as i32
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::CollisionCache;
    use strata_terrain::mesh::Neighborhood;
    use strata_terrain::world::FlatGenerator;
    use strata_terrain::{Chunk, Voxel, VoxelPos};

    /// A tick whose edits changed `pos` (from version `before`) within boxes.
    fn tick_of(pos: ChunkPos, before: u64, boxes: Vec<VoxelBox>) -> TickReach {
        TickReach {
            changed: HashMap::from([(pos, (before, boxes))]),
        }
    }

    fn box_at(lo: [i32; 3], hi: [i32; 3]) -> VoxelBox {
        VoxelBox {
            min: VoxelPos::new(lo[0], lo[1], lo[2]),
            max: VoxelPos::new(hi[0], hi[1], hi[2]),
        }
    }

    /// A world whose 27 chunks around the origin are loaded at version 1,
    /// and a mesh of the origin chunk copied from them.
    fn meshed() -> (World, CollisionMesh) {
        let mut w = World::new(Arc::new(FlatGenerator {
            ground: Voxel::solid(1),
        }));
        for p in with_sources(ChunkPos::new(0, 0, 0)).into_iter().flatten() {
            let c = w.generator().generate(p);
            w.insert(p, c, 1);
        }
        let pos = ChunkPos::new(0, 0, 0);
        let job = MeshJob {
            pos,
            version: 1,
            nb: Neighborhood::from_world(&w, pos),
            base: None,
            known: None,
            sources: sources_of(&w, pos),
        };
        let mesh = CollisionCache::mesh_chunks(&[job]).0.remove(0);
        (w, mesh)
    }

    #[test]
    fn known_only_from_the_versions_the_tick_started_from() {
        let (mut w, mesh) = meshed();
        let then = *mesh.sources().expect("copied from loaded chunks");
        let pos = ChunkPos::new(0, 0, 0);
        let below = ChunkPos::new(0, -1, 0);
        // Nothing changed: nothing differs.
        let now = sources_of(&w, pos).unwrap();
        assert_eq!(
            TickReach::default().known(pos, &mesh, &then, &now),
            Some(NONE_REACHED)
        );
        // The chunk below changed from version 1 in this tick, in local z
        // 4..=6: the layers its box reaches.
        w.insert(below, Chunk::uniform(Voxel::solid(2)), 2);
        let now = sources_of(&w, pos).unwrap();
        let tick = tick_of(below, 1, vec![box_at([3, -5, 4], [9, -1, 6])]);
        assert_eq!(tick.known(pos, &mesh, &then, &now), Some(4..=6));
        // A box out of the neighbourhood's LOD-0 reach reaches nothing.
        let far = tick_of(
            below,
            1,
            vec![
                box_at([3, -9, 4], [9, -2, 6]),
                box_at([40, -5, 4], [41, -1, 6]),
            ],
        );
        assert_eq!(far.known(pos, &mesh, &then, &now), Some(NONE_REACHED));
        // A box counts only inside the chunk it changed: z 0..=31 below.
        let tall = tick_of(below, 1, vec![box_at([0, -3, -40], [2, -1, 90])]);
        assert_eq!(tall.known(pos, &mesh, &then, &now), Some(0..=31));
        // And only in the layers held, -1..=33: in the chunks before and
        // after in z, the neighbourhood holds one layer and two.
        let (behind, ahead) = (ChunkPos::new(0, 0, -1), ChunkPos::new(0, 0, 1));
        let (v_behind, v_ahead) = (
            w.peek(behind).unwrap().version,
            w.peek(ahead).unwrap().version,
        );
        let ends = TickReach {
            changed: HashMap::from([
                (below, (1, Vec::new())),
                (behind, (v_behind, vec![box_at([5, 5, -40], [6, 6, -1])])),
                (ahead, (v_ahead, vec![box_at([5, 5, 32], [6, 6, 90])])),
            ]),
        };
        assert_eq!(ends.known(pos, &mesh, &then, &now), Some(-1..=33));
        // Changed since the mesh, but not by this tick (or from another
        // version): unknown, the whole neighbourhood is compared.
        assert_eq!(TickReach::default().known(pos, &mesh, &then, &now), None);
        let other = tick_of(below, 3, vec![box_at([3, -5, 4], [9, -1, 6])]);
        assert_eq!(other.known(pos, &mesh, &then, &now), None);
        // A mesh of another chunk is no base; one without sources makes a
        // job that copies everything.
        assert_eq!(tick.known(ChunkPos::new(1, 0, 0), &mesh, &then, &now), None);
        let plain = CollisionMesh::build(pos, 1, &Neighborhood::from_world(&w, pos));
        assert_eq!(
            tick.job(&w, pos, 1, Some((Arc::new(plain), None))).known,
            None
        );
    }

    #[test]
    fn a_job_copies_the_layers_its_remesh_reads() {
        let (mut w, mesh) = meshed();
        let pos = ChunkPos::new(0, 0, 0);
        let below = ChunkPos::new(0, -1, 0);
        let mut c = strata_terrain::Chunk::clone(&w.peek(below).unwrap().chunk);
        for x in 3..=9 {
            c.set(x, 31, 5, Voxel::new(0, 0));
        }
        w.insert(below, c, 2);
        let tick = tick_of(below, 1, vec![box_at([3, -1, 5], [9, -1, 5])]);
        let then = mesh.sources().copied();
        let job = tick.job(&w, pos, 1, Some((Arc::new(mesh), then)));
        assert_eq!(job.known, Some(5..=5));
        let (built, _) = CollisionCache::mesh_chunks(&[job]);
        let fresh = CollisionMesh::build(pos, 1, &Neighborhood::from_world(&w, pos));
        assert_eq!(built[0].mesh, fresh.mesh);
        assert_eq!(built[0].sources(), sources_of(&w, pos).as_ref());
    }

    #[test]
    fn a_neighbour_change_out_of_reach_moves_the_cached_versions_on() {
        let (_, mesh) = meshed();
        let pos = ChunkPos::new(0, 0, 0);
        let below = ChunkPos::new(0, -1, 0);
        let slot = with_sources(pos)
            .iter()
            .position(|p| *p == Some(below))
            .unwrap();
        let mut cache = CollisionCache::new(16);
        cache.insert(mesh);
        // Deep in the chunk below: out of the mesh's reach, which stays.
        let deep = box_at([4, -20, 4], [8, -10, 8]);
        assert!(cache.invalidate_touched(below, deep).is_empty());
        cache.moved_on(below, 2);
        let (_, sources) = cache.peek_base(pos).expect("kept");
        assert_eq!(sources.unwrap()[slot], 2);
        // Its top row is the mesh's apron: dropped, with the versions it was
        // right for.
        let top = box_at([4, -1, 4], [8, -1, 8]);
        let dropped = cache.invalidate_touched(below, top);
        cache.moved_on(below, 3);
        let (m, sources) = dropped.iter().find(|(m, _)| m.pos == pos).expect("dropped");
        assert_eq!((m.pos, sources.unwrap()[slot]), (pos, 2));
        assert!(cache.peek_base(pos).is_none());
    }
}
