//! Chunk seams: neighbouring chunks agree bit for bit on shared vertices, and the welded
//! union of separately meshed chunks is watertight, at every LOD.

use crate::mesh_common;

use mesh_common::*;
use strata_terrain::mesh::MeshOptions;
use strata_terrain::ChunkPos;

fn eight_chunks() -> Vec<ChunkPos> {
    (0..8)
        .map(|i| ChunkPos::new(i & 1, (i >> 1) & 1, i >> 2))
        .collect()
}

#[test]
fn two_by_two_by_two_chunks_weld_into_a_closed_surface_at_every_lod() {
    let ball = sphere([32.0, 31.5, 32.5], 19.0);
    let noise = value_noise(5, 6.0);
    let f = move |p: [f64; 3]| ball(p) + 3.0 * noise(p);
    for lod in 0..=3u8 {
        let opts = MeshOptions {
            lod,
            ..MeshOptions::default()
        };
        let meshes: Vec<_> = eight_chunks()
            .into_iter()
            .map(|c| (c, mesh_field(c, &f, 127.5, 16.0, &opts)))
            .collect();
        let parts: Vec<_> = meshes.iter().map(|(c, m)| (*c, m)).collect();
        for (_, m) in &parts {
            assert!(m.triangle_count() > 0, "every chunk holds part of the ball");
        }
        let w = weld(&parts);
        assert!(
            w.shared > 50,
            "lod {lod}: seams must share vertices, got {}",
            w.shared
        );
        assert_watertight(&w.indices);
        assert_eq!(euler(&w.indices), 2, "lod {lod}: one sphere-like surface");
    }
}

#[test]
fn seams_hold_at_non_default_isovalues_and_negative_chunks() {
    let ball = sphere([0.5, -0.5, 0.25], 20.0);
    for iso in [60.0, 200.0] {
        let chunks: Vec<ChunkPos> = (0..8)
            .map(|i| ChunkPos::new((i & 1) - 1, ((i >> 1) & 1) - 1, (i >> 2) - 1))
            .collect();
        let opts = MeshOptions {
            iso: iso as f32,
            ..MeshOptions::default()
        };
        let meshes: Vec<_> = chunks
            .iter()
            .map(|&c| (c, mesh_field(c, &ball, iso, 12.0, &opts)))
            .collect();
        let parts: Vec<_> = meshes.iter().map(|(c, m)| (*c, m)).collect();
        let w = weld(&parts);
        assert_watertight(&w.indices);
        assert_eq!(euler(&w.indices), 2);
    }
}
