//! Costs of the sequencer core: one validated edit end to end (submit with
//! line of sight, then tick with deltas and mesh hashes), raycasts against
//! collision meshes (warm and freshly built; flat ground, generated
//! terrain), parallel meshing, and an eviction pass among 3000 players.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use strata_protocol::{EditRequest, PositionUpdate, Role};
use strata_server::collision::{ray_chunks, CollisionCache, CollisionMesh, MeshJob};
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
            let pos = ChunkPos::new(x, -1, 0);
            MeshJob {
                pos,
                version: 0,
                nb: Neighborhood::from_world(&w, pos),
                base: None,
                known: None,
                sources: None,
            }
        })
        .collect();
    c.bench_function("mesh_chunks_8_flat", |b| {
        b.iter(|| black_box(CollisionCache::mesh_chunks(&jobs)))
    });
}

/// A sequencer as a busy server holds it: `players` sessions standing
/// apart over a square of chunk columns, everything within two chunks of
/// them resident, and one queued edit for each of the first `queued`.
fn crowded(players: u64, queued: u64) -> Sequencer {
    let validation = ValidationConfig {
        edit_rate: BucketConfig {
            capacity: 1 << 40,
            per_second: 0,
        },
        volume_rate: BucketConfig {
            capacity: 1 << 40,
            per_second: 0,
        },
        ..Default::default()
    };
    let cfg = SequencerConfig {
        queue_capacity: 1 << 20,
        ..Default::default()
    };
    let mut s = Sequencer::new(
        world(),
        cfg,
        validation,
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    );
    // 3000 players over 64 × 64 columns hold about 21 000 chunks hot, as
    // 3000 bots did on the 16-core machine.
    let side = ((players as f64 * 4096.0 / 3000.0).sqrt() as u64).max(1) * 32;
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng % side) as i32
    };
    for id in 1..=players {
        s.session_joined(id, format!("p{id}"), Role::Player);
        let (x, z) = (next(), next());
        let pos = PositionUpdate {
            seq: 1,
            pos: FixedVec3::from_voxels(x, 0, z),
        };
        let around = ChunkPos::new(x.div_euclid(32), 0, z.div_euclid(32));
        for dz in -2..=2 {
            for dy in -2..=2 {
                for dx in -2..=2 {
                    if let Some(p) = around.offset(dx, dy, dz) {
                        if !s.is_resident(p) {
                            s.mark_absent(p);
                        }
                    }
                }
            }
        }
        s.update_position(id, pos, 0).expect("position");
        if id <= queued {
            let request = EditRequest {
                client_edit_id: id,
                edit: Edit::Mine {
                    center: FixedVec3::from_voxels(x + 3, -1, z + 2),
                    radius: Fixed::from_voxels(4),
                    strength: 255,
                },
            };
            for p in s.chunks_needed(id, &request.edit) {
                s.mark_absent(p);
            }
            s.submit(id, request, 0).expect("accepted");
        }
    }
    s
}

/// One eviction pass when every resident chunk is near a player, so
/// nothing is dropped and every pass does the same work.
fn evict_pass(c: &mut Criterion) {
    for (players, queued) in [(3000, 30), (3000, 3000)] {
        let mut s = crowded(players, queued);
        let resident = s.resident();
        assert!(s.evict_far_from_players(2).is_empty());
        assert_eq!(s.resident(), resident);
        c.bench_function(
            &format!("evict_pass_{players}_players_{queued}_queued_{resident}_resident"),
            |b| b.iter(|| black_box(s.evict_far_from_players(2))),
        );
    }
}

criterion_group!(
    benches,
    submit_and_tick,
    raycast,
    raycast_sight,
    mesh_chunks,
    evict_pass
);
criterion_main!(benches);
