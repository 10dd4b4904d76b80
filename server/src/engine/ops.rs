//! Op replay: an accepted edit sent as the edit itself plus, per chunk the
//! session holds, its new version and hashes (`WorldUpdate::Op`), to
//! sessions with `CAP_OP_REPLAY`. The client applies it with the same
//! terrain code as the sequencer, so an op of any size is a few dozen
//! bytes; a client whose result differs asks for a resync.

use bytes::Bytes;
use strata_protocol::{OpChunk, OpUpdate, WorldUpdate};
use strata_terrain::edit::Edit;
use strata_terrain::{ChunkPos, VoxelBox, VoxelPos};

use super::fanout::encode_update;
use super::peer::Peer;
use crate::sequencer::AppliedEdit;

/// How one applied edit goes out as an op.
pub(super) struct OpPlan {
    /// Chunks the edit reads outside the voxels it changes (`Smooth`'s
    /// margin): a session must hold all of them to replay it.
    margin_reads: Vec<ChunkPos>,
    /// The op listing every change, for sessions that hold them all.
    whole: Bytes,
}

impl OpPlan {
    /// `None` for edits a client cannot replay: templates live on the server.
    pub fn new(a: &AppliedEdit) -> Option<Self> {
        if matches!(a.edit, Edit::PlaceStructure { .. }) {
            return None;
        }
        let all: Vec<usize> = (0..a.changes.len()).collect();
        Some(Self {
            margin_reads: margin_reads(&a.edit),
            whole: encode(a, &all),
        })
    }

    /// Whether `p` holds every chunk the edit reads beyond the ones it
    /// changes (for edits that read only the voxels they change: always).
    pub fn replayable_by(&self, p: &Peer) -> bool {
        self.margin_reads
            .iter()
            .all(|c| p.held(*c).is_some() && p.interest.covers(*c))
    }

    /// The op frame with the changes `held` (indices into `a.changes`).
    pub fn frame(&self, a: &AppliedEdit, held: &[usize]) -> Bytes {
        if held.len() == a.changes.len() {
            self.whole.clone()
        } else {
            encode(a, held)
        }
    }
}

fn encode(a: &AppliedEdit, held: &[usize]) -> Bytes {
    let chunks = held
        .iter()
        .map(|&i| {
            let c = &a.changes[i];
            OpChunk {
                pos: c.pos,
                version: c.to_version,
                hash: c.delta.target_hash,
                mesh_hash: c.mesh_hash,
            }
        })
        .collect();
    encode_update(&WorldUpdate::Op(OpUpdate {
        seq: a.seq,
        edit: a.edit.clone(),
        chunks,
    }))
}

/// Chunks of the edit's read box (its box grown by its read margin), when
/// the margin is not zero; the box itself is not needed here since the edit
/// was valid when applied.
fn margin_reads(edit: &Edit) -> Vec<ChunkPos> {
    let m = edit.read_margin();
    if m == 0 {
        return Vec::new();
    }
    let Some(b) = edit_box(edit) else {
        return Vec::new();
    };
    VoxelBox {
        min: VoxelPos::new(b.min.x - m, b.min.y - m, b.min.z - m),
        max: VoxelPos::new(b.max.x + m, b.max.y + m, b.max.z + m),
    }
    .chunks()
    .collect()
}

/// The box an accepted edit may change (validated once already).
fn edit_box(edit: &Edit) -> Option<VoxelBox> {
    use strata_terrain::edit::{EditContext, StructureLibrary};
    use strata_terrain::material::MaterialTable;
    let materials = MaterialTable::default();
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    edit.validate(&ctx).ok()
}
