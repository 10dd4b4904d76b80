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

use std::ops::RangeInclusive;

use twox_hash::XxHash3_64;

use super::builder::Builder;
use super::neighborhood::{
    Neighborhood, DIM_X, DIM_Z, LOCAL_MAX, LOCAL_MIN, LOD0_LOCAL_MAX, STEP_Z,
};
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
    std::array::from_fn(|z| layer_print(nb, z))
}

/// The fingerprint of sample layer `z` (an index from local z -1).
fn layer_print(nb: &Neighborhood, z: usize) -> [u64; 2] {
    let (d, m, seed) = (nb.densities(), nb.materials(), print_seed());
    let at = z * STEP_Z..z * STEP_Z + LAYER_READ;
    [
        XxHash3_64::oneshot_with_seed(seed, &d[at.clone()]),
        XxHash3_64::oneshot_with_seed(seed, &m[at]),
    ]
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
    let old_layers = base.1;
    let prints = layer_prints(nb);
    let differ = |z: &usize| prints[*z] != old_layers.prints[*z];
    let (first, last) = match ((0..DIM_Z).find(differ), (0..DIM_Z).rev().find(differ)) {
        _ if old_layers.origin != nb.origin() => (0, DIM_Z - 1),
        (Some(a), Some(b)) => (a, b),
        // Nothing the mesh reads changed.
        _ => return unchanged(base),
    };
    remesh_layers(nb, base, (first, last), prints)
}

/// The sample layers (local z) that [`remesh_chunk_layered_known`] reads when sample layers
/// `changed` differ from the base's: the neighbourhood need hold only these.
pub fn remesh_reads(changed: RangeInclusive<i32>) -> RangeInclusive<i32> {
    // Groups and cell layers a - 2 ..= b + 2 are meshed; a group reads one sample layer
    // below its own and, for z edges, two above.
    (changed.start() - 3).max(LOCAL_MIN)..=(changed.end() + 3).min(LOCAL_MAX)
}

/// [`remesh_chunk_layered`] for a caller that knows which sample layers (local z) may differ
/// between `base`'s neighbourhood and the current one: `changed` (empty when none). `nb` need
/// hold the current samples of [`remesh_reads`]`(changed)` only; nothing else of it is read,
/// and no layer is fingerprinted but those in `changed`, of which only the ones whose
/// fingerprints differ are meshed again. The same mesh and layers as
/// [`remesh_chunk_layered`] of the whole neighbourhood, if `changed` covers every layer that
/// differs; `None` for a base of another chunk, which cannot be used.
pub fn remesh_chunk_layered_known(
    nb: &Neighborhood,
    base: (&Mesh, &MeshLayers),
    changed: RangeInclusive<i32>,
) -> Option<Remeshed> {
    let (_, old_layers) = base;
    if old_layers.origin != nb.origin() {
        return None;
    }
    let (a, b) = (
        (*changed.start()).max(LOCAL_MIN),
        (*changed.end()).min(LOCAL_MAX),
    );
    if a > b {
        return Some(unchanged(base));
    }
    let (first, last) = ((a - LOCAL_MIN) as usize, (b - LOCAL_MIN) as usize);
    let mut prints = old_layers.prints;
    for (z, print) in prints.iter_mut().enumerate().take(last + 1).skip(first) {
        *print = layer_print(nb, z);
    }
    // Of the layers that may differ, those that do.
    let differ = |z: &usize| prints[*z] != old_layers.prints[*z];
    match (
        (first..=last).find(differ),
        (first..=last).rev().find(differ),
    ) {
        (Some(a), Some(b)) => Some(remesh_layers(nb, base, (a, b), prints)),
        _ => Some(unchanged(base)),
    }
}

/// The base itself: nothing a mesh reads changed.
fn unchanged((old, old_layers): (&Mesh, &MeshLayers)) -> Remeshed {
    Remeshed {
        mesh: old.clone(),
        layers: old_layers.clone(),
        reused: LAYERS as u32,
    }
}

/// Re-meshes against `base` when sample layers `first..=last` (indices from local z -1)
/// differ; `prints` are the new neighbourhood's.
fn remesh_layers(
    nb: &Neighborhood,
    base: (&Mesh, &MeshLayers),
    (first, last): (usize, usize),
    prints: [[u64; 2]; DIM_Z],
) -> Remeshed {
    let (old, old_layers) = base;
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
