//! Commit latency of the sled store (group commit, one flush per batch).
//! A measurement, not a test of speed: run it by hand with
//! `cargo test --release -p strata-server --test integration -- --ignored --nocapture store_bench::`.

use crate::store_common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use store_common::{terrain_chunk, Seq};
use strata_server::store::{ChunkStore, CommitStats, SledStore, WorldMeta};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Voxel};

/// (edits per batch, batches timed).
const CASES: [(usize, usize); 3] = [(1, 300), (10, 200), (100, 50)];
/// Chunk positions the edits cycle over, so later batches overwrite.
const POSITIONS: u32 = 512;
/// Distinct dense chunk states the edits cycle over.
const STATES: u32 = 16;

fn pct(sorted: &[Duration], p: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * p) as usize]
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

#[test]
#[ignore = "benchmark: run by hand with --ignored --nocapture"]
fn commit_latency() {
    let states: Vec<Chunk> = (0..STATES).map(terrain_chunk).collect();
    let pos = |i: u32| {
        let i = i % POSITIONS;
        ChunkPos::new(
            (i % 8) as i32 - 4,
            (i / 64) as i32 - 4,
            ((i / 8) % 8) as i32 - 4,
        )
    };
    for (edits, batches) in CASES {
        let dir = tempfile::tempdir().unwrap();
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
        let mut seq = Seq::default();
        let mut n = 0u32;
        let mut total = Vec::new();
        let mut stats = Vec::<CommitStats>::new();
        for _ in 0..batches {
            let edit_list: Vec<Vec<(ChunkPos, Chunk)>> = (0..edits)
                .map(|_| {
                    n += 1;
                    vec![(pos(n), states[(n % STATES) as usize].clone())]
                })
                .collect();
            let b = seq.batch(&edit_list);
            let t = Instant::now();
            stats.push(store.commit_batch(&b).unwrap());
            total.push(t.elapsed());
        }
        total.sort();
        let mut flush: Vec<_> = stats.iter().map(|s| s.flush).collect();
        flush.sort();
        let mean = total.iter().sum::<Duration>() / total.len() as u32;
        let apply = stats.iter().map(|s| s.apply).sum::<Duration>() / stats.len() as u32;
        let encode = stats.iter().map(|s| s.encode).sum::<Duration>() / stats.len() as u32;
        let bytes = stats.iter().map(|s| s.bytes_written).sum::<u64>() / stats.len() as u64;
        println!(
            "{edits:>3} edits/batch x {batches}: commit mean {:.3} ms p50 {:.3} p99 {:.3} max {:.3} | \
             encode mean {:.3} ms, apply mean {:.3} ms | flush p50 {:.3} p99 {:.3} ms | {bytes} B/batch | disk {} KiB",
            ms(mean),
            ms(pct(&total, 0.5)),
            ms(pct(&total, 0.99)),
            ms(*total.last().unwrap()),
            ms(encode),
            ms(apply),
            ms(pct(&flush, 0.5)),
            ms(pct(&flush, 0.99)),
            store.size_on_disk().unwrap() / 1024,
        );
        assert_eq!(store.last_seq().unwrap(), (edits * batches) as u64);
    }
}

/// New chunks a cold-start batch stores (a 3000-bot start stored 92-166
/// per commit, `BENCHMARKS.md`), and batches timed per case.
const FIRST_TOUCHES: [usize; 3] = [16, 64, 128];
const FIRST_TOUCH_BATCHES: usize = 20;

/// A generated surface chunk with a hole mined in it: a first touch.
fn mined(g: &dyn ChunkGenerator, pos: ChunkPos) -> Chunk {
    let mut c = g.generate(pos);
    for z in 12..20 {
        for y in 0..32 {
            for x in 12..20 {
                c.set(x, y, z, Voxel::AIR);
            }
        }
    }
    c
}

/// The commit path of first touches: whole chunks (no generator attached,
/// as before store format 4) against deltas from generated (attached), on
/// one binary. Run as `commit_latency`.
#[test]
#[ignore = "benchmark: run by hand with --ignored --nocapture"]
fn first_touch_commits() {
    let g = Generator::fractal(GenParams::default()).unwrap();
    // Surface chunks: the row that holds the ground at each column.
    let surface = |i: usize| {
        let (x, z) = (i as i32 % 64, i as i32 / 64);
        let y = (g.surface_height(x * 32 + 16, z * 32 + 16) / 32.0).floor() as i32;
        ChunkPos::new(x, y, z)
    };
    for n in FIRST_TOUCHES {
        for attach in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            let store = SledStore::open(dir.path()).unwrap();
            store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
            if attach {
                store.attach_generator(Arc::new(g.clone()));
            }
            let mut seq = Seq::default();
            let mut next = 0;
            let mut total = Vec::new();
            let mut stats = Vec::<CommitStats>::new();
            for _ in 0..FIRST_TOUCH_BATCHES {
                let edits: Vec<Vec<(ChunkPos, Chunk)>> = (0..n)
                    .map(|_| {
                        next += 1;
                        let p = surface(next);
                        vec![(p, mined(&g, p))]
                    })
                    .collect();
                let b = seq.generated_batch(&edits, &g);
                let t = Instant::now();
                stats.push(store.commit_batch(&b).unwrap());
                total.push(t.elapsed());
            }
            total.sort();
            let encode = stats.iter().map(|s| s.encode).sum::<Duration>() / stats.len() as u32;
            let bytes = stats.iter().map(|s| s.bytes_written).sum::<u64>() / stats.len() as u64;
            let t = Instant::now();
            let folded = store.checkpoint(usize::MAX).unwrap();
            println!(
                "{n:>3} new chunks/batch, {}: commit p50 {:.3} ms max {:.3} | encode mean {:.3} ms | \
                 {bytes} B/batch | checkpoint afterwards: {} chunks in {:.1} ms",
                if attach { "from generated" } else { "whole" },
                ms(pct(&total, 0.5)),
                ms(*total.last().unwrap()),
                ms(encode),
                folded.chunks,
                ms(t.elapsed()),
            );
        }
    }
}
