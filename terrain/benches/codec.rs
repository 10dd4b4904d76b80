//! Speed of the delta codec, the chunk snapshot codec and the chunk hash
//! on a terrain-like chunk, plus the payload sizes they produce (printed
//! once at start).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use strata_terrain::chunk_codec::{decode_chunk, encode_chunk};
use strata_terrain::delta::ChunkDelta;
use strata_terrain::hash::chunk_hash;
use strata_terrain::material::ids;
use strata_terrain::pos::index_local;
use strata_terrain::{Chunk, ChunkPos, Voxel, CHUNK_VOLUME};

const POS: ChunkPos = ChunkPos::new(0, 0, 0);

/// A smooth terrain chunk: density ramps across the tilted plane
/// `y = 12 + x/4 + z/8` (about 5 voxels from solid to air), materials in
/// layers (grass, dirt, stone with ore). Same as the codec property tests.
fn terrain_chunk() -> Chunk {
    let mut c = Chunk::default();
    let d = c.dense_mut();
    for i in 0..CHUNK_VOLUME {
        let (x, y, z) = index_local(i);
        let (x, y, z) = (x as i32, y as i32, z as i32);
        let above_q = y * 256 + 128 - (12 * 256 + 64 * x + 32 * z);
        let density = (128 - (above_q * 48).div_euclid(256)).clamp(0, 255) as u8;
        let depth = -above_q.div_euclid(256);
        let material = match depth {
            _ if density == 0 => ids::AIR,
            d if d < 1 => ids::GRASS,
            d if d < 4 => ids::DIRT,
            _ if (x * 7 + y * 13 + z * 5) % 37 == 0 => ids::ORE,
            _ => ids::STONE,
        };
        d.set(i, Voxel::new(density, material));
    }
    c
}

/// Surface point at column (16, 16).
const SURFACE: (i32, i32, i32) = (16, 18, 16);

fn distance(i: usize, c: (i32, i32, i32)) -> f64 {
    let (x, y, z) = index_local(i);
    let (dx, dy, dz) = (x as i32 - c.0, y as i32 - c.1, z as i32 - c.2);
    ((dx * dx + dy * dy + dz * dz) as f64).sqrt()
}

/// Every voxel within `r` becomes air.
fn mine_to_air(base: &Chunk, r: f64) -> Chunk {
    let mut c = base.clone();
    for i in 0..CHUNK_VOLUME {
        if distance(i, SURFACE) <= r {
            c.set_index(i, Voxel::AIR);
        }
    }
    c
}

/// Density lowered by `255 * (1 - d/r)^2` inside `r`, materials kept.
fn mine_falloff(base: &Chunk, r: f64) -> Chunk {
    let mut c = base.clone();
    for i in 0..CHUNK_VOLUME {
        let d = distance(i, SURFACE);
        if d < r {
            let f = 1.0 - d / r;
            let v = c.get_index(i);
            c.set_index(
                i,
                Voxel::new(v.density.saturating_sub((255.0 * f * f) as u8), v.material),
            );
        }
    }
    c
}

/// Density becomes min(old, ramp rising 64 per voxel past radius `r`).
fn mine_smooth(base: &Chunk, r: f64) -> Chunk {
    let mut c = base.clone();
    for i in 0..CHUNK_VOLUME {
        let field = (128.0 + (distance(i, SURFACE) - r) * 64.0).clamp(0.0, 255.0) as u8;
        let v = c.get_index(i);
        if field < v.density {
            c.set_index(i, Voxel::new(field, v.material));
        }
    }
    c
}

fn report_sizes(base: &Chunk) {
    let snapshot = encode_chunk(base).len();
    eprintln!("terrain chunk snapshot (zstd-3 of both planes): {snapshot} bytes");
    let cases: [(&str, Chunk); 5] = [
        ("mine r=3 to air", mine_to_air(base, 3.0)),
        ("mine r=3 falloff", mine_falloff(base, 3.0)),
        ("mine r=3 smooth ramp", mine_smooth(base, 3.0)),
        ("mine r=10 smooth ramp (large)", mine_smooth(base, 10.0)),
        ("mine r=16 to air (large)", mine_to_air(base, 16.0)),
    ];
    for (name, target) in cases {
        let d = ChunkDelta::encode(POS, 0, 1, base, &target).expect("versions increase");
        let changed = (0..CHUNK_VOLUME)
            .filter(|&i| base.get_index(i) != target.get_index(i))
            .count();
        eprintln!(
            "{name}: {changed} voxels changed, delta payload {} bytes (method {:#04x}), \
             target snapshot {} bytes",
            d.payload.len(),
            d.payload[0],
            encode_chunk(&target).len()
        );
    }
}

fn bench_delta(c: &mut Criterion) {
    let base = terrain_chunk();
    report_sizes(&base);
    let mut g = c.benchmark_group("delta");
    g.measurement_time(Duration::from_secs(3));
    for (name, target) in [
        ("mine_r3", mine_to_air(&base, 3.0)),
        ("large_r10_smooth", mine_smooth(&base, 10.0)),
    ] {
        g.bench_function(format!("encode/{name}"), |b| {
            b.iter(|| ChunkDelta::encode(POS, 0, 1, black_box(&base), black_box(&target)))
        });
        // What an edit knows: the voxels it changed, and the base's hash.
        let voxels: Vec<u16> = (0..CHUNK_VOLUME)
            .filter(|&i| base.get_index(i) != target.get_index(i))
            .map(|i| i as u16)
            .collect();
        let base_hash = chunk_hash(&base);
        g.bench_function(format!("encode_from_hash/{name}"), |b| {
            b.iter(|| ChunkDelta::encode_from_hash(POS, 0, 1, &base, base_hash, black_box(&target)))
        });
        g.bench_function(format!("encode_changed/{name}"), |b| {
            b.iter(|| {
                let t = black_box(&target);
                ChunkDelta::encode_changed(POS, 0, 1, &base, base_hash, t, &voxels)
            })
        });
        let delta = ChunkDelta::encode(POS, 0, 1, &base, &target).expect("versions increase");
        g.bench_function(format!("apply/{name}"), |b| {
            b.iter(|| black_box(&delta).apply(&base))
        });
    }
    g.finish();
}

fn bench_chunk_codec(c: &mut Criterion) {
    let chunk = terrain_chunk();
    let bytes = encode_chunk(&chunk);
    let mut g = c.benchmark_group("chunk_codec");
    g.measurement_time(Duration::from_secs(3));
    g.bench_function("encode/terrain", |b| {
        b.iter(|| encode_chunk(black_box(&chunk)))
    });
    g.bench_function("decode/terrain", |b| {
        b.iter(|| decode_chunk(black_box(&bytes)))
    });
    g.finish();
}

/// The chunk hash (XXH3-64 of both planes, streamed): part of every
/// delta's encode and apply. Its hot loop is generic code compiled in
/// this crate, and a change elsewhere in the crate once made it keep its
/// accumulators in memory, 3.5x slower; this shows such a change.
fn bench_chunk_hash(c: &mut Criterion) {
    let chunk = terrain_chunk();
    c.bench_function("chunk_hash/dense", |b| {
        b.iter(|| chunk_hash(black_box(&chunk)))
    });
}

criterion_group!(benches, bench_delta, bench_chunk_codec, bench_chunk_hash);
criterion_main!(benches);
