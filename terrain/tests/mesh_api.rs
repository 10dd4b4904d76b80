//! Options validation, neighbourhood sampling and per-vertex materials.

use crate::mesh_common;

use mesh_common::*;
use strata_terrain::material::ids;
use strata_terrain::mesh::{
    mesh_chunk, try_mesh_chunk, Mesh, MeshError, MeshOptions, Neighborhood, LOCAL_MAX_Y,
    LOD0_LOCAL_MAX, MAX_SURFACE_SCAN,
};
use strata_terrain::world::FlatGenerator;
use strata_terrain::{Chunk, ChunkPos, Voxel, VoxelPos, VoxelRead, World};

#[test]
fn bad_options_are_rejected_with_reasons() {
    let nb = neighborhood(
        ChunkPos::new(0, 0, 0),
        &sphere([16.0; 3], 10.0),
        127.5,
        16.0,
    );
    let d = MeshOptions::default();
    let cases = [
        (
            MeshOptions { iso: f32::NAN, ..d },
            MeshError::NonFiniteIso(f32::NAN),
        ),
        (MeshOptions { lod: 4, ..d }, MeshError::LodTooHigh(4)),
        (
            MeshOptions {
                lod: 1,
                transition_faces: 0x40,
                ..d
            },
            MeshError::BadFaceBits(0x40),
        ),
        (
            MeshOptions {
                transition_faces: 1,
                ..d
            },
            MeshError::TransitionAtLod0,
        ),
        (
            MeshOptions {
                cell_extent: [33, 32, 32],
                ..d
            },
            MeshError::BadExtent {
                extent: [33, 32, 32],
                stride: 1,
            },
        ),
        (
            MeshOptions {
                lod: 2,
                cell_extent: [32, 6, 32],
                ..d
            },
            MeshError::BadExtent {
                extent: [32, 6, 32],
                stride: 4,
            },
        ),
        (
            MeshOptions {
                lod: 1,
                transition_faces: 1,
                cell_extent: [16, 32, 32],
                ..d
            },
            MeshError::PartialExtentWithTransitions([16, 32, 32]),
        ),
    ];
    for (o, e) in cases {
        let got = try_mesh_chunk(&nb, &o).unwrap_err();
        // NaN != NaN, so compare the message for that one.
        assert_eq!(got.to_string(), e.to_string());
        assert_eq!(
            mesh_chunk(&nb, &o),
            Mesh::default(),
            "invalid options give an empty mesh"
        );
    }
    assert!(try_mesh_chunk(&nb, &d).is_ok());
}

#[test]
fn partial_extent_meshes_only_the_requested_cells() {
    let nb = neighborhood(
        ChunkPos::new(0, 0, 0),
        &sphere([16.0; 3], 10.0),
        127.5,
        16.0,
    );
    let full = mesh_chunk(&nb, &MeshOptions::default());
    let half = mesh_chunk(
        &nb,
        &MeshOptions {
            cell_extent: [16, 32, 32],
            ..MeshOptions::default()
        },
    );
    assert!(half.triangle_count() > 0 && half.triangle_count() < full.triangle_count());
    assert!(half.positions.iter().all(|p| p[0] <= 16.0));
    let none = mesh_chunk(
        &nb,
        &MeshOptions {
            cell_extent: [0, 32, 32],
            ..MeshOptions::default()
        },
    );
    assert!(none.is_empty());
}

#[test]
fn from_world_reads_the_apron_from_neighbour_chunks() {
    let world = World::new(std::sync::Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::DIRT),
    }));
    // Chunk (0,0,0) is all air, but its apron row y = -1 is the ground below.
    let nb = Neighborhood::from_world(&world, ChunkPos::new(0, 0, 0));
    assert_eq!(nb.voxel(5, -1, 5), Some(Voxel::solid(ids::DIRT)));
    assert_eq!(nb.voxel(5, 0, 5), Some(Voxel::AIR));
    assert_eq!(nb.voxel(34, 0, 0), None);
    assert_eq!(nb.voxel(0, 32 + MAX_SURFACE_SCAN, 0), Some(Voxel::AIR));
    assert_eq!(nb.voxel(0, 33 + MAX_SURFACE_SCAN, 0), None);
    // The ground surface lies between y = -1 and y = 0, inside chunk (0,-1,0)'s top cells.
    let below = Neighborhood::from_world(&world, ChunkPos::new(0, -1, 0));
    let m = mesh_chunk(&below, &MeshOptions::default());
    assert_eq!(m.triangle_count(), 32 * 32 * 2);
    assert!(m.positions.iter().all(|p| p[1] == 31.5));
    assert!(m.normals.iter().all(|n| *n == [0.0, 1.0, 0.0]));
    assert!(m.materials.iter().all(|&x| x == ids::DIRT));
    assert!(
        mesh_chunk(&nb, &MeshOptions::default()).is_empty(),
        "air above: no cells cross"
    );
}

/// The server drops a cached LOD-0 mesh only when a voxel up to `LOD0_LOCAL_MAX` changes; the
/// surface-scan rows above feed coarse meshes alone.
#[test]
fn lod0_meshes_ignore_the_surface_scan_rows() {
    let field = value_noise(7, 6.0);
    let (chunk, iso, slope) = (ChunkPos::new(0, 0, 0), 127.5, 16.0);
    let base = neighborhood(chunk, &field, iso, slope);
    // Above LOD0_LOCAL_MAX every sample becomes solid sand: another density and material.
    let origin = chunk.origin();
    let changed = Neighborhood::from_fn(origin, |p| {
        if p.y - origin.y > LOD0_LOCAL_MAX {
            Voxel::solid(ids::SAND)
        } else {
            let v = base.voxel(p.x - origin.x, p.y - origin.y, p.z - origin.z);
            v.expect("inside the held range")
        }
    });
    assert_ne!(base, changed);
    assert_eq!(
        changed.voxel(0, LOD0_LOCAL_MAX + 1, 0),
        Some(Voxel::solid(ids::SAND))
    );
    const { assert!(LOD0_LOCAL_MAX < LOCAL_MAX_Y) };
    let lod0 = MeshOptions::default();
    let m = mesh_chunk(&base, &lod0);
    assert!(m.triangle_count() > 100, "the noise crosses the chunk");
    assert_eq!(m, mesh_chunk(&changed, &lod0));
    assert_eq!(m.hash(), mesh_chunk(&changed, &lod0).hash());
    // At LOD 1 the same rows do count: the surface scan climbs into them.
    let lod1 = MeshOptions { lod: 1, ..lod0 };
    assert_ne!(mesh_chunk(&base, &lod1), mesh_chunk(&changed, &lod1));
}

#[test]
fn row_sampling_matches_per_voxel_sampling() {
    let mut world = World::new(std::sync::Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    }));
    let centre = ChunkPos::new(2, -1, -3);
    let mut n = 0u32;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let p = centre.offset(dx, dy, dz).unwrap();
                if (dx, dy, dz) == (1, 1, 1) {
                    continue; // left unloaded: read as generated
                }
                if (dx, dy, dz) == (-1, 0, 0) {
                    world.insert(p, Chunk::uniform(Voxel::new(77, 4)), 1);
                    continue;
                }
                // Distinct voxels near every face, edge and corner of the centre chunk.
                let mut c = Chunk::clone(&world.chunk(p).chunk);
                for i in 0..40 {
                    n += 1;
                    let (x, y, z) = ((i * 7 + n as usize) % 32, (i * 13) % 32, (i * 29 + 3) % 32);
                    c.set(x, y, z, Voxel::new((n * 37 % 256) as u8, (n % 8) as u8));
                    c.set(0, y, z, Voxel::new(200, 5));
                    c.set(31, 31, z, Voxel::new(150, 6));
                    c.set(x, 0, 31, Voxel::new(129, 7));
                }
                world.insert(p, c, 1);
            }
        }
    }
    // Row copies (dense, uniform, generated chunks) equal one read per voxel.
    let a = Neighborhood::from_world(&world, centre);
    let b = Neighborhood::from_fn(centre.origin(), |p| world.voxel(p));
    assert_eq!(a, b);
    assert_eq!(
        mesh_chunk(&a, &MeshOptions::default()).hash(),
        mesh_chunk(&b, &MeshOptions::default()).hash()
    );
    // Missing chunks read as air.
    let lonely = Neighborhood::from_chunks(centre, |p| {
        (p == centre).then(|| &*world.peek(p).unwrap().chunk)
    });
    assert_eq!(lonely.voxel(-1, 5, 5), Some(Voxel::AIR));
    assert_eq!(lonely.voxel(3, 5, 5), a.voxel(3, 5, 5));
    // Refilling a recycled buffer, left dirty by other chunks, gives the same samples.
    let mut recycled = Neighborhood::from_world(&world, centre.offset(0, 1, 0).unwrap());
    assert_ne!(recycled, a);
    recycled.refill_from_world(&world, centre);
    assert_eq!(recycled, a);
    recycled.refill_from_chunks(centre, |p| {
        (p == centre).then(|| &*world.peek(p).unwrap().chunk)
    });
    assert_eq!(recycled, lonely);
}

/// Hills: grass one voxel thick on dirt three thick on stone.
fn hills_voxel(p: VoxelPos) -> Voxel {
    let noise = value_noise(77, 9.0);
    let h = 14.3 + 6.0 * noise([p.x as f64, 0.0, p.z as f64]);
    let y = p.y as f64;
    let d = density(127.5, 16.0, h - y);
    let m = if y >= h - 1.5 {
        ids::GRASS
    } else if y >= h - 4.5 {
        ids::DIRT
    } else {
        ids::STONE
    };
    Voxel::new(d, m)
}

/// Material of the solid endpoint of a vertex's edge.
fn endpoint_material(nb: &Neighborhood, m: &Mesh, i: usize) -> u8 {
    let k = m.keys[i];
    let o = nb.origin();
    let a = [k.base.x - o.x, k.base.y - o.y, k.base.z - o.z];
    let mut b = a;
    b[k.axis as usize] += k.len as i32;
    let va = nb.voxel(a[0], a[1], a[2]).unwrap();
    let vb = nb.voxel(b[0], b[1], b[2]).unwrap();
    if va.density as f32 > 127.5 {
        va.material
    } else {
        vb.material
    }
}

#[test]
fn lod0_vertex_material_is_the_solid_endpoint_material() {
    let nb = Neighborhood::from_fn(VoxelPos::new(0, 0, 0), hills_voxel);
    let m = mesh_chunk(&nb, &MeshOptions::default());
    assert!(m.triangle_count() > 500);
    for i in 0..m.vertex_count() {
        assert_eq!(m.materials[i], endpoint_material(&nb, &m, i));
    }
    let grass = m.materials.iter().filter(|&&x| x == ids::GRASS).count();
    assert!(
        grass * 10 >= m.vertex_count() * 9,
        "the top of the hills is grass"
    );
}

#[test]
fn coarse_lods_keep_grass_on_top_thanks_to_the_surface_scan() {
    let nb = Neighborhood::from_fn(VoxelPos::new(0, 0, 0), hills_voxel);
    for lod in 1..=3u8 {
        let m = mesh_chunk(
            &nb,
            &MeshOptions {
                lod,
                ..MeshOptions::default()
            },
        );
        let up: Vec<usize> = (0..m.vertex_count())
            .filter(|&i| m.normals[i][1] > 0.7)
            .collect();
        assert!(up.len() > 10, "lod {lod}");
        let scan = up.iter().filter(|&&i| m.materials[i] == ids::GRASS).count();
        let naive = up
            .iter()
            .filter(|&&i| endpoint_material(&nb, &m, i) == ids::GRASS)
            .count();
        assert!(
            scan * 100 >= up.len() * 95,
            "lod {lod}: {scan}/{} grass",
            up.len()
        );
        assert!(
            naive < scan,
            "lod {lod}: the scan must matter ({naive} vs {scan})"
        );
    }
}
