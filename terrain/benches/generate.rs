//! World generation speed: one surface, cave and sky chunk (target ≤ 1 ms
//! median for a surface chunk).

use criterion::{criterion_group, criterion_main, Criterion};
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
    for (name, pos) in cases {
        c.bench_function(name, |b| b.iter(|| g.generate(black_box(pos))));
    }
}

criterion_group!(benches, generate);
criterion_main!(benches);
