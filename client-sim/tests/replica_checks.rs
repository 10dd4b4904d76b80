//! End-of-run chunk checks, stale mesh expectations and chunk sharing
//! between replicas.

use std::sync::Arc;

use strata_client_sim::{ChunkPool, Replica, Request};
use strata_protocol::{DeltaUpdate, WorldUpdate};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Voxel};

fn generator() -> Arc<dyn ChunkGenerator> {
    Arc::new(Generator::fractal(GenParams::default()).unwrap())
}

fn snapshot(pos: ChunkPos, version: u64, chunk: &Chunk, mesh_hash: u64) -> WorldUpdate {
    WorldUpdate::Snapshot {
        pos,
        version,
        hash: chunk_hash(chunk),
        mesh_hash,
        data: encode_chunk(chunk),
    }
}

#[test]
fn checks_compare_held_chunks_with_the_servers_copy() {
    let g = generator();
    let mut r = Replica::new(Some(g.clone()));
    let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
    r.apply(WorldUpdate::Generated { pos: a });
    r.apply(WorldUpdate::Generated { pos: b });
    r.expect_check(a);
    r.expect_check(b);
    assert_eq!(r.checks_pending(), 2);
    // The server's copy of `a` matches; its copy of `b` is a newer version.
    r.apply(snapshot(a, 0, &g.generate(a), 0));
    let mut newer = g.generate(b);
    newer.set(3, 3, 3, Voxel::solid(2));
    r.apply(snapshot(b, 4, &newer, 0));
    assert!(!r.is_checking(a) && !r.is_checking(b));
    assert_eq!((r.stats.checks_ok, r.stats.checks_failed), (1, 1));
}

#[test]
fn a_neighbour_changed_by_another_edit_drops_a_stale_mesh_expectation() {
    let g = generator();
    let mut r = Replica::new(Some(g.clone()));
    let center = ChunkPos::new(0, 0, 0);
    for dz in -2..=2 {
        for dy in -2..=2 {
            for dx in -2..=2 {
                let pos = center.offset(dx, dy, dz).unwrap();
                r.apply(WorldUpdate::Generated { pos });
            }
        }
    }
    // A snapshot of `center` whose mesh hash is deliberately wrong, then a
    // neighbour changes before the tick end: the check no longer applies.
    let mut c1 = g.generate(center);
    c1.set(1, 1, 1, Voxel::solid(3));
    r.apply(snapshot(center, 1, &c1, 12345));
    let n = ChunkPos::new(1, 0, 0);
    let before = g.generate(n);
    let mut after = before.clone();
    after.set(0, 1, 1, Voxel::solid(3));
    let delta = ChunkDelta::encode(n, 0, 1, &before, &after).unwrap();
    r.apply(WorldUpdate::Delta(DeltaUpdate {
        delta,
        mesh_hash: r.mesh_hash(n).unwrap() ^ 1,
        seq: 9,
    }));
    r.apply(WorldUpdate::TickEnd { last_seq: 9 });
    // Only the neighbour's own (wrong) hash was compared.
    assert_eq!(r.stats.meshes_checked, 1);
    assert_eq!(r.stats.mesh_mismatches, 1);
    assert_eq!(r.mesh_mismatches()[0].pos, n);
    assert!(r.stats.meshes_unverifiable >= 1);
}

#[test]
fn replicas_share_chunks_through_a_pool() {
    let g = generator();
    let pool = Arc::new(ChunkPool::default());
    let mut a = Replica::with_pool(Some(g.clone()), pool.clone());
    let mut b = Replica::with_pool(Some(g.clone()), pool.clone());
    let pos = ChunkPos::new(2, 0, 2);
    a.apply(WorldUpdate::Generated { pos });
    b.apply(WorldUpdate::Generated { pos });
    assert!(Arc::ptr_eq(
        &a.get(pos).unwrap().chunk,
        &b.get(pos).unwrap().chunk
    ));
    assert_eq!(pool.live_chunks(), 1);
    a.record_history();
    let mut v1 = g.generate(pos);
    v1.set(5, 5, 5, Voxel::AIR);
    a.apply(snapshot(pos, 1, &v1, 0));
    assert_eq!(a.version_hashes().unwrap()[&(pos, 1)], chunk_hash(&v1));
    assert_eq!(a.history().unwrap()[&pos], vec![1]);
}

#[test]
fn patches_rebuild_modified_chunks_from_the_generator_and_refuse_bad_bases() {
    let g = generator();
    let pos = ChunkPos::new(2, 1, 1);
    let base = g.generate(pos);
    let mut edited = base.clone();
    edited.set(4, 5, 6, Voxel::solid(3));
    let patch = |base: &Chunk| WorldUpdate::Patched {
        delta: ChunkDelta::encode(pos, 0, 3, base, &edited).unwrap(),
        mesh_hash: 0,
    };
    let mut r = Replica::new(Some(g.clone()));
    assert_eq!(r.apply(patch(&base)), None);
    let held = r.get(pos).unwrap();
    assert_eq!((held.version, &*held.chunk), (3, &edited));
    assert_eq!((r.stats.snapshots, r.stats.patched), (1, 1));
    // A patch built on another base fails its base-hash check: resync.
    let mut other = base.clone();
    other.set(0, 0, 0, Voxel::solid(9));
    let mut fresh = Replica::new(Some(g.clone()));
    assert_eq!(fresh.apply(patch(&other)), Some(Request::Resync(pos)));
    assert!(fresh.get(pos).is_none());
    assert_eq!(
        (
            fresh.stats.hash_mismatches,
            fresh.stats.patched,
            fresh.stats.snapshots
        ),
        (1, 0, 0)
    );
    // A client without the generator asks for the full chunk instead.
    let mut blind = Replica::new(None);
    assert_eq!(blind.apply(patch(&base)), Some(Request::FullSnapshot(pos)));
}
