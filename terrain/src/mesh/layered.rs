//! Meshing a LOD-0 chunk again after a change, reusing the layers the change cannot reach.
//!
//! A whole LOD-0 chunk is meshed one z-layer after another (`regular.rs`): the vertices of
//! sample layer k's x and y edges (group `Xk`), of the z edges from layer k to k + 1 (`Zk`),
//! and then cell layer k's triangles. A vertex is a function of its edge's samples and their
//! neighbours one voxel away, so `Xk` reads sample layers k - 1..=k + 1, `Zk` reads
//! k - 1..=k + 2, and cell layer k's triangles read the signs of layers k and k + 1.
//!
//! [`MeshLayers`] keeps, beside a mesh, where each group and cell layer starts in it and a
//! fingerprint of each sample layer of the neighbourhood it was meshed from. Meshing a new
//! neighbourhood of the same chunk against such a base ([`remesh_chunk_layered`]) compares
//! the fingerprints: if sample layers a..=b differ, groups and cell layers below `a - 2` are
//! copied from the base, those from `a - 2` to `X{b + 2}` are meshed, and the rest is copied
//! with its vertex indices shifted by the difference in vertex count. The result equals
//! [`mesh_chunk`](super::mesh_chunk) with default options bit for bit (tests compare them on
//! random edits); its cost follows the layers changed, not the chunk.

use twox_hash::XxHash3_64;

use super::builder::Builder;
use super::neighborhood::{Neighborhood, DIM_X, DIM_Z, LOCAL_MIN, LOD0_LOCAL_MAX, STEP_Z};
use super::regular::{mesh_lod0_layers, Marks, GROUPS, LAYERS};
use super::types::{Mesh, DEFAULT_ISO};
use crate::pos::VoxelPos;

/// Samples of one sample layer that a LOD-0 mesh reads: rows of local y up to
/// [`LOD0_LOCAL_MAX`] (the rows above feed only coarse LODs' material scan).
const LAYER_READ: usize = DIM_X * (LOD0_LOCAL_MAX - LOCAL_MIN + 1) as usize;

/// Where a LOD-0 chunk mesh's layers start, and what its neighbourhood held, layer by layer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MeshLayers {
    origin: VoxelPos,
    marks: Marks,
    /// Fingerprints of each sample layer (local z from -1): densities, materials.
    prints: [[u64; 2]; DIM_Z],
}

/// A mesh made by [`remesh_chunk_layered`].
#[derive(Clone, Debug, PartialEq)]
pub struct Remeshed {
    pub mesh: Mesh,
    pub layers: MeshLayers,
    /// Cell layers copied from the base instead of meshed (0..=32).
    pub reused: u32,
}

/// Seed of the layer fingerprints: random per process, so no one can craft voxels whose
/// fingerprints collide (a base is only ever compared within one process).
fn print_seed() -> u64 {
    static SEED: std::sync::OnceLock<u64> = std::sync::OnceLock::new();
    *SEED.get_or_init(|| {
        use std::hash::BuildHasher;
        std::collections::hash_map::RandomState::new().hash_one(0x5eed_u64)
    })
}

/// Fingerprints (densities, materials) of the sample layers of `nb` that a LOD-0 mesh reads.
fn layer_prints(nb: &Neighborhood) -> [[u64; 2]; DIM_Z] {
    let (d, m, seed) = (nb.densities(), nb.materials(), print_seed());
    std::array::from_fn(|z| {
        let at = z * STEP_Z..z * STEP_Z + LAYER_READ;
        [
            XxHash3_64::oneshot_with_seed(seed, &d[at.clone()]),
            XxHash3_64::oneshot_with_seed(seed, &m[at]),
        ]
    })
}

/// [`mesh_chunk`](super::mesh_chunk) with default options, with the [`MeshLayers`] that
/// [`remesh_chunk_layered`] needs of a base.
pub fn mesh_chunk_layered(nb: &Neighborhood) -> (Mesh, MeshLayers) {
    let prints = layer_prints(nb);
    let mut b = Builder::new(nb, DEFAULT_ISO);
    let mut marks = Marks::default();
    let mesh = if mesh_lod0_layers(&mut b, nb, DEFAULT_ISO, 0, LAYERS, &mut marks) {
        b.flush();
        marks.vertices[GROUPS] = b.mesh.keys.len() as u32;
        marks.indices[LAYERS] = b.mesh.indices.len() as u32;
        b.mesh
    } else {
        marks = Marks::default();
        Mesh::default()
    };
    let layers = MeshLayers {
        origin: nb.origin(),
        marks,
        prints,
    };
    (mesh, layers)
}

/// The mesh of `nb` (as [`mesh_chunk_layered`] makes it), copying from `base` (a mesh of an
/// earlier neighbourhood of the same chunk, with its layers) what the difference between the
/// two neighbourhoods cannot reach. A base of another chunk is not used.
pub fn remesh_chunk_layered(nb: &Neighborhood, base: (&Mesh, &MeshLayers)) -> Remeshed {
    let (old, old_layers) = base;
    let prints = layer_prints(nb);
    let differ = |z: &usize| prints[*z] != old_layers.prints[*z];
    let (first, last) = match ((0..DIM_Z).find(differ), (0..DIM_Z).rev().find(differ)) {
        _ if old_layers.origin != nb.origin() => (0, DIM_Z - 1),
        (Some(a), Some(b)) => (a, b),
        // Nothing the mesh reads changed.
        _ => {
            return Remeshed {
                mesh: old.clone(),
                layers: old_layers.clone(),
                reused: LAYERS as u32,
            }
        }
    };
    // Sample layers a..=b changed (local z = index - 1): groups and cell layers from a - 2
    // to b + 1 may change, X{b + 2} only moves.
    let (a, b) = (first as i32 + LOCAL_MIN, last as i32 + LOCAL_MIN);
    let from = (a - 2).max(0) as usize;
    let to = ((b + 2).max(0) as usize).min(LAYERS);
    let om = &old_layers.marks;
    let mut builder = Builder::new(nb, DEFAULT_ISO);
    let mut marks = Marks::default();
    // Room for about the base's size: growing the vectors mid-way copies them.
    builder.reserve(
        old.keys.len() + old.keys.len() / 4,
        (old.indices.len() + old.indices.len() / 4) / 3,
    );
    {
        let (v, i) = (om.vertices[2 * from] as usize, om.indices[from] as usize);
        let m = &mut builder.mesh;
        m.keys.extend_from_slice(&old.keys[..v]);
        m.positions.extend_from_slice(&old.positions[..v]);
        m.normals.extend_from_slice(&old.normals[..v]);
        m.materials.extend_from_slice(&old.materials[..v]);
        m.indices.extend_from_slice(&old.indices[..i]);
        marks.vertices[..=2 * from].copy_from_slice(&om.vertices[..=2 * from]);
        marks.indices[..=from].copy_from_slice(&om.indices[..=from]);
    }
    if !mesh_lod0_layers(&mut builder, nb, DEFAULT_ISO, from, to, &mut marks) {
        return Remeshed {
            mesh: Mesh::default(),
            layers: MeshLayers {
                origin: nb.origin(),
                marks: Marks::default(),
                prints,
            },
            reused: 0,
        };
    }
    builder.flush();
    let mut mesh = builder.mesh;
    if to < LAYERS {
        // The rest starts at group Z{to} and cell layer `to`.
        let (v, i) = (om.vertices[2 * to + 1], om.indices[to]);
        let dv = (mesh.keys.len() as u32).wrapping_sub(v);
        let di = (mesh.indices.len() as u32).wrapping_sub(i);
        let (v, i) = (v as usize, i as usize);
        mesh.keys.extend_from_slice(&old.keys[v..]);
        mesh.positions.extend_from_slice(&old.positions[v..]);
        mesh.normals.extend_from_slice(&old.normals[v..]);
        mesh.materials.extend_from_slice(&old.materials[v..]);
        mesh.indices
            .extend(old.indices[i..].iter().map(|&k| k.wrapping_add(dv)));
        for g in 2 * to + 1..=GROUPS {
            marks.vertices[g] = om.vertices[g].wrapping_add(dv);
        }
        for z in to..=LAYERS {
            marks.indices[z] = om.indices[z].wrapping_add(di);
        }
    } else {
        marks.vertices[GROUPS] = mesh.keys.len() as u32;
        marks.indices[LAYERS] = mesh.indices.len() as u32;
    }
    Remeshed {
        mesh,
        layers: MeshLayers {
            origin: nb.origin(),
            marks,
            prints,
        },
        reused: (LAYERS - (to - from)) as u32,
    }
}
