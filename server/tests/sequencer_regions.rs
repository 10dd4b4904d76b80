//! Region lanes: a tick's output is the same whatever the region size and
//! however many threads apply the lanes.

use crate::sequencer_common;

use sequencer_common::*;
use strata_protocol::Role;
use strata_server::sequencer::{Sequencer, SequencerConfig, TickOutput};
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::ValidationConfig;
use strata_terrain::ChunkPos;

/// Where players stand. Two pairs share a region at any size above 1
/// chunk; (250, 300) and (262, 300) straddle the boundary at x = 256 of
/// 8-chunk regions, so their edits join those two regions.
const SPOTS: [(i32, i32); 7] = [
    (100, 100),
    (110, 100),
    (600, 100),
    (250, 300),
    (262, 300),
    (-300, -300),
    (900, 900),
];

fn generous() -> ValidationConfig {
    let lots = BucketConfig {
        capacity: 1 << 40,
        per_second: 0,
    };
    ValidationConfig {
        edit_rate: lots,
        volume_rate: lots,
        ..Default::default()
    }
}

/// Three rounds of edits at every spot, all queued before one tick, so
/// chunks get multi-step chains and neighbours change after each other.
fn one_tick(region_chunks: u32, threads: usize) -> (Sequencer, TickOutput) {
    let cfg = SequencerConfig {
        region_chunks,
        ..Default::default()
    };
    let mut s = sequencer(cfg, generous());
    for (i, &(x, z)) in SPOTS.iter().enumerate() {
        join_at(&mut s, 10 + i as u64, Role::Admin, x, z);
    }
    let mut id = 0;
    for round in 0..3 {
        for (i, &(x, z)) in SPOTS.iter().enumerate() {
            id += 1;
            let edit = if round == 1 {
                fill((x - 2, 0, z + 4), (x + 2, 2, z + 4))
            } else {
                mine(x - 4 + 5 * round, -1, z + 4, 2 + round)
            };
            s.submit(10 + i as u64, req(id, edit), 0).unwrap();
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let out = pool.install(|| s.tick(5));
    (s, out)
}

/// Everything of an output but the local `queued_at` instants.
fn bytes_of(out: &TickOutput) -> String {
    let applied: Vec<_> = out
        .applied
        .iter()
        .map(|a| (a.seq, a.session_id, a.client_edit_id, &a.edit, &a.changes))
        .collect();
    format!("{applied:?} {:?} {:?}", out.rejected, out.batch)
}

#[test]
fn output_is_the_same_for_any_region_size_and_thread_count() {
    let (s, reference) = one_tick(1024, 1);
    assert_eq!(reference.lanes, 2, "one region per sign of x and z");
    assert_eq!(reference.applied.len(), 3 * SPOTS.len());
    assert!(reference.rejected.is_empty());
    let seqs: Vec<u64> = reference.applied.iter().map(|a| a.seq).collect();
    assert_eq!(seqs, (1..=21).collect::<Vec<_>>(), "queue order");
    for (side, threads) in [(1, 1), (1, 4), (2, 3), (8, 1), (8, 4), (64, 2)] {
        let (t, out) = one_tick(side, threads);
        assert_eq!(
            bytes_of(&out),
            bytes_of(&reference),
            "regions of {side} chunks on {threads} threads"
        );
        let mut modified: Vec<_> = t.world().modified().map(|(p, c)| (p, c.clone())).collect();
        let mut want: Vec<_> = s.world().modified().map(|(p, c)| (p, c.clone())).collect();
        modified.sort_by_key(|m| m.0);
        want.sort_by_key(|m| m.0);
        assert_eq!(modified, want, "the same world after the tick");
    }
}

#[test]
fn regions_split_a_tick_into_lanes() {
    // 8-chunk regions: (100,100) and (110,100) share one, the pair across
    // x = 256 joins two, and three stand alone.
    assert_eq!(one_tick(8, 2).1.lanes, 5);
    // One-chunk regions: the 100/110 pair's boxes share chunk x 3.
    let (_, fine) = one_tick(1, 2);
    assert_eq!(fine.lanes, 5);
    // Mesh hashes are filled in for every change.
    assert!(fine
        .applied
        .iter()
        .flat_map(|a| &a.changes)
        .all(|c| c.mesh_hash != 0));
}

#[test]
fn an_edit_across_a_region_boundary_changes_both_sides_in_one_tick() {
    let (s, out) = one_tick(8, 4);
    // The (250, 300) player's last mine, centred on x = 256, changes
    // chunks x 7 (region 0) and x 8 (region 1).
    let across: Vec<_> = out
        .applied
        .iter()
        .filter(|a| {
            let xs: std::collections::BTreeSet<i32> = a.changes.iter().map(|c| c.pos.x).collect();
            xs.contains(&7) && xs.contains(&8)
        })
        .collect();
    assert!(!across.is_empty(), "an edit changed chunks on both sides");
    for a in &across {
        for c in &a.changes {
            let stored = out.batch.chunks.iter().find(|(p, _, _)| *p == c.pos);
            assert!(stored.is_some_and(|(_, v, _)| *v >= c.to_version));
            assert!(s.world().peek(c.pos).unwrap().version >= c.to_version);
        }
    }
    assert_eq!(
        s.world()
            .peek(ChunkPos::new(8, -1, 9))
            .map(|c| c.version > 0),
        Some(true)
    );
}

/// Two edits in neighbouring 8-chunk regions whose boxes stay inside their
/// own regions (x 249..=255 and 256..=262), but whose mesh aprons reach
/// into each other's: each changes voxels the other chunk's mesh reads.
fn apron_pair(region_chunks: u32, threads: usize) -> TickOutput {
    let cfg = SequencerConfig {
        region_chunks,
        ..Default::default()
    };
    let mut s = sequencer(cfg, generous());
    for (i, x) in [252, 259].into_iter().enumerate() {
        let id = 1 + i as u64;
        join_at(&mut s, id, Role::Admin, x, 300);
        s.submit(id, req(id, mine(x, -1, 304, 3)), 0).unwrap();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| s.tick(5))
}

#[test]
fn mesh_aprons_do_not_join_lanes_and_meshes_see_every_lane() {
    // Boxes in chunks x 7 (region 0) and x 8 (region 1): two lanes, where
    // joining through the aprons made one.
    let split = apron_pair(8, 2);
    assert_eq!(split.lanes, 2);
    // Chunk 7's mesh reads chunk 8, changed by the other lane: the hashes
    // are those of one lane holding both.
    let whole = apron_pair(1024, 1);
    assert_eq!(whole.lanes, 1);
    assert_eq!(bytes_of(&split), bytes_of(&whole));
    assert!(split
        .applied
        .iter()
        .flat_map(|a| &a.changes)
        .all(|c| c.mesh_hash != 0));
}
