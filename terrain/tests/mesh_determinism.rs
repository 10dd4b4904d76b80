//! Golden mesh hashes and thread-count independence.

use crate::mesh_common;

use mesh_common::*;
use rayon::prelude::*;
use strata_terrain::mesh::{faces, mesh_chunk, Mesh, MeshOptions, Neighborhood};
use strata_terrain::ChunkPos;

fn golden_cases() -> Vec<(&'static str, Mesh)> {
    let ball = sphere([16.0, 16.0, 16.0], 12.0);
    let noise = value_noise(42, 6.0);
    let hills = move |p: [f64; 3]| 12.0 + 5.0 * noise([p[0], 0.0, p[2]]) - p[1];
    let c = ChunkPos::new(0, 0, 0);
    let lod = |lod, faces| MeshOptions {
        lod,
        transition_faces: faces,
        ..MeshOptions::default()
    };
    vec![
        (
            "sphere lod0",
            mesh_field(c, &ball, 127.5, 16.0, &MeshOptions::default()),
        ),
        (
            "sphere iso 80",
            mesh_field(
                c,
                &ball,
                80.0,
                16.0,
                &MeshOptions {
                    iso: 80.0,
                    ..Default::default()
                },
            ),
        ),
        (
            "hills lod0",
            mesh_field(ChunkPos::new(-1, 0, 2), &hills, 127.5, 16.0, &lod(0, 0)),
        ),
        ("hills lod2", mesh_field(c, &hills, 127.5, 16.0, &lod(2, 0))),
        (
            "sphere lod1 transitions",
            mesh_field(
                c,
                &ball,
                127.5,
                16.0,
                &lod(1, faces::NEG_X | faces::POS_Y | faces::POS_Z),
            ),
        ),
    ]
}

#[test]
fn golden_mesh_hashes() {
    // Pinned: meshes are compared between server and client by these hashes.
    let expected: [u64; 5] = [
        0xd6c7f3b887825c14,
        0x0710fc2d832d2b89,
        0xeab800c89019136e,
        0xa3f5598fda501876,
        0xfd2193e7f11e2fb4,
    ];
    let got: Vec<u64> = golden_cases().iter().map(|(_, m)| m.hash()).collect();
    for ((name, m), (g, e)) in golden_cases().iter().zip(got.iter().zip(expected)) {
        assert!(m.triangle_count() > 0, "{name}");
        assert_eq!(*g, e, "{name}: got {g:#018x}");
    }
}

#[test]
fn hash_covers_every_field_but_keys() {
    let m = golden_cases().remove(0).1;
    let h = m.hash();
    let mut k = m.clone();
    k.keys.reverse();
    assert_eq!(k.hash(), h, "keys are not hashed");
    let mut p = m.clone();
    p.positions[3][1] += 0.25;
    let mut n = m.clone();
    n.normals[0][0] = -n.normals[0][0];
    let mut mat = m.clone();
    mat.materials[5] ^= 1;
    let mut i = m.clone();
    i.indices.swap(0, 1);
    for changed in [p, n, mat, i] {
        assert_ne!(changed.hash(), h);
    }
    // The documented encoding: counts, positions, normals, materials, indices.
    let e = m.hash_encoding();
    let v = m.vertex_count();
    assert_eq!(e.len(), 8 + v * 24 + v + m.indices.len() * 4);
    assert_eq!(e[..4], (v as u32).to_le_bytes());
    assert_eq!(e[8..12], m.positions[0][0].to_bits().to_le_bytes());
    assert_eq!(
        e[8 + v * 12..8 + v * 12 + 4],
        m.normals[0][0].to_bits().to_le_bytes()
    );
    assert_eq!(e[8 + v * 24], m.materials[0]);
    assert_eq!(strata_terrain::hash::hash_bytes(&e), h);
}

#[test]
fn one_thread_and_many_give_identical_meshes() {
    let noise = value_noise(9, 7.0);
    let f = move |p: [f64; 3]| 20.0 + 10.0 * noise(p) - p[1] * 0.5;
    let chunks: Vec<ChunkPos> = (0..12)
        .map(|i| ChunkPos::new(i % 3 - 1, (i / 3) % 2, i / 6))
        .collect();
    let nbs: Vec<(ChunkPos, Neighborhood)> = chunks
        .iter()
        .map(|&c| (c, neighborhood(c, &f, 127.5, 16.0)))
        .collect();
    let opts = |i: usize| MeshOptions {
        lod: (i % 4) as u8,
        transition_faces: if i % 4 == 0 { 0 } else { (i * 13 % 64) as u8 },
        ..MeshOptions::default()
    };
    let serial: Vec<u64> = nbs
        .iter()
        .enumerate()
        .map(|(i, (_, nb))| mesh_chunk(nb, &opts(i)).hash())
        .collect();
    for threads in [1, 4] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let par: Vec<u64> = pool.install(|| {
            nbs.par_iter()
                .enumerate()
                .map(|(i, (_, nb))| mesh_chunk(nb, &opts(i)).hash())
                .collect()
        });
        assert_eq!(par, serial, "{threads} threads");
    }
    assert!(
        serial
            .iter()
            .filter(|&&h| h != Mesh::default().hash())
            .count()
            >= 6
    );
}
