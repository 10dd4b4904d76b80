//! A chunk's mesh as flat arrays a game engine uploads as they are:
//! positions and normals three floats per vertex, one material id per
//! vertex, three indices per triangle. Meshing is the terrain core's, so a
//! LOD-0 mesh of the same 27 chunks hashes as the server's does.

use std::sync::Arc;

use glam::IVec3;
use strata_terrain::mesh::{try_mesh_chunk, MeshError, MeshOptions, Neighborhood};
use strata_terrain::{Chunk, ChunkPos};

use crate::coords::chunk_origin;

/// The mesh of one chunk at one level of detail.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkMesh {
    pub pos: ChunkPos,
    /// World voxel coordinates of the chunk's local (0, 0, 0): add it to
    /// every position to place the mesh in the world.
    pub origin: IVec3,
    pub lod: u8,
    /// Chunk-local voxel units.
    pub positions: Vec<[f32; 3]>,
    /// Unit length, pointing into air.
    pub normals: Vec<[f32; 3]>,
    pub materials: Vec<u8>,
    /// Triangles, counter-clockwise seen from air.
    pub indices: Vec<u32>,
    /// Whether all 26 neighbours were held. A missing neighbour reads as
    /// air, so faces along that border are provisional: mesh again once it
    /// arrives.
    pub complete: bool,
    /// The terrain core's mesh hash (PROTOCOL.md; the server's at LOD 0).
    pub hash: u64,
}

impl ChunkMesh {
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Positions as one flat array, x y z per vertex (a vertex buffer).
    pub fn positions_flat(&self) -> &[f32] {
        self.positions.as_flattened()
    }

    /// Normals as one flat array, x y z per vertex.
    pub fn normals_flat(&self) -> &[f32] {
        self.normals.as_flattened()
    }
}

/// Meshes `pos` at `lod`, with transition cells on the faces set in
/// `transition_faces` (bit order -X, +X, -Y, +Y, -Z, +Z: faces bordering a
/// finer neighbour). `get` yields the chunks to read; `None` when it has
/// no chunk at `pos` itself, or when `pos` lies so far out that its
/// origin does not fit an `i32` (no replica holds such a chunk).
pub fn mesh_at(
    pos: ChunkPos,
    lod: u8,
    transition_faces: u8,
    mut get: impl FnMut(ChunkPos) -> Option<Arc<Chunk>>,
) -> Result<Option<ChunkMesh>, MeshError> {
    let opts = MeshOptions {
        lod,
        transition_faces,
        ..MeshOptions::default()
    };
    opts.validate()?;
    // A chunk whose origin is past i32 lies far outside the world: no
    // replica holds one.
    let Some(origin) = chunk_origin(pos) else {
        return Ok(None);
    };
    let Some(center) = get(pos) else {
        return Ok(None);
    };
    let mut around: Vec<(ChunkPos, Arc<Chunk>)> = vec![(pos, center)];
    let mut complete = true;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let Some(n) = pos.offset(dx, dy, dz).filter(|n| *n != pos) else {
                    continue;
                };
                match get(n) {
                    Some(c) => around.push((n, c)),
                    None => complete = false,
                }
            }
        }
    }
    let nb = Neighborhood::from_chunks(pos, |p| {
        around.iter().find(|(q, _)| *q == p).map(|(_, c)| &**c)
    });
    let mesh = try_mesh_chunk(&nb, &opts)?;
    Ok(Some(ChunkMesh {
        pos,
        origin,
        lod,
        hash: mesh.hash(),
        positions: mesh.positions,
        normals: mesh.normals,
        materials: mesh.materials,
        indices: mesh.indices,
        complete,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::material::ids;
    use strata_terrain::mesh::{faces, mesh_chunk};
    use strata_terrain::world::FlatGenerator;
    use strata_terrain::{ChunkGenerator, Voxel};

    #[test]
    fn meshes_as_the_terrain_core_does_and_says_when_neighbours_are_missing() {
        let stone = Voxel::solid(ids::STONE);
        let g = FlatGenerator { ground: stone };
        // Chunks with |x| <= 2 and |z| <= 1 are held; the ground's surface
        // runs through the top of the chunks at y = -1.
        let get = |p: ChunkPos| (p.x.abs() <= 2 && p.z.abs() <= 1).then(|| Arc::new(g.generate(p)));
        let pos = ChunkPos::new(0, -1, 0);
        let m = mesh_at(pos, 0, 0, get).unwrap().unwrap();
        let flat =
            Neighborhood::from_fn(pos.origin(), |v| if v.y < 0 { stone } else { Voxel::AIR });
        let expected = mesh_chunk(&flat, &MeshOptions::default());
        assert!(m.complete);
        assert!(m.triangle_count() > 0);
        assert_eq!(m.hash, expected.hash());
        assert_eq!(m.positions, expected.positions);
        assert_eq!(m.origin, IVec3::new(0, -32, 0));
        assert_eq!(m.positions_flat().len(), 3 * m.vertex_count());
        assert_eq!(&m.normals_flat()[..3], &m.normals[0]);

        let coarse = mesh_at(pos, 1, faces::NEG_X, get).unwrap().unwrap();
        assert!(coarse.triangle_count() > 0);
        assert!(coarse.triangle_count() < m.triangle_count());

        let edge = ChunkPos::new(0, -1, 1);
        assert!(!mesh_at(edge, 0, 0, get).unwrap().unwrap().complete);
        assert_eq!(mesh_at(ChunkPos::new(9, 9, 9), 0, 0, get).unwrap(), None);
        assert_eq!(
            mesh_at(pos, 0, faces::POS_X, get),
            Err(MeshError::TransitionAtLod0)
        );
    }

    #[test]
    fn a_chunk_whose_origin_overflows_is_not_meshed() {
        let g = FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        };
        // Whatever `get` hands out: a chunk there has no i32 origin.
        let get = |p: ChunkPos| Some(Arc::new(g.generate(p)));
        assert_eq!(mesh_at(ChunkPos::new(1 << 26, 0, 0), 0, 0, get), Ok(None));
        assert_eq!(
            mesh_at(ChunkPos::new(0, 0, -(1 << 27)), 1, 0, get),
            Ok(None)
        );
        // The farthest origin that fits still meshes.
        let edge = ChunkPos::new((1 << 26) - 2, 0, 0);
        let m = mesh_at(edge, 0, 0, get).unwrap().unwrap();
        assert_eq!(m.origin, IVec3::new(((1 << 26) - 2) * 32, 0, 0));
    }
}
