//! Contouring a 256x256 world slice (8x8 chunks) of a cave-riddled rock.

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, Criterion};
use strata_terrain::contour::{
    contour, contour_tiled, slice_grid, slice_grid_chunks, Axis, GridView, Rect, SliceSpec,
    DENSITY_ISO,
};
use strata_terrain::material::ids;
use strata_terrain::world::ChunkGenerator;
use strata_terrain::{Chunk, ChunkPos, Voxel, World, CHUNK_SIZE};

/// Rock with a spherical cave around a jittered point every 12 voxels: a
/// slice through it holds several hundred outlines.
#[derive(Debug)]
struct CaveGenerator;

const SPACING: i32 = 12;

fn jitter(a: i32, b: i32, c: i32) -> u32 {
    let h = (a as u32).wrapping_mul(0x9E37_79B1)
        ^ (b as u32).wrapping_mul(0x85EB_CA77)
        ^ (c as u32).wrapping_mul(0xC2B2_AE3D);
    let h = (h ^ (h >> 15)).wrapping_mul(0x2C1B_3C6D);
    h ^ (h >> 12)
}

fn density(x: i32, y: i32, z: i32) -> u8 {
    let (cx, cy, cz) = (
        x.div_euclid(SPACING),
        y.div_euclid(SPACING),
        z.div_euclid(SPACING),
    );
    let mut best = f32::MAX;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (a, b, c) = (cx + dx, cy + dy, cz + dz);
                let h = jitter(a, b, c);
                let px = (a * SPACING) as f32 + (h & 7) as f32;
                let py = (b * SPACING) as f32 + ((h >> 3) & 7) as f32;
                let pz = (c * SPACING) as f32 + ((h >> 6) & 7) as f32;
                let r = 3.0 + ((h >> 9) & 3) as f32;
                let d =
                    ((x as f32 - px).powi(2) + (y as f32 - py).powi(2) + (z as f32 - pz).powi(2))
                        .sqrt()
                        - r;
                best = best.min(d);
            }
        }
    }
    (127.5 + best * 32.0).clamp(0.0, 255.0) as u8
}

impl ChunkGenerator for CaveGenerator {
    fn generate(&self, pos: ChunkPos) -> Chunk {
        let mut chunk = Chunk::uniform(Voxel::solid(ids::STONE));
        let o = pos.origin();
        for z in 0..CHUNK_SIZE {
            for y in 0..CHUNK_SIZE {
                for x in 0..CHUNK_SIZE {
                    let d = density(o.x + x, o.y + y, o.z + z);
                    let m = if d >= 128 { ids::STONE } else { ids::AIR };
                    chunk.set(x as usize, y as usize, z as usize, Voxel::new(d, m));
                }
            }
        }
        chunk
    }
}

fn bench(c: &mut Criterion) {
    let spec = SliceSpec {
        axis: Axis::Y,
        level: -40,
        region: Rect::new(-128, -128, 127, 127).unwrap(),
    };
    let mut world = World::new(Arc::new(CaveGenerator));
    world.load((-4..4).flat_map(|z| (-4..4).map(move |x| ChunkPos::new(x, -2, z))));
    let slice = slice_grid_chunks(&world, spec).unwrap();
    let lines = slice.contours(DENSITY_ISO).unwrap();
    let points: usize = lines.iter().map(|l| l.points.len()).sum();
    eprintln!(
        "slice 256x256: {} polylines, {} points",
        lines.len(),
        points
    );
    let mut flat = Vec::with_capacity(256 * 256);
    for v in -128..128 {
        for u in -128..128 {
            flat.push(slice.voxel(u, v).unwrap().density);
        }
    }

    let mut g = c.benchmark_group("contour_256");
    g.bench_function("sample_chunks_and_contour_tiled", |b| {
        b.iter(|| {
            let s = slice_grid_chunks(black_box(&world), spec).unwrap();
            black_box(s.contours(DENSITY_ISO).unwrap())
        })
    });
    g.bench_function("contour_tiled_only", |b| {
        b.iter(|| black_box(contour_tiled(black_box(slice.density()), DENSITY_ISO).unwrap()))
    });
    g.bench_function("contour_single_grid", |b| {
        let grid = GridView::new(&flat, 256, 256, [-128, -128]).unwrap();
        b.iter(|| black_box(contour(black_box(&grid), DENSITY_ISO).unwrap()))
    });
    g.bench_function("sample_per_voxel", |b| {
        b.iter(|| black_box(slice_grid(black_box(&world), spec).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
