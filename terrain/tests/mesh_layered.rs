//! Re-meshing against a base (`remesh_chunk_layered`) gives exactly the mesh that meshing the
//! whole chunk gives, for changes anywhere: middle, faces, aprons, materials only, to and
//! from an empty mesh, and chains of changes.

use strata_terrain::mesh::{
    mesh_chunk, mesh_chunk_layered, remesh_chunk_layered, Mesh, MeshLayers, MeshOptions,
    Neighborhood,
};
use strata_terrain::{ChunkPos, Voxel, VoxelPos};

use crate::mesh_common::value_noise;

/// Small deterministic generator (splitmix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn range(&mut self, lo: i32, hi: i32) -> i32 {
        lo + (self.next() % (hi - lo + 1) as u64) as i32
    }
}

/// One change: voxels of a box set by a rule (carve, fill or repaint).
#[derive(Clone, Copy, Debug)]
struct Change {
    lo: [i32; 3],
    hi: [i32; 3],
    rule: u8,
}

/// A rolling ground with noise, in world voxels.
fn ground(p: VoxelPos) -> Voxel {
    let n = value_noise(7, 6.0)([p.x as f64, p.y as f64, p.z as f64]);
    let s = 20.0 - p.y as f64 + 6.0 * n;
    let d = (127.5 + 40.0 * s).clamp(0.0, 255.0) as u8;
    Voxel::new(d, if n > 0.2 { 3 } else { 2 })
}

/// The world after `changes`, each applied in order over the chunk-local box it names.
fn world(chunk: ChunkPos, changes: &[Change]) -> Neighborhood {
    let o = chunk.origin();
    Neighborhood::from_fn(o, |p| {
        let mut v = ground(p);
        let l = [p.x - o.x, p.y - o.y, p.z - o.z];
        for c in changes {
            if (0..3).all(|i| (c.lo[i]..=c.hi[i]).contains(&l[i])) {
                let h = (l[0] * 31 + l[1] * 17 + l[2] * 7) as u32 % 97;
                v = match c.rule {
                    0 => Voxel::new(0, 0),
                    1 => Voxel::new(255, 4),
                    2 => Voxel::new(v.density, 5),
                    _ => Voxel::new((h * 255 / 96) as u8, (h % 4) as u8),
                };
            }
        }
        v
    })
}

fn full(nb: &Neighborhood) -> Mesh {
    mesh_chunk(nb, &MeshOptions::default())
}

/// Re-meshes `nb` against `base` and checks mesh and layers against meshing it whole.
fn check(nb: &Neighborhood, base: (&Mesh, &MeshLayers), what: &str) -> (Mesh, MeshLayers, u32) {
    let r = remesh_chunk_layered(nb, base);
    let (whole, layers) = mesh_chunk_layered(nb);
    assert_eq!(
        whole,
        full(nb),
        "{what}: layered meshing differs from mesh_chunk"
    );
    assert_eq!(r.mesh, whole, "{what}: re-meshed mesh differs");
    assert_eq!(r.mesh.hash(), whole.hash(), "{what}");
    assert_eq!(r.layers, layers, "{what}: layers differ");
    (r.mesh, r.layers, r.reused)
}

#[test]
fn random_changes_give_the_whole_chunk_mesh() {
    let chunk = ChunkPos::new(2, 0, -3);
    let mut rng = Rng(0x5eed);
    let mut reused_some = 0;
    for case in 0..60 {
        let mut changes = Vec::new();
        let (mut mesh, mut layers) = mesh_chunk_layered(&world(chunk, &changes));
        // A chain of changes, each meshed against the previous result.
        for step in 0..3 {
            let size = [rng.range(0, 6), rng.range(0, 6), rng.range(0, 6)];
            // Anywhere the neighbourhood holds: local -1..=33 (y: the ground is near 20).
            let lo = [rng.range(-1, 33), rng.range(8, 30), rng.range(-1, 33)];
            let hi = std::array::from_fn(|i| lo[i] + size[i]);
            changes.push(Change {
                lo,
                hi,
                rule: (rng.next() % 4) as u8,
            });
            let nb = world(chunk, &changes);
            let what = format!("case {case} step {step}: {changes:?}");
            let (m, l, reused) = check(&nb, (&mesh, &layers), &what);
            if reused > 0 {
                reused_some += 1;
            }
            (mesh, layers) = (m, l);
        }
    }
    assert!(reused_some > 60, "most changes reuse layers: {reused_some}");
}

#[test]
fn edge_cases_give_the_whole_chunk_mesh() {
    let chunk = ChunkPos::new(0, 0, 0);
    let at = |lo: [i32; 3], hi: [i32; 3], rule: u8| Change { lo, hi, rule };
    let base_nb = world(chunk, &[]);
    let (base, layers) = mesh_chunk_layered(&base_nb);
    assert!(!base.indices.is_empty());

    // Nothing the mesh reads changed: the base comes back whole.
    let (_, _, reused) = check(&base_nb, (&base, &layers), "unchanged");
    assert_eq!(reused, 32);
    // Only rows above the LOD-0 reach (surface-scan rows) changed.
    let high = world(chunk, &[at([0, 35, 0], [33, 40, 33], 1)]);
    assert_eq!(check(&high, (&base, &layers), "scan rows").2, 32);

    // Materials only, in the middle: most layers reused.
    let paint = world(chunk, &[at([0, 0, 14], [33, 33, 16], 2)]);
    let (_, _, reused) = check(&paint, (&base, &layers), "materials");
    assert!(reused >= 20, "{reused}");

    // Each apron layer alone, and the first and last sample layers.
    for z in [-1, 0, 1, 31, 32, 33] {
        let nb = world(chunk, &[at([0, 10, z], [33, 30, z], 3)]);
        check(&nb, (&base, &layers), &format!("layer {z}"));
    }

    // To an empty mesh (all air) and back from it.
    let air = world(chunk, &[at([-1, -1, -1], [33, 40, 33], 0)]);
    let (empty, empty_layers, _) = check(&air, (&base, &layers), "to air");
    assert!(empty.indices.is_empty());
    let pocket = world(
        chunk,
        &[
            at([-1, -1, -1], [33, 40, 33], 0),
            at([10, 10, 10], [14, 14, 14], 1),
        ],
    );
    let (m, _, reused) = check(&pocket, (&empty, &empty_layers), "from air");
    assert!(!m.indices.is_empty());
    assert!(reused > 0);

    // And to no surface at all from a change that spans few layers.
    let (pocket_mesh, pocket_layers) = mesh_chunk_layered(&pocket);
    let (m, _, reused) = check(&air, (&pocket_mesh, &pocket_layers), "pocket gone");
    assert!(m.indices.is_empty());
    assert!(reused > 0);

    // A base of another chunk is not reused.
    let other = ChunkPos::new(1, 0, 0);
    let other_nb = world(other, &[at([3, 18, 3], [6, 22, 6], 0)]);
    assert_eq!(
        check(&other_nb, (&base, &layers), "other chunk").2,
        0,
        "another chunk's base meshes everything"
    );
}
