//! World generation speed: one surface, cave and sky chunk (target ≤ 1 ms
//! median for a surface chunk), and a whole column of chunks.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use std::hint::black_box;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkGenerator, ChunkPos};

fn generate(c: &mut Criterion) {
    let g = Generator::fractal(GenParams::default()).expect("default parameters are valid");
    // Default seed: the surface crosses chunk y = 1 here; y = -2 is cave depth.
    let cases = [
        ("surface_chunk", ChunkPos::new(0, 1, 0)),
        ("cave_chunk", ChunkPos::new(2, -2, -1)),
        ("sky_chunk", ChunkPos::new(0, 5, 0)),
    ];
    let surface = g.generate(cases[0].1);
    assert!(
        !surface.is_uniform(),
        "the surface chunk must hold the surface"
    );
    // Each chunk from a fresh generator: the generator remembers recent
    // columns' heights, which a chunk generated once does not reuse.
    let fresh = || Generator::fractal(GenParams::default()).expect("valid");
    for (name, pos) in cases {
        c.bench_function(name, |b| {
            b.iter_batched(fresh, |g| g.generate(black_box(pos)), BatchSize::SmallInput)
        });
    }
    // A column not generated before, bedrock floor to sky, each iteration:
    // what a cold start or the background mesher asks for.
    let mut x = 1000;
    c.bench_function("column_of_chunks", |b| {
        b.iter(|| {
            x += 1;
            for y in -4..=4 {
                black_box(g.generate(ChunkPos::new(x, y, 0)));
            }
        })
    });
}

criterion_group!(benches, generate);
criterion_main!(benches);
