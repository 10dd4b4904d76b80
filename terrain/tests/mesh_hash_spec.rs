//! PROTOCOL.md, "Appendix A: mesh hash encoding", re-implemented from its text alone
//! and checked against `Mesh::hash` (what the server puts in `mesh_hash`).
//! The worked example's bytes and hash are the ones the appendix prints.

use std::sync::Arc;

use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::mesh::{faces, mesh_chunk, Mesh, MeshOptions, Neighborhood};
use strata_terrain::{ChunkPos, Voxel, World};
use twox_hash::XxHash3_64;

/// The appendix's byte string E: V and I as u32 LE; V positions then V
/// normals, three f32 bit patterns (u32 LE) each; V material bytes; I
/// indices as u32 LE.
fn spec_encoding(m: &Mesh) -> Vec<u8> {
    let mut e = Vec::new();
    e.extend_from_slice(&(m.positions.len() as u32).to_le_bytes());
    e.extend_from_slice(&(m.indices.len() as u32).to_le_bytes());
    for v in &m.positions {
        for c in v {
            e.extend_from_slice(&c.to_bits().to_le_bytes());
        }
    }
    for n in &m.normals {
        for c in n {
            e.extend_from_slice(&c.to_bits().to_le_bytes());
        }
    }
    e.extend_from_slice(&m.materials);
    for i in &m.indices {
        e.extend_from_slice(&i.to_le_bytes());
    }
    assert_eq!(e.len(), 8 + 25 * m.positions.len() + 4 * m.indices.len());
    e
}

/// XXH3-64 with seed 0.
fn spec_hash(m: &Mesh) -> u64 {
    XxHash3_64::oneshot_with_seed(0, &spec_encoding(m))
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[test]
fn the_worked_example_has_the_printed_bytes_and_hash() {
    let m = Mesh {
        positions: vec![[0.5, 2.0, 0.0], [1.0, 2.0, 0.0], [0.5, 2.0, -1.0]],
        normals: vec![[0.0, 1.0, 0.0]; 3],
        materials: vec![1, 1, 3],
        indices: vec![0, 2, 1],
        keys: Vec::new(),
    };
    let e = spec_encoding(&m);
    println!("{}", hex(&e));
    println!("{:#018x}", spec_hash(&m));
    let printed = "03 00 00 00 03 00 00 00 \
        00 00 00 3f 00 00 00 40 00 00 00 00 \
        00 00 80 3f 00 00 00 40 00 00 00 00 \
        00 00 00 3f 00 00 00 40 00 00 80 bf \
        00 00 00 00 00 00 80 3f 00 00 00 00 \
        00 00 00 00 00 00 80 3f 00 00 00 00 \
        00 00 00 00 00 00 80 3f 00 00 00 00 \
        01 01 03 \
        00 00 00 00 02 00 00 00 01 00 00 00";
    assert_eq!(
        hex(&e),
        printed.split_whitespace().collect::<Vec<_>>().join(" ")
    );
    assert_eq!(e, m.hash_encoding());
    assert_eq!(spec_hash(&m), m.hash());
    assert_eq!(m.hash(), EXAMPLE_HASH);
}

/// The hash PROTOCOL.md prints for the worked example.
const EXAMPLE_HASH: u64 = 0xe93e_340f_a5a4_02cd;

#[test]
fn an_empty_mesh_is_eight_zero_bytes() {
    let m = Mesh::default();
    assert_eq!(spec_encoding(&m), [0u8; 8]);
    assert_eq!(spec_hash(&m), m.hash());
    assert_eq!(m.hash(), EMPTY_HASH);
    // A chunk with no surface meshes to nothing.
    let air = Neighborhood::from_fn(ChunkPos::new(0, 0, 0).origin(), |_| Voxel::AIR);
    assert_eq!(mesh_chunk(&air, &MeshOptions::default()).hash(), EMPTY_HASH);
}

/// The hash PROTOCOL.md prints for an empty mesh.
const EMPTY_HASH: u64 = 0xc77b_3abb_6f87_acd9;

/// A ball of stone at (cx, cy, cz), radius r, sampled into a neighbourhood.
fn ball(chunk: ChunkPos, c: [f64; 3], r: f64) -> Neighborhood {
    Neighborhood::from_fn(chunk.origin(), |p| {
        let d = ((p.x as f64 - c[0]).powi(2)
            + (p.y as f64 - c[1]).powi(2)
            + (p.z as f64 - c[2]).powi(2))
        .sqrt();
        let density = (127.5 + 24.0 * (r - d)).clamp(0.0, 255.0) as u8;
        Voxel::new(density, if p.y > c[1] as i32 { 1 } else { 3 })
    })
}

#[test]
fn the_spec_matches_real_meshes() {
    let lod0 = mesh_chunk(
        &ball(ChunkPos::new(0, 0, 0), [15.3, 17.1, 14.6], 9.4),
        &MeshOptions::default(),
    );
    assert!(lod0.triangle_count() > 100);
    assert_eq!(spec_hash(&lod0), lod0.hash());

    // A chunk cut by a ball centred in its neighbour: vertices on its faces.
    let cut = mesh_chunk(
        &ball(ChunkPos::new(1, 0, 0), [30.0, 16.0, 16.0], 12.0),
        &MeshOptions::default(),
    );
    assert!(cut.triangle_count() > 10);
    assert_eq!(spec_hash(&cut), cut.hash());

    // Coarse, with transition faces: the encoding does not depend on how
    // the mesh was made.
    let coarse = mesh_chunk(
        &ball(ChunkPos::new(0, 0, 0), [16.0, 16.0, 16.0], 14.0),
        &MeshOptions {
            lod: 2,
            transition_faces: faces::NEG_X | faces::POS_Y,
            ..MeshOptions::default()
        },
    );
    assert!(coarse.triangle_count() > 10);
    assert_eq!(spec_hash(&coarse), coarse.hash());
}

#[test]
fn the_spec_matches_a_surface_chunk_of_the_default_world() {
    // The mesh the server hashes for `mesh_hash`: LOD 0, default options,
    // the chunk and its 26 neighbours.
    let generator = Generator::fractal(GenParams::default()).unwrap();
    let y = generator.surface_height(8, 8).floor() as i32;
    let world = World::new(Arc::new(generator));
    let pos = ChunkPos::new(0, y.div_euclid(32), 0);
    let m = mesh_chunk(
        &Neighborhood::from_world(&world, pos),
        &MeshOptions::default(),
    );
    assert!(m.triangle_count() > 100);
    assert_eq!(spec_hash(&m), m.hash());
}
