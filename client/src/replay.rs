//! Op replay: a `WorldUpdate::Op` applied to held chunks with the terrain
//! core's own `Edit::apply`, the code the server's sequencer runs. The
//! result is a pure function of the chunks the edit reads and the edit, so
//! each listed chunk must come out with the server's hash; anything else
//! (a missing or older base, a chunk the edit reads that is not held, a
//! different hash) is a failure the caller turns into a resync.

use std::sync::{Arc, OnceLock};

use strata_protocol::{OpChunk, OpUpdate};
use strata_terrain::edit::{EditContext, StructureLibrary};
use strata_terrain::hash::chunk_hash;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{Chunk, ChunkPos, MaterialTable, Voxel, VoxelBox, VoxelPos, World};

use crate::replica::Held;

/// Why a listed chunk could not be replayed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayFailure {
    /// The chunk is not held at the op's base version (`version - 1`), or a
    /// chunk the edit reads is not held.
    MissingBase,
    /// The edit did not apply, or the result's hash is not the server's.
    Mismatch,
}

/// One listed chunk's outcome.
pub type Replayed = (OpChunk, Result<Arc<Chunk>, ReplayFailure>);

fn materials() -> &'static MaterialTable {
    static TABLE: OnceLock<MaterialTable> = OnceLock::new();
    TABLE.get_or_init(MaterialTable::default)
}

/// Applies `op.edit` to the chunks `held` gives and checks every listed
/// chunk. Chunks the edit changes but the op does not list are discarded
/// (the session does not hold them, or not at that version).
pub fn replay(op: &OpUpdate, held: impl Fn(ChunkPos) -> Option<Held>) -> Vec<Replayed> {
    let fail_all =
        |f: ReplayFailure| -> Vec<Replayed> { op.chunks.iter().map(|c| (*c, Err(f))).collect() };
    // Templates stay on the server: PlaceStructure is never sent as an op,
    // and would not validate here.
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: materials(),
        structures: &structures,
    };
    let Ok(bbox) = op.edit.validate(&ctx) else {
        return fail_all(ReplayFailure::Mismatch);
    };
    let m = op.edit.read_margin();
    let reads = VoxelBox {
        min: VoxelPos::new(bbox.min.x - m, bbox.min.y - m, bbox.min.z - m),
        max: VoxelPos::new(bbox.max.x + m, bbox.max.y + m, bbox.max.z + m),
    };
    // Chunks not inserted are made of air by this generator: only chunks
    // the op does not list, whose results are dropped, may be missing, and
    // only when the edit reads nothing past the voxels it changes.
    let mut world = World::new(Arc::new(FlatGenerator { ground: Voxel::AIR }));
    for pos in reads.chunks() {
        match held(pos) {
            // Shared: the edit copies only the chunks it changes.
            Some(h) => world.insert(pos, h.chunk.clone(), h.version),
            None if m > 0 => return fail_all(ReplayFailure::MissingBase),
            None => {}
        }
    }
    if op.edit.apply(&mut world, &ctx).is_err() {
        return fail_all(ReplayFailure::Mismatch);
    }
    op.chunks
        .iter()
        .map(|c| {
            let base_ok = held(c.pos).is_some_and(|h| Some(h.version) == c.version.checked_sub(1));
            if !base_ok {
                return (*c, Err(ReplayFailure::MissingBase));
            }
            let result = world
                .peek(c.pos)
                .map(|v| v.chunk.clone())
                .filter(|chunk| chunk_hash(chunk) == c.hash)
                .ok_or(ReplayFailure::Mismatch);
            (*c, result)
        })
        .collect()
}
