//! The 3-D view: a region's LOD-0 meshes, built chunk by chunk exactly as
//! the server builds its collision meshes (`admin::export_mesh`, whose
//! chunk hashes equal the server's), welded and written as binary glTF.

use strata_terrain::mesh::volume::weld;
use strata_terrain::ChunkPos;

use crate::admin::export::{ExportError, MeshRef};
use crate::admin::export_mesh::{mesh_region, ExportMeshError};
use crate::admin::glb::write_glb;
use crate::admin::world_source::{ChunkBox, WorldView};

/// Why a scene was not built.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("the region must have x0 <= x1, y0 <= y1 and z0 <= z1")]
    Empty,
    #[error("the region and the border of chunks its meshes read hold {chunks} chunks; at most {max} ([console] scene_max_chunks)")]
    TooLarge { chunks: u64, max: u64 },
    #[error("rows {0}..={1} are outside the world")]
    Rows(i32, i32),
    #[error(transparent)]
    Mesh(#[from] ExportMeshError),
    #[error(transparent)]
    Export(#[from] ExportError),
}

impl SceneError {
    /// Whether the request, not the server, was at fault.
    pub fn is_bad_request(&self) -> bool {
        matches!(
            self,
            SceneError::Empty | SceneError::TooLarge { .. } | SceneError::Rows(..)
        )
    }
}

/// Checks a requested chunk box against the world and the size cap (the
/// box with the border its meshes read).
pub fn check_box(
    world: &dyn WorldView,
    min: ChunkPos,
    max: ChunkPos,
    max_chunks: u64,
) -> Result<ChunkBox, SceneError> {
    if min.x > max.x || min.y > max.y || min.z > max.z {
        return Err(SceneError::Empty);
    }
    let rows = world.rows();
    if min.y < *rows.start() || max.y > *rows.end() {
        return Err(SceneError::Rows(min.y, max.y));
    }
    let bx = ChunkBox { min, max };
    // Meshing reads (and generates) a border of one chunk around the box:
    // a thin box reads several times its own chunks.
    let [a, b, c] = bx.size().map(|n| n.saturating_add(2));
    let chunks = a.saturating_mul(b).saturating_mul(c);
    if chunks > max_chunks {
        return Err(SceneError::TooLarge {
            chunks,
            max: max_chunks,
        });
    }
    Ok(bx)
}

/// The welded LOD-0 mesh of `bx` as GLB bytes.
pub fn build(world: &dyn WorldView, bx: ChunkBox) -> Result<Vec<u8>, SceneError> {
    let meshes = mesh_region(world, bx, 0, false)?;
    let mesh = weld(meshes.into_iter().map(|(pos, _, m)| (pos.origin(), m)))
        .map_err(ExportMeshError::from)?;
    let mut out = Vec::new();
    write_glb(MeshRef::from(&mesh), &mut out)?;
    Ok(out)
}
