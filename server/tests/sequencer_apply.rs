//! Ordering, versions, delta chains, commit batches and store residency.

use crate::sequencer_common;

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use sequencer_common::*;
use strata_protocol::{RejectReason, Role};
use strata_server::collision::CollisionMesh;
use strata_server::sequencer::{Sequencer, SequencerConfig, TickOutput};
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::mesh::Neighborhood;
use strata_terrain::{Chunk, ChunkPos, Edit, MaterialTable, Voxel};

const X: i32 = HOME.0;
const Z: i32 = HOME.1;

/// Replays every delta of `outs` onto generated chunks and checks each step
/// and the end state against the sequencer's world.
fn replay_matches_world(s: &Sequencer, outs: &[TickOutput]) {
    let gen = s.world().generator().clone();
    let mut replica: HashMap<ChunkPos, (Chunk, u64)> = HashMap::new();
    for a in outs.iter().flat_map(|o| &o.applied) {
        for c in &a.changes {
            let (base, version) = replica
                .entry(c.pos)
                .or_insert_with(|| (gen.generate(c.pos), 0));
            assert_eq!(c.from_version, *version, "chain has no gaps");
            assert_eq!(c.to_version, c.from_version + 1);
            let next = c
                .delta
                .apply(base)
                .expect("delta applies to previous state, target hash checked");
            *base = next;
            *version = c.to_version;
        }
    }
    assert!(!replica.is_empty());
    for (pos, (chunk, version)) in &replica {
        let w = s.world().peek(*pos).unwrap();
        assert_eq!((&*w.chunk, w.version), (chunk, *version), "{pos:?}");
    }
}

/// Past `MAX_SEQ` (only a stored seq near it can bring a world there) no
/// seq is handed out: edits wait in the queue, and nothing overflows.
#[test]
fn no_seq_is_handed_out_past_the_highest_a_store_holds() {
    use strata_server::store::MAX_SEQ;
    let mut s = Sequencer::new(
        world(),
        SequencerConfig::default(),
        ValidationConfig::default(),
        MAX_SEQ - 1,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    )
    .without_store();
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    s.submit(PLAYER, req(1, mine(X, -1, Z + 4, 2)), 0).unwrap();
    s.submit(PLAYER, req(2, mine(X + 1, -2, Z + 4, 2)), 0)
        .unwrap();
    let t = s.tick(10);
    let seqs: Vec<u64> = t.applied.iter().map(|a| a.seq).collect();
    assert_eq!(seqs, vec![MAX_SEQ]);
    assert_eq!(s.queued(), 1, "the other waits");
    assert!(s.tick(20).applied.is_empty());
    assert_eq!((s.queued(), s.last_seq()), (1, MAX_SEQ));
}

/// A cluster node's seq block ends at the limit: a tick hands out seqs up
/// to it and no further; the rest wait until the next block's floor and
/// end are given, and are numbered from there.
#[test]
fn edits_past_the_seq_limit_wait_for_the_next_block() {
    let mut s = Sequencer::new(
        world(),
        SequencerConfig::default(),
        ValidationConfig::default(),
        100,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    )
    .without_store();
    s.limit_seqs(102);
    assert_eq!(s.seqs_left(), 2);
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    for i in 0..4 {
        s.submit(PLAYER, req(i + 1, mine(X + i as i32, -1, Z + 4, 2)), 0)
            .unwrap();
    }
    let seqs = |t: TickOutput| t.applied.iter().map(|a| a.seq).collect::<Vec<u64>>();
    assert_eq!(seqs(s.tick(10)), [101, 102]);
    assert_eq!((s.queued(), s.seqs_left()), (2, 0), "the others wait");
    assert!(s.tick(20).applied.is_empty());
    // The next block: 1000 above the last one's end.
    s.raise_next_seq(1001);
    s.limit_seqs(2000);
    assert_eq!(seqs(s.tick(30)), [1001, 1002]);
    assert_eq!(s.queued(), 0);
}

#[test]
fn consecutive_seqs_rising_versions_and_delta_chains() {
    let mut s = Sequencer::new(
        world(),
        SequencerConfig::default(),
        ValidationConfig::default(),
        41,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    )
    .without_store();
    assert_eq!(s.next_seq(), 42, "continues after the stored last_seq");
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    // Two edits on the same chunk in one tick, then a third in the next.
    s.submit(PLAYER, req(1, mine(X, -1, Z + 4, 2)), 0).unwrap();
    s.submit(PLAYER, req(2, mine(X + 1, -2, Z + 4, 2)), 0)
        .unwrap();
    let t1 = s.tick(10);
    assert_eq!(s.queued(), 0);
    let seqs: Vec<u64> = t1.applied.iter().map(|a| a.seq).collect();
    assert_eq!(seqs, vec![42, 43]);
    assert_eq!(t1.applied[0].client_edit_id, 1);
    assert_eq!(t1.applied[1].session_id, PLAYER);
    let home = ChunkPos::new(3, -1, 3);
    let steps: Vec<(u64, u64)> = t1
        .applied
        .iter()
        .flat_map(|a| a.changes.iter().filter(|c| c.pos == home))
        .map(|c| (c.from_version, c.to_version))
        .collect();
    assert_eq!(steps, vec![(0, 1), (1, 2)], "two-step chain in one tick");

    s.submit(PLAYER, req(3, mine(X, -1, Z + 5, 3)), 1_000)
        .unwrap();
    let t2 = s.tick(1_000);
    assert_eq!(t2.applied[0].seq, 44);
    assert_eq!(s.last_seq(), 44);
    assert_eq!(s.world().peek(home).unwrap().version, 3);
    replay_matches_world(&s, &[t1, t2]);
}

#[test]
fn commit_batch_matches_the_world() {
    let mut s = ready(ValidationConfig::default());
    s.submit(PLAYER, req(1, mine(X, -1, Z + 4, 2)), 0).unwrap();
    s.submit(ADMIN, req(2, fill((X - 3, 0, Z + 6), (X + 3, 3, Z + 6))), 0)
        .unwrap();
    s.submit(PLAYER, req(3, mine(X, -1, Z + 5, 2)), 0).unwrap();
    let out = s.tick(777);
    let b = &out.batch;
    assert_eq!(b.entries.len(), 3);
    assert_eq!(b.last_seq, 3);
    for (e, a) in b.entries.iter().zip(&out.applied) {
        assert_eq!(
            (e.seq, &e.player, &e.edit, e.time_ms),
            (a.seq, &a.player, &a.edit, 777)
        );
        let ch: Vec<_> = a.changes.iter().map(|c| (c.pos, c.to_version)).collect();
        assert_eq!(e.changes, ch);
    }
    assert_eq!(b.entries[1].player, "p2");
    let mut changed: Vec<ChunkPos> = out
        .applied
        .iter()
        .flat_map(|a| a.changes.iter().map(|c| c.pos))
        .collect();
    changed.sort();
    changed.dedup();
    let stored: Vec<ChunkPos> = b.chunks.iter().map(|c| c.0).collect();
    assert_eq!(
        stored, changed,
        "every changed chunk once, in position order"
    );
    for c in &b.chunks {
        let (pos, version, chunk) = c;
        let w = s.world().peek(*pos).unwrap();
        assert_eq!((chunk, *version), (&w.chunk, w.version), "final state");
    }
    let modified = s.world().modified().count();
    assert_eq!(modified, b.chunks.len());
    assert!(s.tick(800).batch.is_empty());
    assert_eq!(s.tick(800).batch.last_seq, 3);
}

#[test]
fn mesh_hashes_match_fresh_meshes_and_fill_the_cache() {
    let mut s = ready(ValidationConfig::default());
    s.submit(PLAYER, req(1, mine(X, -1, Z + 4, 3)), 0).unwrap();
    let out = s.tick(0);
    for c in &out.applied[0].changes {
        let nb = Neighborhood::from_world(s.world(), c.pos);
        let fresh = CollisionMesh::build(c.pos, c.to_version, &nb);
        assert_eq!(c.mesh_hash, fresh.hash);
        let cached = s.collision().get(c.pos, c.to_version).expect("cached");
        assert_eq!(cached.hash, c.mesh_hash);
    }
}

#[test]
fn mesh_hashes_describe_the_world_at_the_tick_end() {
    // Two edits in one tick: the second changes only the neighbour across
    // x = 96, inside the first chunk's mesh apron. Clients mesh at TickEnd,
    // so each chunk's last change must carry the final mesh's hash.
    let mut s = ready(ValidationConfig::default());
    s.submit(PLAYER, req(1, mine(98, -1, Z + 4, 2)), 0).unwrap();
    let apron_only = strata_terrain::Edit::Mine {
        center: strata_terrain::FixedVec3::from_f64([93.5, -1.0, (Z + 4) as f64]).unwrap(),
        radius: strata_terrain::Fixed::from_voxels(2),
        strength: 255,
    };
    s.submit(PLAYER, req(2, apron_only), 0).unwrap();
    let out = s.tick(0);
    let a = ChunkPos::new(3, -1, 3);
    let changed: Vec<Vec<ChunkPos>> = out
        .applied
        .iter()
        .map(|e| e.changes.iter().map(|c| c.pos).collect())
        .collect();
    assert!(
        changed[0].contains(&a) && !changed[1].contains(&a),
        "{changed:?}"
    );
    let mut last = HashMap::new();
    for c in out.applied.iter().flat_map(|e| &e.changes) {
        last.insert(c.pos, (c.to_version, c.mesh_hash));
    }
    for (pos, (version, hash)) in last {
        let nb = Neighborhood::from_world(s.world(), pos);
        assert_eq!(
            hash,
            CollisionMesh::build(pos, version, &nb).hash,
            "{pos:?}"
        );
    }
}

#[test]
fn stale_neighbour_meshes_in_use_are_rebuilt_by_the_tick() {
    // A mine at x = 98 changes chunk x 3 (voxels 96..) and so the apron of
    // chunk x 2, whose voxels stay as they were.
    let mut s = ready(ValidationConfig::default());
    let (used, unused) = (ChunkPos::new(2, -1, 3), ChunkPos::new(2, 0, 3));
    s.mesh_hash(used);
    assert!(s.collision().get(unused, 0).is_none());
    s.submit(PLAYER, req(1, mine(98, -1, Z + 4, 2)), 0).unwrap();
    let (mut out, pending) = s.tick_apply(0);
    let changed = out.applied[0].changes.len();
    assert!(out.applied[0].changes.iter().all(|c| c.pos.x == 3));
    // One mesh per changed chunk, and rewarms: `used` and any other stale
    // mesh the line-of-sight check had cached, never `unused`.
    assert_eq!(pending.changed(), changed);
    assert!(pending.rewarmed() >= 1);
    s.finish_tick(&mut out, pending.build(), &HashSet::new());
    let nb = Neighborhood::from_world(s.world(), used);
    let fresh = CollisionMesh::build(used, 0, &nb);
    let cached = s.collision().get(used, 0).expect("rebuilt, not left stale");
    assert_eq!(cached.hash, fresh.hash);
    assert!(s.collision().get(unused, 0).is_none(), "only meshes in use");
    // The rewarm is counted as used once something looks it up.
    assert_eq!(s.collision().rewarm_outcomes().used, 0);
    assert_eq!(s.mesh_hash(used), fresh.hash);
    assert_eq!(s.collision().rewarm_outcomes().used, 1);
}

#[test]
fn edits_above_the_lod0_apron_keep_the_mesh_below() {
    // Ground level is y = 0, so chunk (3, -1, 3) holds the surface. Its
    // LOD-0 mesh reads up to local 33, world y = 1; world y 2..=8 lie in its
    // neighbourhood (the surface-scan rows) but not in what it reads.
    let mut s = ready(ValidationConfig::default());
    let below = ChunkPos::new(3, -1, 3);
    let fresh =
        |s: &Sequencer| CollisionMesh::build(below, 0, &Neighborhood::from_world(s.world(), below));
    s.mesh_hash(below);
    let before = s.collision().get(below, 0).expect("meshed").clone();
    s.submit(ADMIN, req(1, fill((98, 2, Z + 4), (100, 8, Z + 6))), 0)
        .unwrap();
    let out = s.tick(0);
    assert_eq!(out.applied.len(), 1, "{:?}", out.rejected);
    assert!(out.applied[0].changes.iter().all(|c| c.pos != below));
    let kept = s.collision().get(below, 0).expect("kept");
    assert!(
        std::sync::Arc::ptr_eq(kept, &before),
        "neither dropped nor rebuilt"
    );
    assert_eq!(**kept, fresh(&s), "and still what the world meshes to");
    // World y = 1 is its local 33 (the normals at 32 read it): dropped and
    // rebuilt. (On flat ground only the normals' length changes, so the mesh
    // comes out the same.)
    s.submit(ADMIN, req(2, fill((98, 1, Z + 4), (100, 1, Z + 6))), 1_000)
        .unwrap();
    let out = s.tick(1_000);
    assert_eq!(out.applied.len(), 1, "{:?}", out.rejected);
    let rebuilt = s.collision().get(below, 0).expect("rewarmed");
    assert!(!std::sync::Arc::ptr_eq(rebuilt, &before));
    assert_eq!(**rebuilt, fresh(&s));
}

#[test]
fn adopted_generated_chunks_never_replace_loaded_ones() {
    let mut s = ready(ValidationConfig::default());
    let gen = s.world().generator().clone();
    let fresh = ChunkPos::new(40, 0, 40);
    assert!(s.world().peek(fresh).is_none());
    s.adopt_generated(fresh, &Arc::new(gen.generate(fresh)));
    let held = s.world().peek(fresh).expect("adopted");
    assert_eq!((held.version, &*held.chunk), (0, &gen.generate(fresh)));
    assert!(s.is_resident(fresh));
    // A loaded chunk (here edited) is kept as it is.
    let home = ChunkPos::new(X.div_euclid(32), 0, Z.div_euclid(32));
    s.insert_stored_chunk(home, Chunk::Uniform(Voxel::solid(7)), 3);
    s.adopt_generated(home, &Arc::new(gen.generate(home)));
    let kept = s.world().peek(home).unwrap();
    assert_eq!(
        (kept.version, &*kept.chunk),
        (3, &Chunk::Uniform(Voxel::solid(7)))
    );
}

#[test]
fn max_edits_per_tick_leaves_the_rest_queued() {
    let cfg = SequencerConfig {
        max_edits_per_tick: 2,
        ..Default::default()
    };
    let mut s = sequencer(cfg, ValidationConfig::default());
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    for i in 0..3 {
        s.submit(PLAYER, req(i, mine(X, -1, Z + 4, 1)), 0).unwrap();
    }
    assert_eq!(s.tick(0).applied.len(), 2);
    assert_eq!(s.queued(), 1);
    assert_eq!(s.tick(0).applied[0].seq, 3);
}

/// A sequencer with a store (nothing resident until loaded or marked
/// absent), its next seq above `last_seq`, and the player joined. Without
/// gravity: a report then reads no chunk below the feet's, so the tests
/// may store the one under home themselves.
fn store_backed(last_seq: u64) -> Sequencer {
    store_backed_with(last_seq, false)
}

fn store_backed_with(last_seq: u64, gravity: bool) -> Sequencer {
    let mut v = ValidationConfig::default();
    v.gravity.enabled = gravity;
    let mut s = Sequencer::new(
        world(),
        SequencerConfig::default(),
        v,
        last_seq,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    );
    s.session_joined(PLAYER, "p".into(), Role::Player);
    s
}

/// The tick's first edit took `home` from its stored version 5 to 6, by a
/// delta that turns `stored` into the world's chunk.
fn assert_applied_on_stored(s: &Sequencer, out: &TickOutput, home: ChunkPos, stored: &Chunk) {
    let c = out.applied[0]
        .changes
        .iter()
        .find(|c| c.pos == home)
        .unwrap();
    assert_eq!((c.from_version, c.to_version), (5, 6));
    let now = &*s.world().peek(home).unwrap().chunk;
    assert_eq!(&c.delta.apply(stored).unwrap(), now);
}

/// Chunk column (3, 3) from row `from` up to the world's top row: what a
/// first report there reads (the body, and the sky above it).
fn sky_column(from: i32) -> Vec<ChunkPos> {
    let (_, top) = strata_server::validate::WorldBounds::default().chunk_y_range();
    (from..=top).map(|y| ChunkPos::new(3, y, 3)).collect()
}

#[test]
fn store_backed_chunks_must_be_resident() {
    let mut s = store_backed(10);
    let p = at(1, X, 0, Z);
    let need = s.chunks_needed_for_position(PLAYER, &p);
    // The body's chunk, and (a first report) the column up to the sky.
    assert_eq!(need, sky_column(0));
    assert!(s.update_position(PLAYER, p, 0).is_err());
    for c in need {
        s.mark_absent(c);
    }
    s.update_position(PLAYER, p, 0).unwrap();

    let edit = mine(X, -1, Z + 4, 2);
    let need = s.chunks_needed(PLAYER, &edit);
    let home = ChunkPos::new(3, -1, 3);
    assert!(need.contains(&home) && need.contains(&ChunkPos::new(4, 0, 4)));
    let before = snapshot(&s);
    assert_eq!(
        s.submit(PLAYER, req(1, edit.clone()), 0),
        Err(RejectReason::Busy)
    );
    // The engine's path (rules once, then its sight check on the workers)
    // waits as well, generating nothing.
    let loaded = s.world().loaded();
    assert_eq!(
        s.admit(PLAYER, req(1, edit.clone()), 0),
        Err(RejectReason::Busy)
    );
    assert_eq!((s.sighting(), s.world().loaded()), (0, loaded));
    assert_eq!(snapshot(&s), before);
    // The store has the home chunk at version 5 (one voxel already dug).
    let mut stored = Chunk::uniform(Voxel::solid(3));
    stored.set(0, 0, 0, Voxel::AIR);
    for c in need {
        if c == home {
            s.insert_stored_chunk(c, stored.clone(), 5);
        } else {
            s.mark_absent(c);
        }
    }
    assert!(s.chunks_needed(PLAYER, &edit).is_empty());
    s.submit(PLAYER, req(1, edit), 0).unwrap();
    let out = s.tick(0);
    assert_eq!(out.applied[0].seq, 11);
    assert_applied_on_stored(&s, &out, home, &stored);
    assert_eq!(s.world().peek(home).unwrap().chunk.get(0, 0, 0), Voxel::AIR);
}

/// With gravity, a report reads the ground under the feet too (here, the
/// chunk below theirs).
#[test]
fn a_report_loads_the_ground_under_it() {
    let mut s = store_backed_with(10, true);
    let p = at(1, X, 0, Z);
    let need = s.chunks_needed_for_position(PLAYER, &p);
    let mut want = vec![ChunkPos::new(3, -1, 3)];
    want.extend(sky_column(0));
    assert_eq!(need, want);
    for c in sky_column(0) {
        s.mark_absent(c);
    }
    assert!(matches!(
        s.update_position(PLAYER, p, 0),
        Err(strata_server::validate::PositionReject::ChunkNotLoaded { .. })
    ));
    s.mark_absent(ChunkPos::new(3, -1, 3));
    s.update_position(PLAYER, p, 0).unwrap();
}

/// A standing report above the step reads the ground a catch-up walk
/// may follow (here, under the way's corner across a chunk border that
/// neither end's ground nor the sweep's box reaches); a level one does
/// not.
#[test]
fn a_report_above_the_step_loads_the_ground_of_its_way() {
    let mut s = store_backed_with(10, true);
    for (i, p) in [at(1, X, 0, Z), at(2, 126, 0, 120)].into_iter().enumerate() {
        for c in s.chunks_needed_for_position(PLAYER, &p) {
            s.mark_absent(c);
        }
        s.update_position(PLAYER, p, 2_000 * i as u64).unwrap();
    }
    let corner = ChunkPos::new(4, -1, 3);
    let level = at(3, 140, 0, 140);
    assert!(!s
        .chunks_needed_for_position(PLAYER, &level)
        .contains(&corner));
    let up = at(3, 140, 8, 140);
    assert!(s.chunks_needed_for_position(PLAYER, &up).contains(&corner));
}

/// A report inside solid terrain is refused on its body's chunks alone:
/// none of its way's is loaded for it.
#[test]
fn a_report_inside_the_ground_loads_nothing_of_its_way() {
    let mut s = store_backed(10);
    let p = at(1, X, 0, Z);
    for c in s.chunks_needed_for_position(PLAYER, &p) {
        s.mark_absent(c);
    }
    s.update_position(PLAYER, p, 0).unwrap();
    // 40 voxels on and 10 down, in the rock.
    let buried = at(2, X + 40, -10, Z);
    let body: Vec<ChunkPos> = vec![strata_terrain::VoxelPos::new(X + 40, -9, Z).chunk()];
    let first = s.chunks_needed_for_position(PLAYER, &buried);
    assert!(
        first.len() > body.len(),
        "its way too, while the body is unknown"
    );
    for c in &body {
        s.mark_absent(*c);
    }
    assert_eq!(s.chunks_needed_for_position(PLAYER, &buried), vec![]);
    assert!(matches!(
        s.update_position(PLAYER, buried, 2_000),
        Err(strata_server::validate::PositionReject::InsideSolid { .. })
    ));
}

/// A store-backed sequencer with the player at home, a cold modified
/// chunk `far`, and the chunks `edit` reads resident (`home` stored at
/// version 5 as `stored`).
fn evictable() -> (Sequencer, Edit, ChunkPos, ChunkPos, Chunk) {
    let mut s = store_backed(0);
    let p = at(1, X, 0, Z);
    for c in s.chunks_needed_for_position(PLAYER, &p) {
        s.mark_absent(c);
    }
    s.update_position(PLAYER, p, 0).unwrap();
    // A modified chunk far from anything: cold.
    let far = ChunkPos::new(40, -1, 40);
    s.insert_stored_chunk(far, Chunk::uniform(Voxel::solid(3)), 7);
    let edit = mine(X, -1, Z + 4, 2);
    let home = ChunkPos::new(3, -1, 3);
    let mut stored = Chunk::uniform(Voxel::solid(3));
    stored.set(0, 0, 0, Voxel::AIR);
    for c in s.chunks_needed(PLAYER, &edit) {
        if c == home {
            s.insert_stored_chunk(c, stored.clone(), 5);
        } else {
            s.mark_absent(c);
        }
    }
    (s, edit, home, far, stored)
}

#[test]
fn eviction_with_edits_queued_keeps_what_they_read() {
    let (mut s, edit, home, far, stored) = evictable();
    s.submit(PLAYER, req(1, edit.clone()), 0).unwrap();
    assert_eq!(s.queued(), 1);
    // Nothing is hot, yet the queued edit's chunks stay and the cold one
    // goes: a queue that never empties no longer stops eviction.
    assert!(!s.evict_cold(|_| false).is_empty());
    assert!(s.world().peek(far).is_none() && !s.is_resident(far));
    assert!(s.chunks_needed(PLAYER, &edit).is_empty());
    assert_eq!(s.world().peek(home).map(|c| c.version), Some(5));
    let out = s.tick(0);
    assert_applied_on_stored(&s, &out, home, &stored);
    // With the queue empty, everything not kept goes.
    s.evict_cold(|_| false);
    assert!(!s.is_resident(home));
}

#[test]
fn eviction_far_from_players_keeps_the_cube_around_each() {
    let (mut s, edit, home, far, stored) = evictable();
    s.submit(PLAYER, req(1, edit.clone()), 0).unwrap();
    // The player stands in chunk (3, 0, 3); the queued edit's reads with
    // their neighbours reach up to y = 1.
    let up = |d: i32| ChunkPos::new(3, d, 3);
    let diagonal = |d: i32| ChunkPos::new(3 - d, d, 3 + d);
    for d in 0..=9 {
        for c in [up(d), diagonal(d)] {
            if !s.is_resident(c) {
                s.mark_absent(c);
            }
        }
    }
    assert!(!s.evict_far_from_players(2).is_empty());
    assert!(s.world().peek(far).is_none() && !s.is_resident(far));
    for d in 0..=9 {
        let kept = d <= 2;
        assert_eq!(s.is_resident(up(d)), kept, "{:?}", up(d));
        assert_eq!(s.is_resident(diagonal(d)), kept, "{:?}", diagonal(d));
    }
    assert!(s.chunks_needed(PLAYER, &edit).is_empty());
    let out = s.tick(0);
    assert_applied_on_stored(&s, &out, home, &stored);
    // Radius 0 keeps only the chunk the player stands in.
    s.evict_far_from_players(0);
    assert!(s.is_resident(up(0)));
    assert!(!s.is_resident(up(1)) && !s.is_resident(home));
}

#[test]
fn eviction_keeps_what_edits_awaiting_their_sight_check_read() {
    let (mut s, edit, home, far, stored) = evictable();
    s.admit(PLAYER, req(1, edit.clone()), 0).unwrap();
    assert_eq!((s.queued(), s.sighting()), (0, 1));
    assert!(!s.evict_cold(|_| false).is_empty());
    assert!(s.world().peek(far).is_none());
    assert!(s.chunks_needed(PLAYER, &edit).is_empty());
    assert!(s.check_sighted(0).is_empty());
    let out = s.tick(0);
    assert_applied_on_stored(&s, &out, home, &stored);
}

#[test]
fn a_stored_chunk_changed_twice_in_a_tick_is_committed_as_one_delta() {
    let mut s = store_backed(0);
    let p = at(1, X, 0, Z);
    for c in s.chunks_needed_for_position(PLAYER, &p) {
        s.mark_absent(c);
    }
    s.update_position(PLAYER, p, 0).unwrap();
    let first = mine(X, -1, Z + 4, 2);
    let second = mine(X + 1, -1, Z + 5, 2);
    let home = ChunkPos::new(3, -1, 3);
    let mut stored = Chunk::uniform(Voxel::solid(3));
    stored.set(0, 0, 0, Voxel::AIR);
    for edit in [&first, &second] {
        for c in s.chunks_needed(PLAYER, edit) {
            if c == home {
                s.insert_stored_chunk(c, stored.clone(), 5);
            } else {
                s.mark_absent(c);
            }
        }
    }
    s.submit(PLAYER, req(1, first), 0).unwrap();
    s.submit(PLAYER, req(2, second), 0).unwrap();
    let out = s.tick(0);
    let home_changes: Vec<(u64, u64)> = out
        .applied
        .iter()
        .flat_map(|a| a.changes.iter().filter(|c| c.pos == home))
        .map(|c| (c.from_version, c.to_version))
        .collect();
    assert_eq!(home_changes, [(5, 6), (6, 7)], "each edit's own delta");
    // The store gets one delta across both, which turns the stored chunk
    // into the world's; chunks new to the store go whole.
    let deltas: Vec<_> = out.batch.deltas.iter().filter(|d| d.pos == home).collect();
    assert_eq!(deltas.len(), 1);
    assert_eq!((deltas[0].from_version, deltas[0].to_version), (5, 7));
    let now = &*s.world().peek(home).unwrap().chunk;
    assert_eq!(&deltas[0].apply(&stored).unwrap(), now);
    // Built from the voxels either edit changed: the full encoder's bytes.
    let full = strata_terrain::delta::ChunkDelta::encode(home, 5, 7, &stored, now).unwrap();
    assert_eq!(deltas[0], &full);
    assert_eq!(out.batch.deltas.len(), 1);
    assert!(out.batch.chunks.iter().all(|c| c.0 != home));
}

#[test]
fn prepared_meshes_keep_their_generated_neighbours_and_hash_as_meshed_alone() {
    use strata_server::sequencer::residency::with_neighbours;
    let mut s = ready(ValidationConfig::default());
    // Two neighbours far from every player: nothing around them is loaded.
    let far = [ChunkPos::new(40, -1, 40), ChunkPos::new(41, -1, 40)];
    let around: HashSet<ChunkPos> = far.iter().flat_map(|&p| with_neighbours(p)).collect();
    assert!(around.iter().all(|&p| s.world().peek(p).is_none()));
    s.prepare_meshes(&far);
    // Each neighbour generated once, into the world, at version 0.
    for &p in &around {
        assert_eq!(s.world().peek(p).map(|c| c.version), Some(0), "{p:?}");
    }
    let mut alone = ready(ValidationConfig::default());
    for p in far {
        let fresh = CollisionMesh::build(p, 0, &Neighborhood::from_world(s.world(), p));
        let prepared = s.collision().get(p, 0).expect("meshed");
        assert_eq!(prepared.hash, fresh.hash);
        // A sequencer that meshes it on its own, generating on the fly.
        assert_eq!(alone.mesh_hash(p), fresh.hash);
    }
}

#[test]
fn meshes_copying_only_the_layers_a_tick_reaches_equal_fresh_meshes() {
    // Ticks of mines and fills on both sides of the chunk border at x = 96:
    // from the second tick on, the changed chunks' and their neighbours'
    // meshes are built from the layers the tick's edits reach
    // (`sequencer/reach.rs`), and must equal meshes of the whole
    // neighbourhood, bit for bit.
    let plenty = BucketConfig {
        capacity: 1 << 30,
        per_second: 1 << 30,
    };
    let mut s = ready(ValidationConfig {
        edit_rate: plenty,
        volume_rate: plenty,
        ..ValidationConfig::default()
    });
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut next = |n: i32| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % n as u64) as i32
    };
    let (mut partial, mut whole, mut id, mut accepted) = (0, 0, 0, 0);
    for tick in 0..16 {
        for _ in 0..3 {
            id += 1;
            // Mines centred on the ground's surface (in sight), fills by
            // the admin (players may not fill).
            let (who, edit) = if next(4) == 0 {
                let (x, z) = (X + 3 + next(4), Z + next(7));
                (
                    ADMIN,
                    fill((x, 0, z), (x + next(3), 1 + next(2), z + next(3))),
                )
            } else {
                (PLAYER, mine(X - 6 + next(13), 0, Z + next(7), 1 + next(3)))
            };
            // A fill may hide a later edit from sight: refused, it changes nothing.
            accepted += usize::from(s.submit(who, req(id, edit), 0).is_ok());
        }
        let (mut out, pending) = s.tick_apply(tick);
        let built = pending.build();
        partial += built.layers.partial_copies;
        whole += built.layers.whole_copies;
        s.finish_tick(&mut out, built, &HashSet::new());
        let mut seen = HashSet::new();
        for c in out.applied.iter().flat_map(|a| &a.changes) {
            for (dx, dy, dz) in (0..27).map(|i| (i % 3 - 1, i / 3 % 3 - 1, i / 9 - 1)) {
                let p = ChunkPos::new(c.pos.x + dx, c.pos.y + dy, c.pos.z + dz);
                let v = s.world().peek(p).map_or(0, |c| c.version);
                let Some(m) = s.collision().get(p, v).filter(|_| seen.insert(p)) else {
                    continue;
                };
                let fresh = CollisionMesh::build(p, v, &Neighborhood::from_world(s.world(), p));
                assert_eq!(m.mesh, fresh.mesh, "tick {tick}: {p:?}");
                assert_eq!(m.hash, fresh.hash);
            }
        }
    }
    assert!(accepted >= 30, "{accepted} edits accepted");
    assert!(
        partial >= 10,
        "layers copied for {partial} meshes, whole for {whole}"
    );
}

#[test]
fn a_tick_applied_ahead_meshes_against_older_meshes_whole() {
    // The engine applies a tick while the one before it commits, before
    // that tick's meshes are cached: the first tick dropped the meshes it
    // made stale, so the second finds no base for them and copies whole
    // neighbourhoods. Every change's mesh hash still describes the world.
    let cfg = SequencerConfig {
        max_edits_per_tick: 1,
        ..Default::default()
    };
    let mut s = sequencer(cfg, ValidationConfig::default());
    join_at(&mut s, PLAYER, Role::Player, X, Z);
    s.submit(PLAYER, req(1, mine(X - 3, 0, Z + 2, 2)), 0)
        .unwrap();
    let out = s.tick(0);
    assert!(!out.applied.is_empty());
    // Two ticks on one chunk, in different layers, the second applied
    // ahead (one edit a tick, both queued before).
    s.submit(PLAYER, req(2, mine(X + 2, 0, 98, 2)), 0).unwrap();
    s.submit(PLAYER, req(3, mine(X + 2, 0, 106, 2)), 0).unwrap();
    let (mut first, first_meshes) = s.tick_apply(1);
    let (mut second, second_meshes) = s.tick_apply(2);
    assert_eq!((first.applied.len(), second.applied.len()), (1, 1));
    let ahead: HashSet<ChunkPos> = second.applied[0].changes.iter().map(|c| c.pos).collect();
    let built = second_meshes.build();
    assert!(built.layers.whole_copies > 0, "{:?}", built.layers);
    s.finish_tick(&mut first, first_meshes.build(), &ahead);
    s.finish_tick(&mut second, built, &HashSet::new());
    for c in &second.applied[0].changes {
        let fresh = CollisionMesh::build(
            c.pos,
            c.to_version,
            &Neighborhood::from_world(s.world(), c.pos),
        );
        assert_eq!(c.mesh_hash, fresh.hash, "{:?}", c.pos);
    }
}
