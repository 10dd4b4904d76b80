//! Commit latency of the sled store (group commit, one flush per batch).
//! A measurement, not a test of speed: run it by hand with
//! `cargo test --release -p strata-server --test integration -- --ignored --nocapture store_bench::`.

use crate::store_common;

use std::time::{Duration, Instant};

use store_common::{terrain_chunk, Seq};
use strata_server::store::{ChunkStore, CommitStats, SledStore, WorldMeta};
use strata_terrain::{Chunk, ChunkPos};

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
