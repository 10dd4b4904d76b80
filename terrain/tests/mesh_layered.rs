//! Re-meshing against a base (`remesh_chunk_layered`) gives exactly the mesh that meshing the
//! whole chunk gives, for changes anywhere: middle, faces, aprons, materials only, to and
//! from an empty mesh, and chains of changes.

use std::ops::RangeInclusive;
use std::sync::Arc;

use strata_terrain::mesh::{
    mesh_chunk, mesh_chunk_layered, remesh_chunk_layered, remesh_chunk_layered_known, remesh_reads,
    Mesh, MeshLayers, MeshOptions, Neighborhood,
};
use strata_terrain::{Chunk, ChunkPos, Voxel, VoxelPos, World};

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

/// 60 chains of 3 random changes to `chunk`, each re-meshed by `remesh(changes so far, base,
/// what)` against the mesh before it, which returns the new mesh and layers and how many
/// layers it copied; most must copy some.
fn random_chains(
    chunk: ChunkPos,
    seed: u64,
    mut remesh: impl FnMut(&[Change], (&Mesh, &MeshLayers), &str) -> (Mesh, MeshLayers, u32),
) {
    let mut rng = Rng(seed);
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
            let what = format!("case {case} step {step}: {changes:?}");
            let (m, l, reused) = remesh(&changes, (&mesh, &layers), &what);
            if reused > 0 {
                reused_some += 1;
            }
            (mesh, layers) = (m, l);
        }
    }
    assert!(reused_some > 60, "most changes reuse layers: {reused_some}");
}

#[test]
fn random_changes_give_the_whole_chunk_mesh() {
    let chunk = ChunkPos::new(2, 0, -3);
    random_chains(chunk, 0x5eed, |changes, base, what| {
        check(&world(chunk, changes), base, what)
    });
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

/// `world(chunk, changes)` where its sample layers (local z) in `held`, and noise elsewhere:
/// what a neighbourhood refilled only in `held` may hold.
fn partly(chunk: ChunkPos, changes: &[Change], held: RangeInclusive<i32>) -> Neighborhood {
    let real = world(chunk, changes);
    let o = chunk.origin();
    Neighborhood::from_fn(o, |p| {
        let l = [p.x - o.x, p.y - o.y, p.z - o.z];
        if held.contains(&l[2]) {
            return real.voxel(l[0], l[1], l[2]).expect("held");
        }
        let h = (l[0] * 131 + l[1] * 71 + l[2] * 29) as u32 % 251;
        Voxel::new(h as u8, (h % 5) as u8)
    })
}

/// The sample layers (local z) a change's box can reach in the neighbourhood.
fn reach(c: &Change) -> RangeInclusive<i32> {
    c.lo[2].max(-1)..=c.hi[2].min(33)
}

#[test]
fn known_changes_need_only_the_layers_they_reach() {
    let chunk = ChunkPos::new(-1, 0, 4);
    random_chains(chunk, 0xbeef, |changes, base, what| {
        let last = changes.last().expect("a change");
        let whole = world(chunk, changes);
        // Only the layers the re-mesh reads are the world's; the rest is noise.
        let nb = partly(chunk, changes, remesh_reads(reach(last)));
        let r =
            remesh_chunk_layered_known(&nb, base, reach(last)).expect("a base of the same chunk");
        let (m, l) = mesh_chunk_layered(&whole);
        assert_eq!(r.mesh, m, "{what}: re-meshed mesh differs");
        assert_eq!(r.mesh, full(&whole), "{what}");
        assert_eq!(r.layers, l, "{what}: layers differ");
        (r.mesh, r.layers, r.reused)
    });
}

#[test]
fn known_changes_outside_the_reach_or_of_another_chunk() {
    let chunk = ChunkPos::new(0, 0, 0);
    let base_nb = world(chunk, &[]);
    let (base, layers) = mesh_chunk_layered(&base_nb);
    // Nothing changed: the base comes back, whatever the neighbourhood holds.
    let noise = partly(chunk, &[], 100..=100);
    let r =
        remesh_chunk_layered_known(&noise, (&base, &layers), RangeInclusive::new(40, 34)).unwrap();
    assert_eq!(
        (r.mesh, r.layers, r.reused),
        (base.clone(), layers.clone(), 32)
    );
    // A change below the held layers reaches from the first layer on.
    let low = Change {
        lo: [0, 10, -9],
        hi: [33, 30, -1],
        rule: 0,
    };
    let nb = partly(chunk, &[low], remesh_reads(-9..=-1));
    let r = remesh_chunk_layered_known(&nb, (&base, &layers), -9..=-1).unwrap();
    assert_eq!(r.mesh, full(&world(chunk, &[low])));
    // A base of another chunk cannot be used.
    let other = world(ChunkPos::new(1, 0, 0), &[]);
    assert!(remesh_chunk_layered_known(&other, (&base, &layers), 0..=3).is_none());
}

#[test]
fn refilling_some_layers_from_the_world_copies_those_layers() {
    #[derive(Debug)]
    struct Ground;
    impl strata_terrain::ChunkGenerator for Ground {
        fn generate(&self, pos: ChunkPos) -> Chunk {
            let mut c = Chunk::uniform(Voxel::new(0, 0));
            for i in 0..32 {
                let v = Voxel::new((pos.x * 7 + pos.y * 13 + pos.z * 29 + i * 5) as u8, 1);
                c.set(i as usize, (i * 3 % 32) as usize, (i * 11 % 32) as usize, v);
            }
            c
        }
    }
    let mut w = World::new(Arc::new(Ground));
    let pos = ChunkPos::new(3, -1, 2);
    // Some chunks held (a modified one among them), the rest generated.
    for (dz, v) in [(-1, 9), (0, 3), (1, 1)] {
        let p = ChunkPos::new(pos.x + 1, pos.y, pos.z + dz);
        w.insert(p, Chunk::uniform(Voxel::new(200, v as u8)), v);
    }
    let expected = Neighborhood::from_world(&w, pos);
    for layers in [-1..=-1, -1..=4, 7..=20, 30..=33, 31..=40, -5..=50] {
        // A buffer that held another chunk's neighbourhood.
        let mut nb = Neighborhood::from_world(&w, ChunkPos::new(-8, 5, 1));
        nb.refill_layers_from_world(&w, pos, layers.clone());
        assert_eq!(nb.origin(), expected.origin());
        let mut kept = 0;
        for z in -1..=33 {
            let same =
                (-1..=40).all(|y| (-1..=33).all(|x| nb.voxel(x, y, z) == expected.voxel(x, y, z)));
            if layers.contains(&z) {
                assert!(same, "layer {z} of {layers:?} copied");
            } else if !same {
                kept += 1;
            }
        }
        // The layers outside were left as they were (another chunk's).
        let outside = (-1..=33).filter(|z| !layers.contains(z)).count();
        assert_eq!(kept, outside, "{layers:?}");
    }
}
