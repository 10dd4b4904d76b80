//! Power cuts on LazyFS below the store and the data dir: whatever a
//! write method returned from is still there after every write that was
//! never fsynced is dropped. sled's `flush` alone fails these (its
//! `sync_file_range` leaves the data in LazyFS's cache, and its blob files
//! are never synced at all), and sled as published fails the last one on
//! its own (vendor/sled/STRATA.md).

use crate::store_common;

use store_common::{noisy_chunk, Seq};
use strata_server::datadir::DataDir;
use strata_server::store::{ChunkStore, SledStore, StoreConfig, StoredPosition, WorldMeta};
use strata_terrain::edit::FixedVec3;
use strata_terrain::ChunkPos;
use strata_tests::lazyfs::LazyFs;

const PARAMS: &str = "kind = \"hills\"";

#[test]
fn commits_blob_files_and_blobs_survive_a_power_cut() {
    let Some(mut fs) = LazyFs::for_test("commits_blob_files_and_blobs_survive_a_power_cut") else {
        return;
    };
    let dir = fs.mount_dir().join("world.sled");
    // No background thread (nothing syncs behind the store's back), and
    // sled's old 512 KiB segments, whose big leaves go to blob files.
    let config = StoreConfig {
        flush_every_ms: 0,
        segment_size_bytes: 512 * 1024,
        ..Default::default()
    };
    let store = SledStore::open_with(&dir, &config).unwrap();
    store.init_meta(&WorldMeta::new(7, 3, PARAMS)).unwrap();
    let mut seq = Seq::default();
    let mut blob_files = 0;
    for round in 0..4u64 {
        let edits: Vec<_> = (0..32)
            .map(|i| vec![(ChunkPos::new(i, 0, 0), noisy_chunk(round * 32 + i as u64))])
            .collect();
        store.commit_batch(&seq.delta_batch(&edits)).unwrap();
        let files = std::fs::read_dir(dir.join("blobs")).map_or(0, |d| d.count());
        blob_files = blob_files.max(files);
    }
    assert!(blob_files > 0, "the commits wrote sled blob files");
    store.put_blob("zones", b"[1,2,3]").unwrap();
    store.put_blob("scratch", b"gone").unwrap();
    assert!(store.delete_blob("scratch").unwrap());
    let ana = StoredPosition {
        feet: FixedVec3::from_voxels(70, 12, -40),
        known_ms: 1_790_000_000_000,
    };
    store.save_positions(&[("ana".to_string(), ana)]).unwrap();
    // The process "dies": no drop, no last flush.
    std::mem::forget(store);
    fs.power_cut();

    let store = SledStore::open_with(&dir, &config).unwrap();
    assert_eq!(store.last_seq().unwrap(), seq.last_seq);
    assert_eq!(store.load_meta().unwrap().unwrap().seed, 7);
    for i in 0..32 {
        let stored = store.load_chunk(ChunkPos::new(i, 0, 0)).unwrap().unwrap();
        assert_eq!(stored.version, 4);
        assert_eq!(stored.chunk, noisy_chunk(3 * 32 + i as u64));
    }
    assert_eq!(
        store.get_blob("zones").unwrap().as_deref(),
        Some(&b"[1,2,3]"[..])
    );
    assert_eq!(store.get_blob("scratch").unwrap(), None);
    let positions: Vec<_> = store.player_positions().map(|r| r.unwrap()).collect();
    assert_eq!(positions, vec![("ana".to_string(), ana)]);
    let report = store.check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

#[test]
fn a_new_data_dir_keeps_its_identity_through_a_power_cut() {
    let Some(mut fs) = LazyFs::for_test("a_new_data_dir_keeps_its_identity_through_a_power_cut")
    else {
        return;
    };
    let root = fs.mount_dir().join("data");
    let (made, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert!(report.created_secret.is_some() && report.created_cert.is_some());
    let cert = std::fs::read(made.cert_path()).unwrap();
    let secret = std::fs::read(made.secret_path()).unwrap();
    drop(made);
    fs.power_cut();

    // Nothing is generated again: tokens and pinned clients stay valid.
    let (kept, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert!(!report.created_anything(), "{report}");
    assert_eq!(std::fs::read(kept.cert_path()).unwrap(), cert);
    assert_eq!(std::fs::read(kept.secret_path()).unwrap(), secret);
}

/// Checkpoint folds are not flushed on their own (a flush would hold
/// sled's global lock, which commits need, while it waits for the disk):
/// the next commit's fsync carries them, and a fold no commit carried is
/// lost to a power cut without losing anything else, since reads replay
/// the deltas it would have removed.
#[test]
fn folds_ride_on_the_next_commit_and_a_lost_fold_loses_nothing() {
    let Some(mut fs) = LazyFs::for_test("folds_ride_on_the_next_commit") else {
        return;
    };
    let dir = fs.mount_dir().join("world.sled");
    // No background thread: only the store's own flushes reach the disk.
    let config = StoreConfig {
        flush_every_ms: 0,
        ..Default::default()
    };
    let store = SledStore::open_with(&dir, &config).unwrap();
    store.init_meta(&WorldMeta::new(7, 3, PARAMS)).unwrap();
    let chunks: Vec<ChunkPos> = (0..8).map(|i| ChunkPos::new(i, 1, -i)).collect();
    let mut seq = Seq::default();
    let round = |seq: &mut Seq, salt: u64, which: &[ChunkPos]| {
        let edits: Vec<_> = which
            .iter()
            .enumerate()
            .map(|(i, &p)| vec![(p, noisy_chunk(salt * 100 + i as u64))])
            .collect();
        seq.delta_batch(&edits)
    };
    store.commit_batch(&round(&mut seq, 1, &chunks)).unwrap();
    store.commit_batch(&round(&mut seq, 2, &chunks)).unwrap();
    store.commit_batch(&round(&mut seq, 3, &chunks)).unwrap();
    assert_eq!(store.delta_count().unwrap(), 16);

    // Folded, then carried by a commit to one other chunk.
    let (carried, lost) = chunks.split_at(4);
    assert_eq!(store.fold_chunks(carried).unwrap().chunks, 4);
    let other = ChunkPos::new(40, 0, 0);
    store.commit_batch(&round(&mut seq, 4, &[other])).unwrap();
    // Folded after the last commit, and never synced.
    assert_eq!(store.fold_chunks(lost).unwrap().chunks, 4);
    assert_eq!(store.delta_count().unwrap(), 0);
    std::mem::forget(store);
    fs.power_cut();

    let store = SledStore::open_with(&dir, &config).unwrap();
    assert_eq!(store.last_seq().unwrap(), seq.last_seq);
    // The carried folds stayed; the others left their deltas, unless sled
    // wrote them out on its own (a full log buffer is written and
    // fdatasynced at once): a chunk keeps both its deltas or neither.
    let left = store.chunks_with_deltas(None, usize::MAX).unwrap();
    assert!(left.iter().all(|p| lost.contains(p)), "{left:?}");
    assert_eq!(store.delta_count().unwrap() as usize, 2 * left.len());
    for (p, v) in &seq.versions {
        let stored = store.load_chunk(*p).unwrap().unwrap();
        assert_eq!((stored.version, &stored.chunk), (*v, &seq.states[p]));
    }
    assert!(store.check().unwrap().is_ok(), "{:?}", store.check());

    // `sync_folds` makes folds durable with no commit after them.
    assert_eq!(store.fold_chunks(lost).unwrap().chunks as usize, left.len());
    store.sync_folds().unwrap();
    std::mem::forget(store);
    fs.power_cut();
    let store = SledStore::open_with(&dir, &config).unwrap();
    assert_eq!(store.delta_count().unwrap(), 0);
    for (p, v) in &seq.versions {
        let stored = store.load_chunk(*p).unwrap().unwrap();
        assert_eq!((stored.version, &stored.chunk), (*v, &seq.states[p]));
    }
    assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
}

/// sled writes a leaf larger than a quarter segment to a blob file of its
/// own, and unlinks it once the page that replaced it counts as stable.
/// Folds rewrite chunk leaves with no sync of Strata's; sled's background
/// flush then writes them out. A power cut after that keeps every
/// acknowledged chunk: with `sync_file_range` as its barrier, sled had
/// unlinked the old leaf's blob while its replacement was still in the
/// cache, and the store lost the leaf or no longer opened
/// (vendor/sled/STRATA.md).
#[test]
fn a_blob_replaced_by_an_unsynced_fold_survives_a_power_cut() {
    let Some(mut fs) = LazyFs::for_test("a_blob_replaced_by_an_unsynced_fold") else {
        return;
    };
    let dir = fs.mount_dir().join("world.sled");
    // sled's background flush on, and 512 KiB segments: big leaves go to
    // blob files.
    let config = StoreConfig {
        flush_every_ms: 10,
        segment_size_bytes: 512 * 1024,
        ..Default::default()
    };
    // Leaves of noisy chunks go to blob files; those of the others (a few
    // KiB each) stay inline and fill segments, which sled must retire
    // before it removes the blobs their pages replaced.
    let noisy: Vec<ChunkPos> = (0..32).map(|i| ChunkPos::new(i, 0, 0)).collect();
    let inline: Vec<ChunkPos> = (0..160).map(|i| ChunkPos::new(i, 1, 0)).collect();
    let chunks: Vec<ChunkPos> = noisy.iter().chain(&inline).copied().collect();
    let mut seq = Seq::default();
    let mut store = SledStore::open_with(&dir, &config).unwrap();
    store.init_meta(&WorldMeta::new(7, 3, PARAMS)).unwrap();
    // Whether the flush beat the cut is timing: four cuts, each after its
    // own unsynced fold (sled's own barrier lost the world in about a
    // third of them).
    for cut in 0..4u64 {
        for round in 0..6u64 {
            let salt = |i: usize| (cut * 10 + round) * 1000 + i as u64;
            let edits: Vec<_> = noisy
                .iter()
                .enumerate()
                .map(|(i, &p)| vec![(p, noisy_chunk(salt(i)))])
                .chain(
                    inline
                        .iter()
                        .enumerate()
                        .map(|(i, &p)| vec![(p, speckled_chunk(salt(500 + i)))]),
                )
                .collect();
            store.commit_batch(&seq.delta_batch(&edits)).unwrap();
            // Folded (the noisy leaves rewritten as blobs), made durable
            // by `sync_folds`; the last round's fold is not.
            store.fold_chunks(&chunks).unwrap();
            if round < 5 {
                store.sync_folds().unwrap();
            }
        }
        // sled's background flush writes the unsynced fold out meanwhile.
        std::thread::sleep(std::time::Duration::from_millis(300));
        std::mem::forget(store);
        fs.power_cut();

        store = SledStore::open_with(&dir, &config).unwrap();
        assert_eq!(store.last_seq().unwrap(), seq.last_seq, "cut {cut}");
        for (p, v) in &seq.versions {
            let stored = store.load_chunk(*p).unwrap().unwrap();
            assert_eq!((stored.version, &stored.chunk), (*v, &seq.states[p]));
        }
        assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
    }
}

/// Stone with one voxel in sixteen of random density: a few KiB encoded.
fn speckled_chunk(salt: u64) -> strata_terrain::Chunk {
    let noisy = noisy_chunk(salt);
    let mut d = strata_terrain::chunk::DenseChunk::filled(strata_terrain::Voxel::solid(1));
    let strata_terrain::Chunk::Dense(n) = &noisy else {
        unreachable!("noisy chunks are dense")
    };
    for i in (0..strata_terrain::CHUNK_VOLUME).step_by(16) {
        d.set(i, n.get(i));
    }
    strata_terrain::Chunk::Dense(d)
}
