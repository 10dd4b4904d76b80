//! The mesher's public value types: options, output mesh, vertex identity, errors.

use thiserror::Error;

use crate::pos::{VoxelPos, CHUNK_SIZE};

/// Default isovalue: halfway between 127 and 128, so no u8 sample can equal it.
pub const DEFAULT_ISO: f32 = 127.5;
/// Highest supported level of detail (stride `1 << MAX_LOD` = 8 voxels).
pub const MAX_LOD: u8 = 3;
/// Mask of the six face bits of [`MeshOptions::transition_faces`].
pub const ALL_FACES: u8 = 0b11_1111;

/// Face bit order of [`MeshOptions::transition_faces`]: -X, +X, -Y, +Y, -Z, +Z.
pub mod faces {
    pub const NEG_X: u8 = 1 << 0;
    pub const POS_X: u8 = 1 << 1;
    pub const NEG_Y: u8 = 1 << 2;
    pub const POS_Y: u8 = 1 << 3;
    pub const NEG_Z: u8 = 1 << 4;
    pub const POS_Z: u8 = 1 << 5;
}

/// What to mesh and how: isovalue, level of detail, LOD transition faces, extent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshOptions {
    /// A sample is inside (solid) when its density is strictly greater than `iso`.
    pub iso: f32,
    /// Level of detail 0..=3; cells span `1 << lod` voxels.
    pub lod: u8,
    /// Bit i set: face i borders a FINER (`lod - 1`) neighbour. Bit order -X,+X,-Y,+Y,-Z,+Z.
    /// Must be 0 at lod 0.
    pub transition_faces: u8,
    /// Voxels of cells meshed per axis from local 0 (default 32). Each must be a multiple of
    /// the stride, and all must be 32 when `transition_faces != 0`.
    pub cell_extent: [u32; 3],
}

impl Default for MeshOptions {
    fn default() -> Self {
        Self {
            iso: DEFAULT_ISO,
            lod: 0,
            transition_faces: 0,
            cell_extent: [CHUNK_SIZE as u32; 3],
        }
    }
}

/// Why a [`MeshOptions`] value is rejected by [`crate::mesh::try_mesh_chunk`].
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MeshError {
    #[error("isovalue {0} is not finite")]
    NonFiniteIso(f32),
    #[error("lod {0} is above the maximum {MAX_LOD}")]
    LodTooHigh(u8),
    #[error("transition faces {0:#08b} use bits outside the six face bits")]
    BadFaceBits(u8),
    #[error("transition faces need lod >= 1 (a finer neighbour must exist)")]
    TransitionAtLod0,
    #[error(
        "cell extent {extent:?} must be <= {CHUNK_SIZE} and a multiple of the stride {stride}"
    )]
    BadExtent { extent: [u32; 3], stride: u32 },
    #[error("transition faces need the full cell extent of {CHUNK_SIZE}, got {0:?}")]
    PartialExtentWithTransitions([u32; 3]),
}

impl MeshOptions {
    /// Voxels per cell edge at this level of detail.
    pub fn stride(&self) -> u32 {
        1u32 << self.lod.min(MAX_LOD)
    }

    /// Checks every field; `Ok` means meshing with these options is well defined.
    pub fn validate(&self) -> Result<(), MeshError> {
        if !self.iso.is_finite() {
            return Err(MeshError::NonFiniteIso(self.iso));
        }
        if self.lod > MAX_LOD {
            return Err(MeshError::LodTooHigh(self.lod));
        }
        if self.transition_faces & !ALL_FACES != 0 {
            return Err(MeshError::BadFaceBits(self.transition_faces));
        }
        if self.lod == 0 && self.transition_faces != 0 {
            return Err(MeshError::TransitionAtLod0);
        }
        let stride = self.stride();
        if self
            .cell_extent
            .iter()
            .any(|&e| e > CHUNK_SIZE as u32 || e % stride != 0)
        {
            return Err(MeshError::BadExtent {
                extent: self.cell_extent,
                stride,
            });
        }
        if self.transition_faces != 0 && self.cell_extent != [CHUNK_SIZE as u32; 3] {
            return Err(MeshError::PartialExtentWithTransitions(self.cell_extent));
        }
        Ok(())
    }
}

/// Identity of a sample edge in WORLD voxel coordinates: `base` is the lower endpoint, the edge
/// runs `len` voxels along `axis` (0=x, 1=y, 2=z). Two chunk meshes that share a vertex give it
/// the same key. Without transition faces a key names one position, so meshes weld by key;
/// with them a chunk pushes vertices near its faces by its own amounts, and one key may sit at
/// different positions in two chunks: weld by key and position ([`super::volume::weld`] does).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VertexKey {
    pub base: VoxelPos,
    pub axis: u8,
    pub len: u8,
}

impl VertexKey {
    /// The key of an edge given by its chunk-local lower endpoint, for a
    /// chunk whose local (0, 0, 0) is `origin` (wrapping at the i32 limits).
    pub fn from_local(origin: VoxelPos, lower: [i32; 3], axis: usize, len: u32) -> Self {
        VertexKey {
            base: VoxelPos::new(
                origin.x.wrapping_add(lower[0]),
                origin.y.wrapping_add(lower[1]),
                origin.z.wrapping_add(lower[2]),
            ),
            axis: axis as u8,
            len: len as u8,
        }
    }
}

/// An indexed triangle mesh of one chunk, in chunk-local voxel units.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Chunk-local voxel units: sample (i,j,k) sits at (i,j,k).
    pub positions: Vec<[f32; 3]>,
    /// Unit length, from the density gradient (central differences), pointing into air.
    pub normals: Vec<[f32; 3]>,
    /// Per vertex material id.
    pub materials: Vec<u8>,
    /// Triangles, counter-clockwise seen from air (outside).
    pub indices: Vec<u32>,
    /// Per vertex: global identity of the edge it sits on (for welding).
    pub keys: Vec<VertexKey>,
}

impl Mesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }
}
