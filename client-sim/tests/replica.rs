//! The replica applies what a server would send, detects gaps and bad
//! hashes, and checks mesh hashes against meshes built from the server's world.

use std::sync::Arc;

use strata_client_sim::{Replica, Request};
use strata_protocol::{DeltaUpdate, WorldUpdate};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::mesh::{mesh_chunk, MeshOptions, Neighborhood};
use strata_terrain::{
    ChunkGenerator, ChunkPos, Edit, EditContext, Fixed, FixedVec3, MaterialTable, World,
};

fn generator() -> Arc<Generator> {
    Arc::new(Generator::fractal(GenParams::default()).unwrap())
}

/// The chunks around `center` as a server sends them to a new client.
fn subscribe(replica: &mut Replica, center: ChunkPos) {
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let pos = center.offset(dx, dy, dz).unwrap();
                assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
            }
        }
    }
}

fn server_mesh_hash(world: &World, pos: ChunkPos) -> u64 {
    mesh_chunk(
        &Neighborhood::from_world(world, pos),
        &MeshOptions::default(),
    )
    .hash()
}

#[test]
fn deltas_and_meshes_follow_the_server() {
    let g = generator();
    let mut world = World::new(g.clone());
    let (x, z) = (40, 40);
    let y = g.surface_height(x, z).floor() as i32;
    let center = strata_terrain::VoxelPos::new(x, y, z).chunk();
    let mut replica = Replica::new(Some(g.clone() as Arc<dyn ChunkGenerator>));
    replica.record_history();
    subscribe(&mut replica, center);
    let around: Vec<ChunkPos> = (-2..=2)
        .flat_map(|dz| {
            (-2..=2).flat_map(move |dy| (-2..=2).map(move |dx| center.offset(dx, dy, dz).unwrap()))
        })
        .collect();
    world.load(around);
    let materials = MaterialTable::default();
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    for (seq, dx) in [(1u64, 0), (2, 2)] {
        let edit = Edit::Mine {
            center: FixedVec3::from_voxels(x + dx, y, z),
            radius: Fixed::from_voxels(3),
            strength: 255,
        };
        let out = edit.apply(&mut world, &ctx).unwrap();
        for ch in &out.changed {
            let after = world.peek(ch.pos).unwrap().chunk.clone();
            let delta =
                ChunkDelta::encode(ch.pos, ch.from_version, ch.to_version, &ch.before, &after)
                    .unwrap();
            let mesh_hash = server_mesh_hash(&world, ch.pos);
            assert_eq!(
                replica.apply(WorldUpdate::Delta(DeltaUpdate {
                    delta,
                    mesh_hash,
                    seq
                })),
                None
            );
        }
        assert_eq!(replica.apply(WorldUpdate::TickEnd { last_seq: seq }), None);
    }
    let stats = replica.stats;
    assert!(stats.deltas >= 2, "{stats:?}");
    assert_eq!(stats.mesh_mismatches, 0, "{:?}", replica.mesh_mismatches());
    assert!(stats.meshes_checked >= 1, "{stats:?}");
    let held = replica.get(center).unwrap();
    assert_eq!(held.version, 2);
    assert_eq!(
        chunk_hash(&held.chunk),
        chunk_hash(&world.peek(center).unwrap().chunk)
    );
    assert_eq!(replica.history().unwrap()[&center], vec![0, 1, 2]);
    assert_eq!(replica.last_seq(), 2);
}

#[test]
fn a_wrong_mesh_hash_is_reported_with_both_hashes() {
    let g = generator();
    let mut world = World::new(g.clone());
    let center = ChunkPos::new(0, 1, 0);
    let mut replica = Replica::new(Some(g.clone() as Arc<dyn ChunkGenerator>));
    subscribe(&mut replica, center);
    let before = strata_terrain::Chunk::clone(&world.chunk(center).chunk);
    let mut after = before.clone();
    after.set(5, 5, 5, strata_terrain::Voxel::solid(2));
    world.commit(center, after.clone());
    let delta = ChunkDelta::encode(center, 0, 1, &before, &after).unwrap();
    let good = server_mesh_hash(&world, center);
    replica.apply(WorldUpdate::Delta(DeltaUpdate {
        delta,
        mesh_hash: good ^ 1,
        seq: 1,
    }));
    replica.apply(WorldUpdate::TickEnd { last_seq: 1 });
    let m = replica.mesh_mismatches();
    assert_eq!(m.len(), 1);
    assert_eq!(
        (m[0].pos, m[0].version, m[0].server, m[0].client),
        (center, 1, good ^ 1, good)
    );
}

#[test]
fn gaps_and_bad_data_ask_for_a_resync() {
    let g = generator();
    let pos = ChunkPos::new(0, 0, 0);
    let mut replica = Replica::new(Some(g.clone() as Arc<dyn ChunkGenerator>));
    replica.apply(WorldUpdate::Generated { pos });
    let base = g.generate(pos);
    let mut v1 = base.clone();
    v1.set(1, 1, 1, strata_terrain::Voxel::AIR);
    let mut v2 = v1.clone();
    v2.set(2, 2, 2, strata_terrain::Voxel::solid(7));
    // A delta from version 1 while the replica holds version 0: a gap.
    let skip = ChunkDelta::encode(pos, 1, 2, &v1, &v2).unwrap();
    let r = replica.apply(WorldUpdate::Delta(DeltaUpdate {
        delta: skip,
        mesh_hash: 0,
        seq: 9,
    }));
    assert_eq!(r, Some(Request::Resync(pos)));
    assert!(
        replica.get(pos).is_none(),
        "a stale chunk is dropped until resent"
    );
    // A snapshot whose data does not match its hash is refused.
    let bad = WorldUpdate::Snapshot {
        pos,
        version: 2,
        hash: chunk_hash(&v2) ^ 1,
        mesh_hash: 0,
        data: encode_chunk(&v2),
    };
    assert_eq!(replica.apply(bad), Some(Request::Resync(pos)));
    let good = WorldUpdate::Snapshot {
        pos,
        version: 2,
        hash: chunk_hash(&v2),
        mesh_hash: 0,
        data: encode_chunk(&v2),
    };
    assert_eq!(replica.apply(good), None);
    assert_eq!(replica.get(pos).unwrap().version, 2);
    assert_eq!(replica.stats.gaps, 1);
    assert_eq!(replica.stats.hash_mismatches, 1);
    // Without a generator, version-0 chunks need full data.
    let mut blind = Replica::new(None);
    assert_eq!(
        blind.apply(WorldUpdate::Generated { pos }),
        Some(Request::FullSnapshot(pos))
    );
    blind.apply(WorldUpdate::Unsubscribed { pos });
    assert!(blind.is_empty());
}

#[test]
fn late_deltas_of_a_forgotten_chunk_are_dropped_not_resynced() {
    let g = generator();
    let mut replica = Replica::new(Some(g.clone() as Arc<dyn ChunkGenerator>));
    let pos = ChunkPos::new(1, 0, 1);
    assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
    let base = g.generate(pos);
    let mut target = base.clone();
    target.set(3, 3, 3, strata_terrain::Voxel::AIR);
    let delta = ChunkDelta::encode(pos, 0, 1, &base, &target).unwrap();
    let update = || {
        WorldUpdate::Delta(DeltaUpdate {
            delta: delta.clone(),
            mesh_hash: 0,
            seq: 1,
        })
    };
    // Forgotten: a delta the server sent before it handled the Forget.
    replica.drop_chunk(pos);
    assert!(replica.get(pos).is_none());
    assert_eq!(replica.apply(update()), None, "no resync for it");
    assert_eq!(replica.stats.gaps, 0);
    // A whole chunk the server sent before it handled the Forget is not
    // taken in: the server no longer sends its deltas, so it would go stale.
    assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
    assert!(replica.get(pos).is_none(), "late snapshot ignored");
    assert_eq!(replica.stats.generated, 1);
    // Asked for again (resync), it is held and takes deltas as usual.
    replica.undrop(pos);
    assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
    assert_eq!(replica.apply(update()), None);
    assert_eq!(replica.get(pos).map(|h| h.version), Some(1));
    // A chunk dropped without Forget (it left the view) is asked for again.
    assert_eq!(replica.apply(WorldUpdate::Unsubscribed { pos }), None);
    assert_eq!(replica.apply(update()), Some(Request::Resync(pos)));
    // A forgotten chunk that leaves the view and comes back is taken in.
    replica.drop_chunk(pos);
    assert_eq!(replica.apply(WorldUpdate::Unsubscribed { pos }), None);
    assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
    assert_eq!(replica.get(pos).map(|h| h.version), Some(0));
}
