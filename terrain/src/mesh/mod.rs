//! Smooth-voxel meshing: Marching Cubes at LOD 0..=3 with Transvoxel LOD transitions.
//!
//! How it works:
//!
//! * Input is a [`Neighborhood`]: the chunk's voxels plus a read-only apron (local -1..=33 on
//!   x/z, -1..=40 on y) taken from the face, edge and corner neighbours. The mesher reads
//!   nothing else, so a mesh is a pure function of the neighbourhood and the [`MeshOptions`].
//! * A sample is solid when `density > iso` (default 127.5, which no u8 equals). Cells span
//!   `stride = 1 << lod` voxels (LOD 1..=3: every 2nd, 4th, 8th sample). Each cell's 8-bit
//!   case indexes Lengyel's crack-free regular tables from `transvoxel-data` (`tables.rs`
//!   states their corner/edge numbering and winding; triangles come out CCW seen from air).
//! * Speed (`regular.rs`): solid flags of each sample row are packed into a `u64` (SWAR
//!   compare, 8 samples per step); word operations on the four rows under a row of cells find
//!   the mixed cells, and only those are visited; a compile-time table flattens Lengyel's
//!   class, vertex and triangle tables to "case -> triangle corners as cell edges", and a
//!   fixed slot layout makes each cell edge's slot offset a constant. Vertex
//!   data is computed afterwards in batches (`builder.rs`): the edge parameter in exact
//!   integer arithmetic for half-integer isovalues, square roots and divisions of a batch
//!   in one vectorisable loop. Scratch memory is reused per thread.
//! * Welding: each sign-changing sample edge yields exactly one vertex, cached per sample and
//!   axis over two z-layers. A vertex's position, normal and material depend only on its edge
//!   (`builder.rs` gives the exact quantized interpolation: t rounded to 1/65536 and kept off
//!   the endpoints, so plateau data cannot make zero-area triangles), and its [`VertexKey`]
//!   names the edge in world coordinates: neighbouring chunk meshes agree bit for bit on
//!   shared vertices and can be welded by key.
//! * Normals (`normals.rs`): the negated density gradient (central differences, apron
//!   included) interpolated along the edge, normalised once: no lighting seams.
//! * Materials (`material.rs`): the material of the edge's solid endpoint (seed 001's dominant
//!   material, reduced to the one solid corner of the edge so shared vertices agree); on
//!   edges longer than one voxel, seed 001's surface scan (climb +Y up to
//!   [`MAX_SURFACE_SCAN`] voxels while solid, take the last solid material), so grass stays
//!   grass at coarse LOD.
//! * LOD transitions (`transition.rs`): for each face bit (a FINER neighbour there), regular
//!   vertices within one cell of that face are pushed inward by up to [`TRANSITION_WIDTH`] of
//!   a cell, and Transvoxel transition cells fill the slab. Their full-resolution side samples
//!   the face at half stride, giving exactly the finer neighbour's vertices (same keys, same
//!   bits); their low-resolution side reuses the pushed regular vertices. Where a transition
//!   face meets a non-transition face, the push tapers to zero on the latter, so a same-LOD
//!   neighbour there still matches. Any subset of the 6 faces works, including chunk edges
//!   and corners where 2 or 3 transition faces meet (tested on all 63 subsets at LOD 1..=3).
//!   The push is the chunk's own, so with transitions a key no longer names one position:
//!   two coarse chunks touching along an edge or a corner can put one key at different
//!   places. [`volume::weld`] therefore joins vertices only on equal key AND position.
//!   Caveat: about a quarter of Lengyel's transition triangles lie in the full-resolution
//!   face, so transition cells can emit zero-area triangles when their vertices happen to be
//!   collinear or coincide (linear data, and where the slab tapers to zero); they are kept,
//!   since dropping them would open the key-welded mesh. Regular cells never emit them.
//! * Re-meshing after a change (`layered.rs`): [`remesh_chunk_layered`] meshes only the
//!   z-layers a change can reach and copies the rest from an earlier mesh of the chunk;
//!   [`remesh_chunk_layered_known`] does the same from a neighbourhood holding only the
//!   layers it reads ([`remesh_reads`]), for a caller that knows which layers changed.
//! * [`Mesh::hash`] digests a documented byte encoding (`hash.rs`).

mod builder;
mod hash;
mod layered;
mod material;
mod neighborhood;
mod normals;
mod regular;
mod tables;
mod transition;
mod types;
pub mod volume;

pub use layered::{
    mesh_chunk_layered, remesh_chunk_layered, remesh_chunk_layered_known, remesh_reads, MeshLayers,
    Remeshed,
};
pub use neighborhood::{
    Neighborhood, APRON_HIGH, APRON_LOW, LOCAL_MAX, LOCAL_MAX_Y, LOCAL_MIN, LOD0_LOCAL_MAX,
    MAX_SURFACE_SCAN,
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
    b.flush();
    if opts.transition_faces != 0 {
        transition::mesh_transitions(&mut b, nb, opts.iso, stride as i32, opts.transition_faces);
    }
    Ok(b.mesh)
}
