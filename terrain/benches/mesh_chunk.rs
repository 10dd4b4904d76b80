//! Per-chunk meshing speed. Target: <= 60 µs median for a terrain surface chunk at LOD 0
//! (welded, with normals). Fields are analytic so this does not depend on world generation.
//!
//! Times are the benchmark thread's own CPU time (from `/proc/thread-self/schedstat`, Linux),
//! not wall-clock time, so other processes competing for the machine's cores do not inflate
//! them. Elsewhere the wall clock is used.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, SamplingMode};
use strata_terrain::mesh::{
    mesh_chunk, mesh_chunk_layered, remesh_chunk_layered, MeshOptions, Neighborhood, ALL_FACES,
};
use strata_terrain::{Chunk, ChunkPos, Voxel};

#[path = "../tests/mesh_common/mod.rs"]
mod mesh_common;
use mesh_common::{neighborhood, sphere, value_noise};

fn terrain() -> Neighborhood {
    terrain_dug(None)
}

/// The terrain field, with a ball of `(centre, radius)` made air.
fn terrain_dug(pit: Option<([f64; 3], f64)>) -> Neighborhood {
    let n = value_noise(1, 24.0);
    let d = value_noise(2, 7.0);
    let f = move |p: [f64; 3]| {
        let xz = [p[0], 0.0, p[2]];
        let ground = 16.0 + 9.0 * n(xz) + 2.0 * d(xz) - p[1];
        match pit {
            // Air inside the ball, the terrain unchanged outside it.
            Some((c, r)) if sphere(c, r)(p) >= 0.0 => -8.0,
            _ => ground,
        }
    };
    neighborhood(ChunkPos::new(0, 0, 0), &f, 127.5, 16.0)
}

fn cave() -> Neighborhood {
    let n = value_noise(3, 9.0);
    let f = move |p: [f64; 3]| 6.0 * n(p) + 1.5;
    neighborhood(ChunkPos::new(0, -2, 0), &f, 127.5, 16.0)
}

fn ball() -> Neighborhood {
    neighborhood(
        ChunkPos::new(0, 0, 0),
        &sphere([16.0, 16.0, 16.0], 13.0),
        127.5,
        16.0,
    )
}

fn worst() -> Neighborhood {
    let n = value_noise(4, 1.5);
    neighborhood(
        ChunkPos::new(0, 0, 0),
        &(move |p: [f64; 3]| 8.0 * n(p)),
        127.5,
        16.0,
    )
}

/// CPU time this thread has run, in nanoseconds, if the kernel reports it.
fn thread_cpu_ns() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    s.split_whitespace().next()?.parse().ok()
}

/// Times `iters` runs of `f` in thread CPU time (wall clock where unavailable).
fn cpu_time(iters: u64, mut f: impl FnMut()) -> Duration {
    let (c0, w0) = (thread_cpu_ns(), std::time::Instant::now());
    for _ in 0..iters {
        f();
    }
    match (c0, thread_cpu_ns()) {
        (Some(a), Some(b)) => Duration::from_nanos(b.saturating_sub(a)),
        _ => w0.elapsed(),
    }
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("mesh_chunk");
    // Flat sampling: every sample runs many iterations, well above the few-millisecond
    // granularity of the kernel's per-thread CPU clock.
    g.sampling_mode(SamplingMode::Flat)
        .sample_size(30)
        .measurement_time(Duration::from_secs(4))
        .warm_up_time(Duration::from_secs(1));
    let lod0 = MeshOptions::default();
    let fields = [
        ("terrain", terrain()),
        ("cave", cave()),
        ("sphere", ball()),
        ("noise", worst()),
    ];
    for (name, nb) in &fields {
        let tris = mesh_chunk(nb, &lod0).triangle_count();
        g.bench_function(format!("lod0/{name} ({tris} tris)"), |b| {
            b.iter_custom(|n| {
                cpu_time(n, || {
                    black_box(mesh_chunk(black_box(nb), &lod0));
                })
            })
        });
    }
    let nb = &fields[0].1;
    // The server's re-mesh of a changed chunk: a pit of radius 3 dug at the surface, meshed
    // whole and against the mesh before it.
    let (before, layers) = mesh_chunk_layered(nb);
    let surface = (0..32)
        .rev()
        .find(|&y| nb.voxel(16, y, 16).is_some_and(|v| v.density > 127));
    let pit = terrain_dug(Some(([16.0, f64::from(surface.unwrap_or(16)), 16.0], 3.0)));
    g.bench_function("lod0/terrain pit, whole", |b| {
        b.iter_custom(|n| {
            cpu_time(n, || {
                black_box(mesh_chunk_layered(black_box(&pit)));
            })
        })
    });
    g.bench_function("lod0/terrain pit, re-meshed", |b| {
        b.iter_custom(|n| {
            cpu_time(n, || {
                black_box(remesh_chunk_layered(black_box(&pit), (&before, &layers)));
            })
        })
    });
    for lod in 1..=3u8 {
        for (label, faces) in [("plain", 0), ("6 transitions", ALL_FACES)] {
            let o = MeshOptions {
                lod,
                transition_faces: faces,
                ..MeshOptions::default()
            };
            g.bench_function(format!("lod{lod}/terrain {label}"), |b| {
                b.iter_custom(|n| {
                    cpu_time(n, || {
                        black_box(mesh_chunk(black_box(nb), &o));
                    })
                })
            });
        }
    }
    // The server's path: 27 loaded dense chunks copied a row at a time.
    let mut dense = Chunk::uniform(Voxel::new(140, 2));
    dense.dense_mut();
    g.bench_function("neighborhood/from_chunks dense", |b| {
        b.iter_custom(|n| {
            cpu_time(n, || {
                black_box(Neighborhood::from_chunks(ChunkPos::new(0, 0, 0), |_| {
                    Some(&dense)
                }));
            })
        })
    });
    // The same copy into a recycled buffer: no allocation, no zeroing.
    let mut recycled = Neighborhood::from_chunks(ChunkPos::new(0, 0, 0), |_| None);
    g.bench_function("neighborhood/refill_from_chunks dense", |b| {
        b.iter_custom(|n| {
            cpu_time(n, || {
                recycled.refill_from_chunks(ChunkPos::new(0, 0, 0), |_| Some(&dense));
                black_box(&recycled);
            })
        })
    });
    g.bench_function("neighborhood/from_fn terrain", |b| {
        b.iter_custom(|n| {
            cpu_time(n, || {
                black_box(terrain());
            })
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
