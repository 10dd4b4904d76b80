//! Smooth-voxel meshing: Marching Cubes at LOD 0..=3 with Transvoxel LOD transitions.
//!
//! How it works:
//!
//! * Input is a [`Neighborhood`]: the chunk's voxels plus a read-only apron (local -1..=33 on
//!   x/z, -1..=40 on y) taken from the face, edge and corner neighbours. The mesher reads
//!   nothing else, so meshing is a pure function of the neighbourhood and the options.
//! * A sample is solid when `density > iso` (default 127.5, which no u8 equals). Cells span
//!   `stride = 1 << lod` voxels; the case of each cell indexes Lengyel's crack-free regular
//!   tables from `transvoxel-data` (see `tables.rs` for their corner/edge conventions).
//! * Welding: each sign-changing sample edge yields exactly one vertex, cached per sample and
//!   axis over two z-layers. A vertex's position, normal and material depend only on its edge
//!   (see `builder.rs` for the exact quantized interpolation), and its [`VertexKey`] names the
//!   edge in world coordinates, so neighbouring chunk meshes agree bit for bit on shared
//!   vertices and can be welded by key.
//! * Normals are the negated density gradient (central differences, using the apron)
//!   interpolated along the edge: no lighting seams at chunk borders.
//! * Materials: the solid endpoint's material; on coarse edges, seed 001's upward surface scan
//!   (`material.rs`).
//! * LOD transitions (`transition.rs`): for each face bordering a finer chunk, Transvoxel
//!   transition cells stitch the finer neighbour's half-stride vertices to this chunk's
//!   vertices, and the regular vertices near that face are pushed inward by
//!   [`TRANSITION_WIDTH`] of a cell to make room for them.
//! * [`Mesh::hash`] digests a documented byte encoding (`hash.rs`).

mod builder;
mod hash;
mod material;
mod neighborhood;
mod normals;
mod regular;
mod tables;
mod transition;
mod types;
pub mod volume;

pub use neighborhood::{
    Neighborhood, APRON_HIGH, APRON_LOW, LOCAL_MAX, LOCAL_MAX_Y, LOCAL_MIN, MAX_SURFACE_SCAN,
};
pub use transition::TRANSITION_WIDTH;
pub use types::{faces, Mesh, MeshError, MeshOptions, VertexKey, ALL_FACES, DEFAULT_ISO, MAX_LOD};

use builder::Builder;

/// Meshes one chunk. Invalid options (see [`MeshOptions::validate`]) give an empty mesh; use
/// [`try_mesh_chunk`] to learn why.
pub fn mesh_chunk(nb: &Neighborhood, opts: &MeshOptions) -> Mesh {
    try_mesh_chunk(nb, opts).unwrap_or_default()
}

/// Meshes one chunk, rejecting invalid options with a typed error.
pub fn try_mesh_chunk(nb: &Neighborhood, opts: &MeshOptions) -> Result<Mesh, MeshError> {
    opts.validate()?;
    let stride = opts.stride();
    let cells = opts.cell_extent.map(|e| (e / stride) as usize);
    let mut b = Builder::new(nb, opts.iso);
    regular::mesh_regular(&mut b, nb, opts.iso, stride as i32, cells);
    if opts.transition_faces != 0 {
        transition::mesh_transitions(&mut b, nb, opts.iso, stride as i32, opts.transition_faces);
    }
    Ok(b.mesh)
}
