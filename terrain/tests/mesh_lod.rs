//! Stride LOD and Transvoxel: no cracks against finer neighbours on any face subset.

use crate::mesh_common;

use mesh_common::*;
use std::collections::HashMap;
use strata_terrain::mesh::volume::weld as key_weld;
use strata_terrain::mesh::{
    mesh_chunk, Mesh, MeshOptions, Neighborhood, VertexKey, TRANSITION_WIDTH,
};
use strata_terrain::ChunkPos;

const SLOPE: f64 = 16.0;
const ISO: f64 = 127.5;
/// Face neighbour offsets in face-bit order -X,+X,-Y,+Y,-Z,+Z.
const DIRS: [[i32; 3]; 6] = [
    [-1, 0, 0],
    [1, 0, 0],
    [0, -1, 0],
    [0, 1, 0],
    [0, 0, -1],
    [0, 0, 1],
];

fn lod(lod: u8, faces: u8) -> MeshOptions {
    MeshOptions {
        lod,
        transition_faces: faces,
        ..MeshOptions::default()
    }
}

/// Is `p` inside the union of the given chunk boxes with some margin on every side?
fn interior(p: [f64; 3], chunks: &[ChunkPos]) -> bool {
    const EPS: f64 = 1e-3;
    (0..8).all(|corner| {
        let q = [0, 1, 2].map(|a| p[a] + if corner >> a & 1 == 1 { EPS } else { -EPS });
        chunks.iter().any(|c| {
            let o = origin_f(*c);
            (0..3).all(|a| q[a] >= o[a] && q[a] <= o[a] + 32.0)
        })
    })
}

/// The triangles of a LOD `k` neighbour mesh with a vertex within one cell (plus one voxel) of
/// the centre chunk (0,0,0), compacted. Speeds the welds up; edges opened by the crop lie
/// outside the centre chunk, and only open edges inside the centre chunk's box are counted.
fn crop(chunk: ChunkPos, m: &Mesh, k: u8) -> Mesh {
    let o = origin_f(chunk);
    let margin = f64::from(1u32 << k) + 1.0;
    let near = |i: u32| {
        let p = m.positions[i as usize];
        (0..3).all(|a| (-margin..=32.0 + margin).contains(&(o[a] + f64::from(p[a]))))
    };
    let mut out = Mesh::default();
    let mut remap = vec![u32::MAX; m.vertex_count()];
    for t in m.indices.chunks_exact(3) {
        if t.iter().any(|&i| near(i)) {
            for &i in t {
                if remap[i as usize] == u32::MAX {
                    remap[i as usize] = out.positions.len() as u32;
                    out.positions.push(m.positions[i as usize]);
                    out.normals.push(m.normals[i as usize]);
                    out.materials.push(m.materials[i as usize]);
                    out.keys.push(m.keys[i as usize]);
                }
                out.indices.push(remap[i as usize]);
            }
        }
    }
    out
}

/// Open edges of the welded union whose midpoints lie inside the union of the chunks and
/// within the centre chunk's box.
fn interior_cracks(parts: &[(ChunkPos, &Mesh)]) -> usize {
    let w = weld(parts);
    let chunks: Vec<ChunkPos> = parts.iter().map(|p| p.0).collect();
    open_edges(&w.indices)
        .into_iter()
        .filter(|&(a, b)| {
            let (pa, pb) = (w.positions[a as usize], w.positions[b as usize]);
            let mid = [0, 1, 2].map(|k| (pa[k] + pb[k]) / 2.0);
            mid.iter().all(|c| (-1e-3..=32.0 + 1e-3).contains(c)) && interior(mid, &chunks)
        })
        .count()
}

/// Zero-area triangles may only appear in transition cells (a third of Lengyel's transition
/// triangles lie in the full-resolution face, and linear data makes their vertices collinear);
/// every such triangle touches a transition face and they stay rare.
fn assert_degenerates_only_on_transition_faces(m: &Mesh, mask: u8) {
    let pos = positions64(m);
    let mut bad = 0;
    for t in m.indices.chunks_exact(3) {
        if min_double_area(&pos, t) > 0.0 {
            continue;
        }
        bad += 1;
        let on_face = t.iter().any(|&i| {
            let p = pos[i as usize];
            (0..6).any(|f| mask >> f & 1 == 1 && p[f / 2] == if f % 2 == 0 { 0.0 } else { 32.0 })
        });
        assert!(
            on_face,
            "zero-area triangle away from the transition faces {mask:06b}"
        );
    }
    assert!(
        bad * 100 <= m.triangle_count(),
        "{bad} zero-area triangles of {}",
        m.triangle_count()
    );
}

/// On a smooth field, facets facing away from their vertex normals may only sit in the
/// transition slabs (Lengyel's cells fold part of the surface into the full-resolution face),
/// never among the shrunk regular cells, and they stay a minority.
fn assert_flips_only_in_transition_slabs(m: &Mesh, plain: &Mesh, k: u8, mask: u8) {
    let s = f64::from(1u32 << k);
    let pos = positions64(m);
    let mut flipped = 0;
    for t in m.indices.chunks_exact(3) {
        let p = [0, 1, 2].map(|i| pos[t[i] as usize]);
        let e1 = [0, 1, 2].map(|a| p[1][a] - p[0][a]);
        let e2 = [0, 1, 2].map(|a| p[2][a] - p[0][a]);
        let g = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let n = [0, 1, 2].map(|a| {
            t.iter()
                .map(|&i| f64::from(m.normals[i as usize][a]))
                .sum::<f64>()
        });
        if g[0] * n[0] + g[1] * n[1] + g[2] * n[2] > 0.0 {
            continue;
        }
        flipped += 1;
        let in_slab = p.iter().all(|q| {
            (0..6).any(|f| {
                let d = if f % 2 == 0 {
                    q[f / 2]
                } else {
                    32.0 - q[f / 2]
                };
                mask >> f & 1 == 1 && d <= s * TRANSITION_WIDTH
            })
        });
        assert!(
            in_slab,
            "lod {k} mask {mask:06b}: flipped facet outside the slabs: {p:?}"
        );
    }
    assert!(
        flipped < m.triangle_count() / 4,
        "lod {k} mask {mask:06b}: {flipped} flipped"
    );
    assert_eq!(
        normal_agreement(plain),
        1.0,
        "lod {k}: without transitions no facet flips"
    );
}

struct Scene {
    centre: Neighborhood,
    around: Vec<(ChunkPos, Neighborhood)>,
}

fn scene(f: &Field) -> Scene {
    let c = ChunkPos::new(0, 0, 0);
    Scene {
        centre: neighborhood(c, f, ISO, SLOPE),
        around: DIRS
            .iter()
            .map(|d| {
                let p = ChunkPos::new(d[0], d[1], d[2]);
                (p, neighborhood(p, f, ISO, SLOPE))
            })
            .collect(),
    }
}

fn fields() -> Vec<Box<Field>> {
    let noise = value_noise(11, 5.0);
    let ball = sphere([16.0, 16.0, 16.0], 21.0);
    let wobbly = value_noise(3, 7.0);
    vec![
        Box::new(noise),
        Box::new(move |p| ball(p) + 4.0 * wobbly(p)),
    ]
}

#[test]
fn every_transition_face_subset_is_crack_free_at_every_lod() {
    for (smooth, f) in [false, true].into_iter().zip(fields()) {
        let s = scene(&*f);
        for k in 1..=3u8 {
            let fine: Vec<Mesh> = s
                .around
                .iter()
                .map(|(p, nb)| crop(*p, &mesh_chunk(nb, &lod(k - 1, 0)), k - 1))
                .collect();
            let same: Vec<Mesh> = s
                .around
                .iter()
                .map(|(p, nb)| crop(*p, &mesh_chunk(nb, &lod(k, 0)), k))
                .collect();
            // Control: without transition cells, finer neighbours leave cracks.
            let plain = mesh_chunk(&s.centre, &lod(k, 0));
            let mut parts = vec![(ChunkPos::new(0, 0, 0), &plain)];
            parts.extend(s.around.iter().zip(&fine).map(|((p, _), m)| (*p, m)));
            assert!(interior_cracks(&parts) > 0, "control at lod {k} must crack");

            for mask in 1..64u8 {
                let m = mesh_chunk(&s.centre, &lod(k, mask));
                assert!(
                    m.triangle_count() > plain.triangle_count(),
                    "lod {k} mask {mask:06b}"
                );
                assert_degenerates_only_on_transition_faces(&m, mask);
                if smooth {
                    assert_flips_only_in_transition_slabs(&m, &plain, k, mask);
                }
                let mut parts = vec![(ChunkPos::new(0, 0, 0), &m)];
                for (i, (p, _)) in s.around.iter().enumerate() {
                    let n = if mask >> i & 1 == 1 {
                        &fine[i]
                    } else {
                        &same[i]
                    };
                    parts.push((*p, n));
                }
                let cracks = interior_cracks(&parts);
                assert_eq!(
                    cracks, 0,
                    "lod {k} mask {mask:06b}: {cracks} open interior edges"
                );
            }
        }
    }
}

/// `p` of a mesh of `chunk` in world units, as the weld computes it.
fn world(chunk: ChunkPos, p: [f32; 3]) -> [f32; 3] {
    let o = chunk.origin();
    [o.x as f32 + p[0], o.y as f32 + p[1], o.z as f32 + p[2]]
}

/// Triangles of the meshes welded by exact world position alone.
fn position_weld(parts: &[(ChunkPos, &Mesh)]) -> Vec<u32> {
    let mut ids: HashMap<[u32; 3], u32> = HashMap::new();
    let mut out = Vec::new();
    for (c, m) in parts {
        for &i in &m.indices {
            let p = world(*c, m.positions[i as usize]).map(f32::to_bits);
            let next = ids.len() as u32;
            out.push(*ids.entry(p).or_insert(next));
        }
    }
    out
}

/// Keys that two meshes put at different world positions.
fn key_conflicts(parts: &[(ChunkPos, &Mesh)]) -> usize {
    let mut seen: HashMap<VertexKey, [f32; 3]> = HashMap::new();
    let mut conflicts = 0;
    for (c, m) in parts {
        for (k, p) in m.keys.iter().zip(&m.positions) {
            let p = world(*c, *p);
            if *seen.entry(*k).or_insert(p) != p {
                conflicts += 1;
            }
        }
    }
    conflicts
}

/// Coarse chunks that touch along a face, an edge or a corner push their
/// shared vertices by transition faces of their own, so one key can name
/// two positions. `volume::weld` keeps those apart: it never moves a
/// vertex, and its seams are no less manifold than an exact-position weld.
#[test]
fn key_weld_of_mixed_lod_meshes_never_moves_a_vertex() {
    let f = value_noise(11, 5.0);
    let a = ChunkPos::new(0, 0, 0);
    let na = neighborhood(a, &f, ISO, SLOPE);
    let few = [
        0u8, 0b000001, 0b000100, 0b010000, 0b101010, 0b010101, 0b111111,
    ];
    let mut conflicts = 0;
    for k in 1..=2u8 {
        let ma: Vec<Mesh> = (0..64).map(|m| mesh_chunk(&na, &lod(k, m))).collect();
        for b in [
            ChunkPos::new(1, 0, 0),
            ChunkPos::new(1, 1, 0),
            ChunkPos::new(0, 1, 1),
            ChunkPos::new(1, 1, 1),
        ] {
            let nb = neighborhood(b, &f, ISO, SLOPE);
            for mask_b in few {
                let mb = mesh_chunk(&nb, &lod(k, mask_b));
                for (mask_a, x) in ma.iter().enumerate() {
                    let parts = [(a, x), (b, &mb)];
                    conflicts += key_conflicts(&parts);
                    let w =
                        key_weld(parts.iter().map(|(c, m)| (c.origin(), (*m).clone()))).unwrap();
                    let inputs = parts.iter().flat_map(|(c, m)| {
                        m.indices
                            .iter()
                            .map(|&i| world(*c, m.positions[i as usize]))
                    });
                    for (j, p) in inputs.enumerate() {
                        assert_eq!(
                            w.positions[w.indices[j] as usize], p,
                            "lod {k} {b:?} masks {mask_a:06b}/{mask_b:06b}: a vertex moved"
                        );
                    }
                    assert!(
                        non_manifold_edges(&w.indices)
                            <= non_manifold_edges(&position_weld(&parts)),
                        "lod {k} {b:?} masks {mask_a:06b}/{mask_b:06b}"
                    );
                }
            }
        }
    }
    assert!(conflicts > 0, "the layouts put one key at two positions");
}
