//! Cluster commits on a real PostgreSQL: nodes committing side by side,
//! each in a region of its own. A measurement, not a test of speed: run it
//! by hand with
//! `cargo test --release -p strata-server --test integration -- --ignored --nocapture store_pg_bench::`.

use crate::store_common;

use std::time::{Duration, Instant};

use store_common::{terrain_chunk, Seq};
use strata_server::cluster::ClusterConfig;
use strata_server::sequencer::regions::DEFAULT_REGION_CHUNKS;
use strata_server::store::pg::PgConfig;
use strata_server::store::{ChunkStore, PgStore, WorldMeta};
use strata_terrain::ChunkPos;
use strata_tests::postgres::database;

/// Batches each node commits per round.
const BATCHES: usize = 300;
/// Chunks each batch changes (one edit's worth).
const CHUNKS: i32 = 2;

/// Commits `BATCHES` batches in region `rx` (region 0 on z), one after
/// another; returns each commit's time.
fn commit_run(store: &PgStore, world: &mut Seq, rx: i32) -> Vec<Duration> {
    let side = DEFAULT_REGION_CHUNKS as i32;
    (0..BATCHES)
        .map(|i| {
            let changes = (0..CHUNKS)
                .map(|c| {
                    let pos = ChunkPos::new(rx * side + c, (i % 4) as i32, 0);
                    (pos, terrain_chunk((i as u32) * 7 + c as u32))
                })
                .collect();
            let batch = world.delta_batch(&[changes]);
            let t = Instant::now();
            store.commit_batch(&batch).unwrap();
            t.elapsed()
        })
        .collect()
}

fn p50_ms(mut d: Vec<Duration>) -> f64 {
    d.sort();
    d[d.len() / 2].as_secs_f64() * 1e3
}

#[test]
#[ignore = "benchmark: run by hand with --ignored --nocapture"]
fn nodes_committing_side_by_side() {
    let Some(db) = database("bench_side_by_side") else {
        return;
    };
    let node = |id: &str| {
        let pg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let cluster = ClusterConfig {
            node_id: id.into(),
            lease_ms: 60_000,
            renew_ms: 10_000,
            adopt: false,
            ..ClusterConfig::default()
        };
        let s = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster).unwrap();
        s.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
        let world = Seq {
            last_seq: s.reserve_seqs(0).unwrap(),
            ..Seq::default()
        };
        (s, world)
    };
    let nodes: Vec<(PgStore, Seq)> = (0..4).map(|i| node(&format!("n{i}"))).collect();
    let mut nodes: Vec<(PgStore, Seq, i32)> = nodes
        .into_iter()
        .enumerate()
        .map(|(i, (s, w))| (s, w, i as i32))
        .collect();
    // Each node's region claimed and warm before anything is timed.
    for (s, w, rx) in &mut nodes {
        commit_run(s, w, *rx);
    }
    for n in [1usize, 2, 4] {
        let started = Instant::now();
        let times: Vec<Vec<Duration>> = std::thread::scope(|scope| {
            let runs: Vec<_> = nodes[..n]
                .iter_mut()
                .map(|(s, w, rx)| scope.spawn(move || commit_run(s, w, *rx)))
                .collect();
            runs.into_iter().map(|r| r.join().unwrap()).collect()
        });
        let took = started.elapsed().as_secs_f64();
        let all: Vec<Duration> = times.into_iter().flatten().collect();
        let commits = all.len();
        println!(
            "{n} node(s) side by side: {commits} commits in {took:.2} s, \
             {:.0} commits/s together, commit p50 {:.2} ms",
            commits as f64 / took,
            p50_ms(all)
        );
    }
}

/// Chunks an edit needs that are not in memory: read one statement each,
/// as `make_resident` did, or in one (`load_chunks`). Each chunk has a
/// record and two deltas past it; 27 chunks, an edit's neighbourhood.
#[test]
#[ignore = "benchmark: run by hand with --ignored --nocapture"]
fn reading_chunks_one_by_one_and_together() {
    let Some(db) = database("bench_read_together") else {
        return;
    };
    let store = store_common::pg_store(&db);
    store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
    let positions: Vec<ChunkPos> = (0..27)
        .map(|i| ChunkPos::new(i % 3, (i / 3) % 3, i / 9))
        .collect();
    let mut world = Seq::default();
    for salt in 0..3u32 {
        let changes = positions
            .iter()
            .map(|&p| {
                (
                    p,
                    terrain_chunk(salt * 100 + p.x as u32 * 9 + p.y as u32 * 3),
                )
            })
            .collect();
        store.commit_batch(&world.delta_batch(&[changes])).unwrap();
    }
    const ROUNDS: usize = 200;
    let (mut alone, mut together) = (Vec::new(), Vec::new());
    for _ in 0..ROUNDS {
        let t = Instant::now();
        for &p in &positions {
            store.load_chunk(p).unwrap().unwrap();
        }
        alone.push(t.elapsed());
        let t = Instant::now();
        let got = store.load_chunks(&positions).unwrap();
        together.push(t.elapsed());
        assert!(got.iter().all(Option::is_some));
    }
    println!(
        "27 chunks (record + 2 deltas each), p50 of {ROUNDS}: one by one {:.2} ms, together {:.2} ms",
        p50_ms(alone),
        p50_ms(together)
    );
}
