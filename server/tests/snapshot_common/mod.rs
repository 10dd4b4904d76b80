//! Helpers shared by the online snapshot tests: standing spots on the
//! generated ground, the world at a seq rebuilt from the edit log, and a
//! snapshot file checked against it.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use strata_server::datadir::DataDir;
use strata_server::snapshot::SnapshotReader;
use strata_server::store::{ChunkStore, SledStore};
use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::edit::{EditContext, StructureLibrary};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{ChunkPos, FixedVec3, MaterialTable, VoxelPos, World};

/// A ground voxel at (x, z) and the feet position standing on it.
pub fn spot(x: i32, z: i32) -> (FixedVec3, VoxelPos) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let y = g.surface_height(x, z);
    (
        FixedVec3::from_f64([x as f64, y + 1.0, z as f64]).unwrap(),
        VoxelPos::new(x, y.floor() as i32, z),
    )
}

/// The world after replaying the store's log up to `seq` on a fresh world,
/// with the version of every chunk the log changed.
pub fn replay(store: &SledStore, seq: u64) -> (World, BTreeMap<ChunkPos, u64>) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let mut world = World::new(Arc::new(g));
    let materials = MaterialTable::default();
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    let mut versions = BTreeMap::new();
    for e in store.edit_log(1..=seq) {
        let e = e.unwrap();
        e.edit.apply(&mut world, &ctx).unwrap();
        for (pos, v) in e.changes {
            assert_eq!(
                world.chunk(pos).version,
                v,
                "replay of seq {} diverged",
                e.seq
            );
            versions.insert(pos, v);
        }
    }
    (world, versions)
}

/// Checks snapshot `file` against the stopped server's store in `data`:
/// every chunk hash, and the chunk set with versions, equal the edit log
/// replayed to `seq`. Returns the store, that world and the snapshot's
/// own chunk versions (equal to the replay's, checked here).
pub fn assert_snapshot_is_log_at(
    data: &Path,
    file: &Path,
    seq: u64,
) -> (SledStore, World, BTreeMap<ChunkPos, u64>) {
    let dd = DataDir::open_existing(data).unwrap();
    let store = SledStore::open(&dd.world_db_path()).unwrap();
    let (mut world, versions) = replay(&store, seq);
    let mut reader = SnapshotReader::open(file).unwrap();
    let mut in_snapshot = BTreeMap::new();
    while let Some(c) = reader.next_chunk().unwrap() {
        let chunk = decode_chunk(&c.payload).unwrap();
        let want = chunk_hash(&world.chunk(c.pos).chunk);
        assert_eq!(chunk_hash(&chunk), want, "{:?}", c.pos);
        in_snapshot.insert(c.pos, c.version);
    }
    assert_eq!(in_snapshot, versions, "chunk set and versions at seq {seq}");
    (store, world, in_snapshot)
}
