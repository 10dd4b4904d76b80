//! Which chunks the sequencer may read: loaded ones, and ones the store
//! said it does not have (those are generated). Anything else must be
//! loaded from the store first, or an edit would build on a stale
//! generated chunk and overwrite the stored one.

use std::collections::HashSet;

use strata_terrain::mesh::{APRON_HIGH, APRON_LOW};
use strata_terrain::{ChunkPos, VoxelBox, VoxelPos, World, CHUNK_SIZE};

/// The voxels an edit's box reads, grown by its read margin and one chunk
/// on each side: the neighbours' voxels feed the collision meshes of the
/// changed chunks.
pub fn edit_footprint(bbox: &VoxelBox, margin: i32) -> VoxelBox {
    grown(bbox, margin + CHUNK_SIZE)
}

/// The voxels whose chunks' data or collision meshes an edit may read or
/// change: the box grown by its read margin and the meshes' apron (a
/// chunk's mesh reads one sample below its first and two past its last on
/// each axis, so a change within two voxels of a chunk border remeshes the
/// chunk beyond). A cluster node must hold every region it reaches
/// (`Sequencer::edit_regions`): the chunks themselves, not the whole
/// neighbours [`edit_footprint`] loads.
pub fn edit_mesh_reach(bbox: &VoxelBox, margin: i32) -> VoxelBox {
    grown(bbox, margin + MESH_REACH)
}

/// How far past a changed voxel a mesh may change: [`APRON_HIGH`] + 1
/// (the normal at the last sample past the border reads one further).
pub const MESH_REACH: i32 = APRON_HIGH + 1;
const _: () = assert!(MESH_REACH >= APRON_LOW);

/// The voxels applying an edit reads or writes: the box grown by its read
/// margin, without the mesh apron.
pub fn edit_reads(bbox: &VoxelBox, margin: i32) -> VoxelBox {
    grown(bbox, margin)
}

fn grown(bbox: &VoxelBox, grow: i32) -> VoxelBox {
    VoxelBox {
        min: VoxelPos::new(
            bbox.min.x.saturating_sub(grow),
            bbox.min.y.saturating_sub(grow),
            bbox.min.z.saturating_sub(grow),
        ),
        max: VoxelPos::new(
            bbox.max.x.saturating_add(grow),
            bbox.max.y.saturating_add(grow),
            bbox.max.z.saturating_add(grow),
        ),
    }
}

/// A chunk and its 26 neighbours.
pub fn with_neighbours(c: ChunkPos) -> impl Iterator<Item = ChunkPos> {
    (-1..=1).flat_map(move |dz| {
        (-1..=1).flat_map(move |dy| (-1..=1).filter_map(move |dx| c.offset(dx, dy, dz)))
    })
}

/// Tracks chunks known to be absent from the store.
#[derive(Debug, Clone, Default)]
pub struct Residency {
    /// Seeded foldhash, as the world's chunk map: looked up for every
    /// chunk an edit reads.
    absent: HashSet<ChunkPos, foldhash::fast::RandomState>,
    /// No store at all: every chunk not loaded is generated.
    storeless: bool,
}

impl Residency {
    pub fn storeless() -> Self {
        Self {
            absent: HashSet::default(),
            storeless: true,
        }
    }

    pub fn mark_absent(&mut self, pos: ChunkPos) {
        self.absent.insert(pos);
    }

    /// A chunk that is stored now no longer needs its absent mark.
    pub fn mark_present(&mut self, pos: ChunkPos) {
        self.absent.remove(&pos);
    }

    /// Forgets absent marks for which `keep` is false.
    pub fn retain_absent(&mut self, keep: impl Fn(ChunkPos) -> bool) {
        self.absent.retain(|p| keep(*p));
    }

    /// Chunks marked absent.
    pub fn absent_len(&self) -> usize {
        self.absent.len()
    }

    pub fn is_storeless(&self) -> bool {
        self.storeless
    }

    pub fn is_resident(&self, world: &World, pos: ChunkPos) -> bool {
        self.may_generate(pos) || world.peek(pos).is_some()
    }

    /// Whether `pos`, when not loaded, is generated: the store has no
    /// version of it (or there is no store).
    pub fn may_generate(&self, pos: ChunkPos) -> bool {
        self.storeless || self.absent.contains(&pos)
    }

    /// The chunks of `wanted` that still need loading, sorted and deduplicated.
    pub fn missing(
        &self,
        world: &World,
        wanted: impl IntoIterator<Item = ChunkPos>,
    ) -> Vec<ChunkPos> {
        let mut v: Vec<ChunkPos> = wanted
            .into_iter()
            .filter(|p| !self.is_resident(world, *p))
            .collect();
        v.sort();
        v.dedup();
        v
    }
}
