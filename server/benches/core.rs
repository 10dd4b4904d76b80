//! Costs of the sequencer core: one validated edit end to end (submit with
//! line of sight, then tick with deltas and mesh hashes), raycasts against
//! collision meshes (warm and freshly built; flat ground, generated
//! terrain), and parallel meshing.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use strata_protocol::{EditRequest, PositionUpdate, Role};
use strata_server::collision::{ray_chunks, CollisionCache, CollisionMesh};
use strata_server::sequencer::{Sequencer, SequencerConfig};
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::{Fixed, FixedVec3, StructureLibrary};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::material::ids;
use strata_terrain::mesh::Neighborhood;
use strata_terrain::world::FlatGenerator;
use strata_terrain::world::VoxelRead;
use strata_terrain::{ChunkPos, Edit, MaterialTable, Voxel, VoxelPos, World};

fn world() -> World {
    World::new(Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    }))
}

fn submit_and_tick(c: &mut Criterion) {
    let validation = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: u64::MAX / 2000,
            per_second: 0,
        },
        volume_rate: BucketConfig {
            capacity: u64::MAX / 2000,
            per_second: 0,
        },
        ..Default::default()
    };
    let mut s = Sequencer::new(
        world(),
        SequencerConfig::default(),
        validation,
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    )
    .without_store();
    s.session_joined(1, "p".into(), Role::Player);
    let pos = PositionUpdate {
        seq: 1,
        pos: FixedVec3::from_voxels(100, 0, 100),
    };
    s.update_position(1, pos, 0).unwrap();
    let mut id = 0u64;
    // Alternating mine and build at one spot keeps every edit changing voxels.
    let mut step = move |s: &mut Sequencer| {
        id += 1;
        let center = FixedVec3::from_voxels(100, 0, 105);
        let radius = Fixed::from_voxels(4);
        let edit = if id % 2 == 0 {
            Edit::Build {
                center,
                radius,
                material: ids::DIRT,
                strength: 255,
            }
        } else {
            Edit::Mine {
                center,
                radius,
                strength: 255,
            }
        };
        let request = EditRequest {
            client_edit_id: id,
            edit,
        };
        s.submit(1, request, 0).expect("accepted");
        s.tick(0)
    };
    for _ in 0..2 {
        let out = step(&mut s);
        assert!(!out.applied[0].changes.is_empty(), "edit changes voxels");
    }
    c.bench_function("submit_and_tick_mine_or_build_r4", |b| {
        b.iter(|| black_box(step(&mut s)))
    });
}

fn raycast(c: &mut Criterion) {
    let w = world();
    let mut cache = CollisionCache::default();
    let origin = [10.3, 20.0, 10.7];
    let dir = [0.4, -1.0, 0.3];
    cache.ensure(&w, &ray_chunks(origin, dir, 40.0));
    c.bench_function("raycast_flat_warm", |b| {
        b.iter(|| black_box(cache.raycast(black_box(origin), dir, 40.0)))
    });
}

/// A line-of-sight ray as `submit` casts it: from an eye 2.6 voxels above
/// generated terrain to the ground 7 voxels away.
fn raycast_sight(c: &mut Criterion) {
    let w = World::new(Arc::new(Generator::fractal(GenParams::default()).unwrap()));
    let ground = |x: i32, z: i32| {
        (-64..64)
            .rev()
            .find(|&y| w.voxel(VoxelPos::new(x, y, z)).density > 127)
            .expect("terrain in -64..64") as f64
    };
    let origin = [10.5, ground(10, 10) + 2.6, 10.5];
    let target = [16.5, ground(16, 14) + 0.5, 14.5];
    let dir: [f64; 3] = std::array::from_fn(|i| target[i] - origin[i]);
    let dist = dir.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut cache = CollisionCache::default();
    cache.ensure(&w, &ray_chunks(origin, dir, dist));
    c.bench_function("raycast_terrain_sight_warm", |b| {
        b.iter(|| black_box(cache.raycast(black_box(origin), dir, dist)))
    });
    // The first cast against freshly built meshes, as after an edit.
    let meshes: Vec<CollisionMesh> = ray_chunks(origin, dir, dist)
        .into_iter()
        .map(|p| CollisionMesh::build(p, 0, &Neighborhood::from_world(&w, p)))
        .collect();
    c.bench_function("raycast_terrain_sight_first", |b| {
        b.iter_batched_ref(
            || {
                let mut fresh = CollisionCache::default();
                for m in &meshes {
                    fresh.insert(m.clone());
                }
                fresh
            },
            |fresh| black_box(fresh.raycast(black_box(origin), dir, dist)),
            BatchSize::SmallInput,
        )
    });
}

fn mesh_chunks(c: &mut Criterion) {
    let w = world();
    let jobs: Vec<_> = (0..8)
        .map(|x| {
            let p = ChunkPos::new(x, -1, 0);
            (p, 0, Neighborhood::from_world(&w, p))
        })
        .collect();
    c.bench_function("mesh_chunks_8_flat", |b| {
        b.iter(|| black_box(CollisionCache::mesh_chunks(&jobs)))
    });
}

criterion_group!(
    benches,
    submit_and_tick,
    raycast,
    raycast_sight,
    mesh_chunks
);
criterion_main!(benches);
