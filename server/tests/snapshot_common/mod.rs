//! Helpers shared by the snapshot tests: standing spots on the generated
//! ground, the world at a seq rebuilt from the edit log, a snapshot file
//! checked against it, and snapshot files written from generated chunks.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use strata_protocol::admin::ZoneSpec;
use strata_server::datadir::DataDir;
use strata_server::snapshot::{SnapshotHeader, SnapshotReader, SnapshotWriter};
use strata_server::store::{ChunkStore, SledStore};
use strata_terrain::chunk_codec::{decode_chunk, encode_chunk};
use strata_terrain::edit::{EditContext, StructureLibrary};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{ChunkGenerator, ChunkPos, FixedVec3, MaterialTable, VoxelPos, World};

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

/// The header of a default-generator world at `seq` with one zone.
pub fn header(seq: u64) -> SnapshotHeader {
    SnapshotHeader {
        seed: GenParams::default().seed,
        generator_version: strata_terrain::gen::GENERATOR_VERSION,
        seq,
        generator_params: toml::to_string(&GenParams::default()).unwrap(),
        zones: vec![ZoneSpec {
            name: "z".into(),
            min: VoxelPos::new(0, 0, 0),
            max: VoxelPos::new(1, 1, 1),
        }],
    }
}

/// Writes a snapshot of `header` holding generated chunks at the given
/// versions (ascending positions).
pub fn write_snapshot(path: &Path, header: &SnapshotHeader, chunks: &[(ChunkPos, u64)]) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = SnapshotWriter::new(file, header).unwrap();
    for &(pos, v) in chunks {
        w.chunk(pos, v, &encode_chunk(&g.generate(pos))).unwrap();
    }
    w.finish().unwrap();
}

/// Writes a snapshot of `header` holding `n` chunks of noise (each about
/// 64 KiB encoded: zstd finds nothing to take), in a row along x.
pub fn write_noise_snapshot(path: &Path, header: &SnapshotHeader, n: i32) {
    use strata_terrain::{Chunk, Voxel};
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = SnapshotWriter::new(file, header).unwrap();
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for x in 0..n {
        let mut c = Chunk::uniform(Voxel::AIR);
        for i in 0..strata_terrain::CHUNK_VOLUME {
            // xorshift64
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            c.set_index(i, Voxel::new(state as u8, 1 + (state >> 8) as u8 % 4));
        }
        w.chunk(ChunkPos::new(x, 0, 0), 1, &encode_chunk(&c))
            .unwrap();
    }
    w.finish().unwrap();
}
