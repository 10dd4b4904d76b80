//! Shared helpers for the mesh tests: analytic fields, welding and topology checks.
#![allow(dead_code)]

use std::collections::HashMap;

use strata_terrain::mesh::{mesh_chunk, Mesh, MeshOptions, Neighborhood, VertexKey};
use strata_terrain::{ChunkPos, Voxel, VoxelPos};

/// A signed "solidness" field in world voxel coordinates: positive inside.
pub type Field = dyn Fn([f64; 3]) -> f64 + Sync;

/// Density of a field value: `iso + slope * s`, rounded and clamped to u8.
pub fn density(iso: f64, slope: f64, s: f64) -> u8 {
    (iso + slope * s + 0.5).floor().clamp(0.0, 255.0) as u8
}

/// Neighborhood of `chunk` sampling `f` with the given iso/slope; material 3 (stone)
/// everywhere, except material 1 (grass) on the top two solid voxels under air.
pub fn neighborhood(chunk: ChunkPos, f: &Field, iso: f64, slope: f64) -> Neighborhood {
    Neighborhood::from_fn(chunk.origin(), |p| {
        let at = |dy: i32| [p.x as f64, (p.y + dy) as f64, p.z as f64];
        let d = density(iso, slope, f(at(0)));
        let above = density(iso, slope, f(at(2)));
        let m = if (above as f64) <= iso { 1 } else { 3 };
        Voxel::new(d, m)
    })
}

pub fn mesh_field(chunk: ChunkPos, f: &Field, iso: f64, slope: f64, opts: &MeshOptions) -> Mesh {
    mesh_chunk(&neighborhood(chunk, f, iso, slope), opts)
}

pub fn sphere(c: [f64; 3], r: f64) -> impl Fn([f64; 3]) -> f64 + Sync {
    move |p| {
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        r - (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    }
}

/// Torus around the y axis through `c`: ring radius `big`, tube radius `small`.
pub fn torus(c: [f64; 3], big: f64, small: f64) -> impl Fn([f64; 3]) -> f64 + Sync {
    move |p| {
        let (x, y, z) = (p[0] - c[0], p[1] - c[1], p[2] - c[2]);
        let q = (x * x + z * z).sqrt() - big;
        small - (q * q + y * y).sqrt()
    }
}

/// Deterministic lattice value noise in [-1, 1], trilinear between lattice points `cell` apart.
pub fn value_noise(seed: u64, cell: f64) -> impl Fn([f64; 3]) -> f64 + Sync {
    move |p| {
        let h = |x: i64, y: i64, z: i64| {
            let mut v = seed ^ (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            v ^= (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            v ^= (z as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
            v ^= v >> 31;
            v = v.wrapping_mul(0xD6E8_FEB8_6659_FD93);
            v ^= v >> 32;
            (v & 0xFFFF) as f64 / 32767.5 - 1.0
        };
        let g = p.map(|c| c / cell);
        let b = g.map(|c| c.floor());
        let f = [g[0] - b[0], g[1] - b[1], g[2] - b[2]];
        let s = f.map(|t| t * t * (3.0 - 2.0 * t));
        let (bx, by, bz) = (b[0] as i64, b[1] as i64, b[2] as i64);
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let mut acc = [0.0; 4];
        for (i, a) in acc.iter_mut().enumerate() {
            let (dy, dz) = ((i & 1) as i64, (i >> 1) as i64);
            *a = lerp(h(bx, by + dy, bz + dz), h(bx + 1, by + dy, bz + dz), s[0]);
        }
        lerp(lerp(acc[0], acc[1], s[1]), lerp(acc[2], acc[3], s[1]), s[2])
    }
}

/// Undirected edge -> (count of a->b with a<b, count of b->a).
fn edge_uses(indices: &[u32]) -> HashMap<(u32, u32), (u32, u32)> {
    let mut m: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
    for t in indices.chunks_exact(3) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let e = m.entry((a.min(b), a.max(b))).or_default();
            if a < b {
                e.0 += 1
            } else {
                e.1 += 1
            }
        }
    }
    m
}

/// Every edge is used by exactly two triangles, in opposite directions.
pub fn assert_watertight(indices: &[u32]) {
    assert!(!indices.is_empty(), "mesh is empty");
    for (e, (f, b)) in edge_uses(indices) {
        assert!(
            f == 1 && b == 1,
            "edge {e:?} used {f} forward and {b} backward"
        );
    }
}

/// Edges not matched by exactly one opposite edge.
pub fn open_edges(indices: &[u32]) -> Vec<(u32, u32)> {
    let mut v: Vec<_> = edge_uses(indices)
        .into_iter()
        .filter(|(_, (f, b))| !(*f == 1 && *b == 1))
        .map(|(e, _)| e)
        .collect();
    v.sort();
    v
}

/// Edges used by more than two triangles.
pub fn non_manifold_edges(indices: &[u32]) -> usize {
    edge_uses(indices)
        .values()
        .filter(|(f, b)| f + b > 2)
        .count()
}

/// V - E + F over the vertices the triangles use.
pub fn euler(indices: &[u32]) -> i64 {
    let mut verts: Vec<u32> = indices.to_vec();
    verts.sort();
    verts.dedup();
    let e = edge_uses(indices).len() as i64;
    verts.len() as i64 - e + (indices.len() / 3) as i64
}

fn tri(pos: &[[f64; 3]], t: &[u32]) -> ([f64; 3], [f64; 3], [f64; 3]) {
    (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize])
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn positions64(m: &Mesh) -> Vec<[f64; 3]> {
    m.positions.iter().map(|p| p.map(f64::from)).collect()
}

/// Total area and enclosed (signed, positive when wound CCW from outside) volume.
pub fn area_volume(pos: &[[f64; 3]], indices: &[u32]) -> (f64, f64) {
    let (mut area, mut vol) = (0.0, 0.0);
    for t in indices.chunks_exact(3) {
        let (a, b, c) = tri(pos, t);
        let n = cross(sub(b, a), sub(c, a));
        area += dot(n, n).sqrt() / 2.0;
        vol += dot(a, cross(b, c)) / 6.0;
    }
    (area, vol)
}

/// Smallest doubled triangle area (exact for the mesher's dyadic positions).
pub fn min_double_area(pos: &[[f64; 3]], indices: &[u32]) -> f64 {
    indices
        .chunks_exact(3)
        .map(|t| {
            let (a, b, c) = tri(pos, t);
            let n = cross(sub(b, a), sub(c, a));
            dot(n, n).sqrt()
        })
        .fold(f64::INFINITY, f64::min)
}

/// Normals are unit length and face the same side as their triangles' geometric normals.
pub fn assert_normals_agree(m: &Mesh) {
    assert_normals_agree_pct(m, 99);
}

/// Like [`assert_normals_agree`], for at least `pct` percent of the triangles.
pub fn assert_normals_agree_pct(m: &Mesh, pct: usize) {
    let r = normal_agreement(m);
    assert!(
        r * 100.0 >= pct as f64,
        "only {:.2}% of triangles face their normals",
        r * 100.0
    );
}

/// Checks normals are unit length; returns the fraction of triangles whose geometric normal
/// faces the same side as their vertex normals.
pub fn normal_agreement(m: &Mesh) -> f64 {
    let pos = positions64(m);
    for n in &m.normals {
        let l = n
            .iter()
            .map(|c| (*c as f64) * (*c as f64))
            .sum::<f64>()
            .sqrt();
        assert!((l - 1.0).abs() < 1e-5, "normal {n:?} not unit");
    }
    let mut agree = 0usize;
    for t in m.indices.chunks_exact(3) {
        let (a, b, c) = tri(&pos, t);
        let g = cross(sub(b, a), sub(c, a));
        let avg = [0, 1, 2].map(|k| {
            t.iter()
                .map(|&i| m.normals[i as usize][k] as f64)
                .sum::<f64>()
        });
        if dot(g, avg) > 0.0 {
            agree += 1;
        }
    }
    agree as f64 / m.triangle_count().max(1) as f64
}

/// Welds meshes of several chunks by vertex key. Returns world positions, normals, materials
/// and the re-indexed triangles; panics if two meshes disagree on a shared vertex.
pub struct Welded {
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub materials: Vec<u8>,
    pub keys: Vec<VertexKey>,
    pub indices: Vec<u32>,
    pub shared: usize,
}

pub fn weld(parts: &[(ChunkPos, &Mesh)]) -> Welded {
    let mut ids: HashMap<VertexKey, u32> = HashMap::new();
    let mut w = Welded {
        positions: vec![],
        normals: vec![],
        materials: vec![],
        keys: vec![],
        indices: vec![],
        shared: 0,
    };
    for (chunk, m) in parts {
        let o = chunk.origin();
        let remap: Vec<u32> = (0..m.vertex_count())
            .map(|i| {
                let p = m.positions[i];
                // Exact: positions are dyadic with few bits.
                let world = [o.x as f32 + p[0], o.y as f32 + p[1], o.z as f32 + p[2]];
                let world64 = world.map(f64::from);
                let key = m.keys[i];
                match ids.get(&key) {
                    Some(&id) => {
                        assert_eq!(
                            w.positions[id as usize], world64,
                            "position differs for {key:?}"
                        );
                        assert_eq!(
                            w.normals[id as usize], m.normals[i],
                            "normal differs for {key:?}"
                        );
                        assert_eq!(
                            w.materials[id as usize], m.materials[i],
                            "material differs for {key:?}"
                        );
                        w.shared += 1;
                        id
                    }
                    None => {
                        let id = w.positions.len() as u32;
                        ids.insert(key, id);
                        w.positions.push(world64);
                        w.normals.push(m.normals[i]);
                        w.materials.push(m.materials[i]);
                        w.keys.push(key);
                        id
                    }
                }
            })
            .collect();
        w.indices
            .extend(m.indices.iter().map(|&i| remap[i as usize]));
    }
    w
}

pub fn origin_f(c: ChunkPos) -> [f64; 3] {
    let o: VoxelPos = c.origin();
    [o.x as f64, o.y as f64, o.z as f64]
}
