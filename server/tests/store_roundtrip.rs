//! Round trips through a real store: sled in a tempdir, and PostgreSQL
//! where a test is not about sled's own files.

use crate::store_common;

use store_common::{noisy_chunk, places, terrain_chunk, Place, Seq};
use strata_server::store::keys::{chunk_key, chunk_pos_from_key};
use strata_server::store::{
    ChunkStore, SledStore, StoreError, WorldMeta, STORE_FORMAT_VERSION, TREE_CHUNKS,
};
use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::material::ids;
use strata_terrain::{Chunk, ChunkPos, Voxel};

const PARAMS: &str = "[terrain]\nsea_level = 0\n";

/// Each backend's store with a world's metadata.
fn new_stores(test: &str) -> Vec<(Place, Box<dyn ChunkStore>)> {
    places(test)
        .into_iter()
        .map(|place| {
            let store = place.open();
            store.init_meta(&WorldMeta::new(42, 3, PARAMS)).unwrap();
            (place, store)
        })
        .collect()
}

#[test]
fn meta_round_trips_and_is_idempotent() {
    for place in places("meta_round_trips") {
        meta_round_trips_on(&place);
    }
}

fn meta_round_trips_on(place: &Place) {
    let store = place.open();
    assert_eq!(store.load_meta().unwrap(), None);
    let meta = WorldMeta::new(0xDEAD_BEEF_F00D_u64, 7, PARAMS);
    assert_eq!(store.init_meta(&meta).unwrap(), meta);
    assert_eq!(store.load_meta().unwrap(), Some(meta.clone()));
    // Same inputs again: accepted, unchanged.
    assert_eq!(store.init_meta(&meta).unwrap(), meta);
    drop(store);
    let store = place.open();
    let loaded = store.load_meta().unwrap().unwrap();
    assert_eq!(loaded, meta);
    assert_eq!(loaded.format_version, STORE_FORMAT_VERSION);
}

#[test]
fn init_meta_refuses_different_generation_inputs() {
    for (_place, store) in new_stores("init_meta_refuses") {
        init_meta_refuses_on(&*store);
    }
}

fn init_meta_refuses_on(store: &dyn ChunkStore) {
    let err = store.init_meta(&WorldMeta::new(43, 3, PARAMS)).unwrap_err();
    assert!(
        matches!(&err, StoreError::MetaMismatch { field: "seed", stored, given } if stored == "42" && given == "43"),
        "{err}"
    );
    let err = store.init_meta(&WorldMeta::new(42, 4, PARAMS)).unwrap_err();
    assert!(matches!(
        err,
        StoreError::MetaMismatch {
            field: "generator_version",
            ..
        }
    ));
    let err = store
        .init_meta(&WorldMeta::new(42, 3, "other"))
        .unwrap_err();
    assert!(matches!(
        err,
        StoreError::MetaMismatch {
            field: "generator_params",
            ..
        }
    ));
    let mut bad = WorldMeta::new(42, 3, PARAMS);
    bad.last_seq = 5;
    assert!(matches!(
        store.init_meta(&bad),
        Err(StoreError::InvalidMeta { .. })
    ));
    bad = WorldMeta::new(42, 3, PARAMS);
    bad.format_version = 99;
    assert!(matches!(
        store.init_meta(&bad),
        Err(StoreError::UnsupportedFormat { found: 99, .. })
    ));
    assert_eq!(store.load_meta().unwrap().unwrap().seed, 42);
}

#[test]
fn chunks_round_trip_uniform_and_dense() {
    for (_place, store) in new_stores("chunks_round_trip") {
        chunks_round_trip_on(&*store);
    }
}

fn chunks_round_trip_on(store: &dyn ChunkStore) {
    let mut seq = Seq::default();
    let rock = Chunk::uniform(Voxel::solid(ids::STONE));
    let dense = terrain_chunk(1);
    let a = ChunkPos::new(-1, 0, 7);
    let b = ChunkPos::new(3, -2, -9);
    assert!(store.load_chunk(a).unwrap().is_none());
    let stats = store
        .commit_batch(&seq.batch(&[vec![(a, rock.clone()), (b, dense.clone())]]))
        .unwrap();
    assert!(stats.bytes_written > 0);
    let got_a = store.load_chunk(a).unwrap().unwrap();
    assert_eq!((got_a.chunk, got_a.version), (rock.clone(), 1));
    let got_b = store.load_chunk(b).unwrap().unwrap();
    assert_eq!((got_b.chunk, got_b.version), (dense.clone(), 1));
    // The raw stream carries the codec bytes: tiny for uniform, decodable for dense.
    let raw: Vec<_> = store.raw_chunks().collect::<Result<_, _>>().unwrap();
    assert_eq!(raw.len(), 2);
    let raw_a = raw.iter().find(|r| r.pos == a).unwrap();
    assert_eq!(raw_a.encoded.len(), 3);
    let raw_b = raw.iter().find(|r| r.pos == b).unwrap();
    assert!(
        raw_b.encoded.len() < 16 * 1024,
        "dense chunk {} bytes",
        raw_b.encoded.len()
    );
    assert_eq!(decode_chunk(&raw_b.encoded).unwrap(), dense);
    assert_eq!(store.chunk_count().unwrap(), 2);
    assert!(store.size_on_disk().unwrap() > 0);
}

#[test]
fn batches_and_log_ranges_round_trip_across_reopen() {
    for place in places("batches_and_log_ranges") {
        batches_and_log_ranges_on(&place);
    }
}

fn batches_and_log_ranges_on(place: &Place) {
    let mut seq = Seq::default();
    let p = |i: i32| ChunkPos::new(i, -i, i * 2);
    let mut batches = Vec::new();
    {
        let store = place.open();
        store.init_meta(&WorldMeta::new(1, 1, PARAMS)).unwrap();
        for round in 0..4u32 {
            // Three edits per tick; edits 0 and 2 touch the same chunk.
            let b = seq.batch(&[
                vec![(p(0), terrain_chunk(round * 3))],
                vec![
                    (p(1), terrain_chunk(round * 3 + 1)),
                    (p(2), Chunk::default()),
                ],
                vec![(p(0), terrain_chunk(round * 3 + 2))],
            ]);
            store.commit_batch(&b).unwrap();
            batches.push(b);
        }
        assert_eq!(store.last_seq().unwrap(), 12);
    }
    let store = place.open();
    assert_eq!(store.load_meta().unwrap().unwrap().last_seq, 12);
    let all: Vec<_> = batches.iter().flat_map(|b| b.entries.clone()).collect();
    let log: Vec<_> = store.edit_log(1..=12).collect::<Result<_, _>>().unwrap();
    assert_eq!(log, all);
    let mid: Vec<_> = store.edit_log(5..=7).collect::<Result<_, _>>().unwrap();
    assert_eq!(mid, all[4..7].to_vec());
    assert_eq!(store.edit_log(11..=100).count(), 2);
    #[allow(clippy::reversed_empty_ranges)]
    let empty = store.edit_log(9..=3).count();
    assert_eq!(empty, 0);
    assert_eq!(store.log_entry(4).unwrap().as_ref(), Some(&all[3]));
    assert_eq!(store.log_entry(13).unwrap(), None);
    // p(0) changed twice per tick: version 8, holding the last state.
    let c0 = store.load_chunk(p(0)).unwrap().unwrap();
    assert_eq!((c0.version, c0.chunk), (8, terrain_chunk(11)));
    let versions: Vec<_> = store.modified_chunks().collect::<Result<_, _>>().unwrap();
    let mut expected = vec![(p(0), 8), (p(1), 4), (p(2), 4)];
    expected.sort();
    assert_eq!(versions, expected);
    assert!(
        store.check().unwrap().is_ok(),
        "{:?}",
        store.check().unwrap()
    );
}

#[test]
fn modified_chunks_reads_versions_without_decoding_bodies() {
    let dir = tempfile::tempdir().unwrap();
    let mut seq = Seq::default();
    let (a, b, c) = (
        ChunkPos::new(0, 0, 0),
        ChunkPos::new(-4, 1, 9),
        ChunkPos::new(2, -3, 1),
    );
    {
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(1, 1, PARAMS)).unwrap();
        let dense = noisy_chunk(5);
        store
            .commit_batch(&seq.batch(&[vec![(a, dense.clone()), (b, terrain_chunk(2))]]))
            .unwrap();
        store.commit_batch(&seq.batch(&[vec![(a, dense)]])).unwrap();
    }
    // Replace b's body with bytes that do not decode, keeping its version.
    {
        let db = strata_server::store::open_raw(dir.path()).unwrap();
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        let mut garbage = 1u64.to_be_bytes().to_vec();
        garbage.extend_from_slice(b"\x28\xb5\x2f\xfd not zstd");
        chunks.insert(chunk_key(b), garbage).unwrap();
        db.flush().unwrap();
    }
    let store = SledStore::open(dir.path()).unwrap();
    assert!(store.load_chunk(b).is_err(), "b's body is corrupt");
    let versions: Vec<_> = store.modified_chunks().collect::<Result<_, _>>().unwrap();
    let mut expected = vec![(a, 2), (b, 1)];
    expected.sort();
    assert_eq!(versions, expected);
    drop(store);

    // A value too short to hold a version is corruption, named by position.
    {
        let db = strata_server::store::open_raw(dir.path()).unwrap();
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        chunks.insert(chunk_key(c), &[0u8, 1, 2][..]).unwrap();
        db.flush().unwrap();
    }
    let store = SledStore::open(dir.path()).unwrap();
    let results: Vec<_> = store.modified_chunks().collect();
    assert_eq!(results.len(), 3);
    let err = results.into_iter().find_map(Result::err).unwrap();
    assert!(matches!(err, StoreError::Corrupt { .. }), "{err}");
    assert!(err.to_string().contains("(2, -3, 1)"), "{err}");
}

#[test]
fn key_order_matches_chunk_pos_order_including_negatives() {
    for (_place, store) in new_stores("key_order") {
        key_order_on(&*store);
    }
}

fn key_order_on(store: &dyn ChunkStore) {
    let vals = [i32::MIN, -70_000, -33, -1, 0, 1, 32, 70_000, i32::MAX];
    let mut positions = Vec::new();
    for (i, &x) in vals.iter().enumerate() {
        let y = vals[(i * 4) % vals.len()];
        let z = vals[(i * 7 + 3) % vals.len()];
        positions.push(ChunkPos::new(x, y, z));
        positions.push(ChunkPos::new(-7, y, z));
        positions.push(ChunkPos::new(x, -7, z));
    }
    positions.sort();
    positions.dedup();
    for w in positions.windows(2) {
        assert!(chunk_key(w[0]) < chunk_key(w[1]), "{:?} {:?}", w[0], w[1]);
    }
    // Commit in a scrambled order; the store iterates in ChunkPos order.
    let mut seq = Seq::default();
    let mut scrambled = positions.clone();
    scrambled.reverse();
    scrambled.rotate_left(5);
    let edits: Vec<_> = scrambled
        .iter()
        .map(|p| vec![(*p, Chunk::uniform(Voxel::solid(ids::DIRT)))])
        .collect();
    store.commit_batch(&seq.batch(&edits)).unwrap();
    let stored: Vec<_> = store.modified_chunks().map(|r| r.unwrap().0).collect();
    assert_eq!(stored, positions);
    for p in &positions {
        assert_eq!(chunk_pos_from_key(&chunk_key(*p)), Some(*p));
    }
}

#[test]
fn blobs_round_trip_and_enforce_limits() {
    for place in places("blobs_round_trip") {
        blobs_round_trip_on(&place);
    }
}

fn blobs_round_trip_on(place: &Place) {
    {
        let store = place.open();
        assert_eq!(store.get_blob("zones").unwrap(), None);
        store
            .put_blob("zones", b"[[zone]]\nname = \"spawn\"")
            .unwrap();
        store.put_blob("other", &[0, 1, 2]).unwrap();
        assert!(store.delete_blob("other").unwrap());
        assert!(!store.delete_blob("other").unwrap());
        assert!(matches!(
            store.put_blob("", b"x"),
            Err(StoreError::InvalidBlob { .. })
        ));
        let long = "n".repeat(strata_server::store::MAX_BLOB_NAME_BYTES + 1);
        assert!(matches!(
            store.get_blob(&long),
            Err(StoreError::InvalidBlob { .. })
        ));
        let big = vec![0u8; strata_server::store::MAX_BLOB_BYTES + 1];
        assert!(matches!(
            store.put_blob("big", &big),
            Err(StoreError::InvalidBlob { .. })
        ));
        assert_eq!(store.get_blob("big").unwrap(), None);
    }
    let store = place.open();
    assert_eq!(
        store.get_blob("zones").unwrap().as_deref(),
        Some(&b"[[zone]]\nname = \"spawn\""[..])
    );
    assert_eq!(store.get_blob("other").unwrap(), None);
}

#[test]
fn a_blob_is_swapped_only_over_what_was_read() {
    for place in places("blob_swap") {
        let store = place.open();
        // None: written only where there is no blob yet.
        assert!(store.swap_blob("access", None, b"one").unwrap());
        assert!(!store.swap_blob("access", None, b"two").unwrap());
        assert!(!store.swap_blob("access", Some(b"zero"), b"two").unwrap());
        assert_eq!(
            store.get_blob("access").unwrap().as_deref(),
            Some(&b"one"[..])
        );
        assert!(store.swap_blob("access", Some(b"one"), b"two").unwrap());
        // Limits hold as for `put_blob`, and a refusal writes nothing.
        let big = vec![0u8; strata_server::store::MAX_BLOB_BYTES + 1];
        assert!(matches!(
            store.swap_blob("access", Some(b"two"), &big),
            Err(StoreError::InvalidBlob { .. })
        ));
        drop(store);
        let store = place.open();
        assert_eq!(
            store.get_blob("access").unwrap().as_deref(),
            Some(&b"two"[..])
        );
    }
}

/// Writers racing on one blob, each adding its mark to what it read and
/// swapping until it succeeds: no mark is lost (sled's compare-and-swap;
/// PostgreSQL's row lock, the WHERE re-checked on the row it waited for).
#[test]
fn racing_swaps_lose_no_change() {
    for place in places("blob_swap_race") {
        // On PostgreSQL four stores of their own (as four nodes); sled
        // opens once, so its four writers share it.
        let first: std::sync::Arc<dyn ChunkStore> = place.open().into();
        let stores: Vec<std::sync::Arc<dyn ChunkStore>> = (0..4)
            .map(|i| match place {
                Place::Postgres(_) if i > 0 => place.open().into(),
                _ => first.clone(),
            })
            .collect();
        std::thread::scope(|scope| {
            for (w, store) in stores.iter().enumerate() {
                scope.spawn(move || {
                    for i in 0..25 {
                        loop {
                            let raw = store.get_blob("marks").unwrap();
                            let mut next = raw.clone().unwrap_or_default();
                            next.extend_from_slice(format!("{w}.{i};").as_bytes());
                            if store.swap_blob("marks", raw.as_deref(), &next).unwrap() {
                                break;
                            }
                        }
                    }
                });
            }
        });
        let marks = stores[0].get_blob("marks").unwrap().unwrap();
        let text = String::from_utf8(marks).unwrap();
        assert_eq!(text.split_terminator(';').count(), 100, "{text}");
    }
}

#[test]
fn every_background_setting_keeps_overwritten_chunks() {
    // Off (no segment cleaning), the default slice, and sled's own period,
    // each with the smallest page cache so overwrites page in and out.
    for flush_every_ms in [0, strata_server::store::DEFAULT_FLUSH_EVERY_MS, 500] {
        let dir = tempfile::tempdir().unwrap();
        let config = strata_server::store::StoreConfig {
            cache_capacity_bytes: strata_server::store::MIN_CACHE_CAPACITY_BYTES,
            flush_every_ms,
            ..Default::default()
        };
        let store = SledStore::open_with(dir.path(), &config).unwrap();
        store.init_meta(&WorldMeta::new(42, 3, PARAMS)).unwrap();
        let mut seq = Seq::default();
        for round in 0..40u32 {
            let edits: Vec<Vec<(ChunkPos, Chunk)>> = (0..8)
                .map(|i| vec![(ChunkPos::new(i, 0, 0), terrain_chunk(round * 8 + i as u32))])
                .collect();
            store.commit_batch(&seq.batch(&edits)).unwrap();
        }
        drop(store);
        let store = SledStore::open_with(dir.path(), &config).unwrap();
        for i in 0..8 {
            let stored = store.load_chunk(ChunkPos::new(i, 0, 0)).unwrap().unwrap();
            assert_eq!(stored.version, 40, "flush_every_ms = {flush_every_ms}");
            assert_eq!(stored.chunk, terrain_chunk(39 * 8 + i as u32));
        }
        assert_eq!(store.last_seq().unwrap(), seq.last_seq);
    }
}

/// Most files in sled's `blobs` dir seen after each of `rounds` commits of
/// 32 large chunk records into a store with `segment_size_bytes`.
fn most_blob_files(segment_size_bytes: usize, rounds: u64) -> usize {
    let dir = tempfile::tempdir().unwrap();
    let config = strata_server::store::StoreConfig {
        segment_size_bytes,
        ..Default::default()
    };
    let store = SledStore::open_with(dir.path(), &config).unwrap();
    store.init_meta(&WorldMeta::new(42, 3, PARAMS)).unwrap();
    let mut seq = Seq::default();
    let mut most = 0;
    for round in 0..rounds {
        let edits: Vec<Vec<(ChunkPos, Chunk)>> = (0..32)
            .map(|i| vec![(ChunkPos::new(i, 0, 0), noisy_chunk(round * 32 + i as u64))])
            .collect();
        store.commit_batch(&seq.batch(&edits)).unwrap();
        let blobs = std::fs::read_dir(dir.path().join("blobs")).map_or(0, |d| d.count());
        most = most.max(blobs);
    }
    most
}

#[test]
fn leaves_of_large_chunks_stay_inline_with_the_default_segments() {
    // sled's own 512 KiB segments push a leaf of big records to a blob file
    // (created inside the commit, which must fsync it); the default keeps
    // them inline.
    assert!(
        most_blob_files(512 * 1024, 6) > 0,
        "the old size makes blob files"
    );
    assert_eq!(
        most_blob_files(strata_server::store::DEFAULT_SEGMENT_SIZE_BYTES, 6),
        0
    );
}

#[test]
fn an_existing_store_keeps_its_segment_size() {
    use strata_server::store::{persisted_segment_size, StoreConfig, DEFAULT_SEGMENT_SIZE_BYTES};
    let dir = tempfile::tempdir().unwrap();
    let old = StoreConfig {
        segment_size_bytes: 512 * 1024,
        ..Default::default()
    };
    let store = SledStore::open_with(dir.path(), &old).unwrap();
    store.init_meta(&WorldMeta::new(42, 3, PARAMS)).unwrap();
    let mut seq = Seq::default();
    let batch = seq.batch(&[vec![(ChunkPos::new(1, 2, 3), terrain_chunk(5))]]);
    store.commit_batch(&batch).unwrap();
    drop(store);
    assert_eq!(persisted_segment_size(dir.path()), Some(512 * 1024));
    // The default asks for another size; the store opens with its own.
    let store = SledStore::open_with(dir.path(), &StoreConfig::default()).unwrap();
    let stored = store.load_chunk(ChunkPos::new(1, 2, 3)).unwrap().unwrap();
    assert_eq!((stored.version, stored.chunk), (1, terrain_chunk(5)));
    drop(store);
    assert_eq!(persisted_segment_size(dir.path()), Some(512 * 1024));
    let fresh = tempfile::tempdir().unwrap();
    drop(SledStore::open(fresh.path()).unwrap());
    assert_eq!(
        persisted_segment_size(fresh.path()),
        Some(DEFAULT_SEGMENT_SIZE_BYTES)
    );
}

/// A position's feet stay a 12-byte record in `players`, the layout older
/// builds read (they open the store and resume players where they stood);
/// the time goes in `player_times`, which they do not know.
#[test]
fn positions_keep_the_feet_record_older_builds_read() {
    use strata_server::store::{StoredPosition, TREE_PLAYERS, TREE_PLAYER_TIMES};
    use strata_terrain::edit::{Fixed, FixedVec3};
    let dir = tempfile::tempdir().unwrap();
    let feet = FixedVec3::new(Fixed(256), Fixed(-512), Fixed(768));
    {
        let store = SledStore::open(dir.path()).unwrap();
        let p = StoredPosition {
            feet,
            known_ms: 1_790_000_000_000,
        };
        store.save_positions(&[("ana".into(), p)]).unwrap();
        let got: Vec<_> = store.player_positions().map(|r| r.unwrap()).collect();
        assert_eq!(got, [("ana".to_string(), p)]);
    }
    let db = strata_server::store::open_raw(dir.path()).unwrap();
    let record = db
        .open_tree(TREE_PLAYERS)
        .unwrap()
        .get("ana")
        .unwrap()
        .unwrap();
    assert_eq!(record.len(), 12);
    let x = i32::from_be_bytes(record[..4].try_into().unwrap());
    assert_eq!(x, 256);
    let time = db
        .open_tree(TREE_PLAYER_TIMES)
        .unwrap()
        .get("ana")
        .unwrap()
        .unwrap();
    assert_eq!(
        u64::from_be_bytes(time[..].try_into().unwrap()),
        1_790_000_000_000
    );
}

/// A position read while it is saved again is one save's, feet and time
/// together, whether read alone or in the walk over every player.
#[test]
fn a_position_read_during_saves_is_one_saves() {
    use std::sync::atomic::{AtomicBool, Ordering};
    use strata_server::store::StoredPosition;
    use strata_terrain::edit::{Fixed, FixedVec3};
    let dir = tempfile::tempdir().unwrap();
    let store = SledStore::open(dir.path()).unwrap();
    let at = |i: i32| StoredPosition {
        feet: FixedVec3::new(Fixed(i), Fixed(0), Fixed(0)),
        known_ms: i as u64,
    };
    let one_save = |p: StoredPosition| p.feet.x.0 as u64 == p.known_ms;
    store.save_positions(&[("ana".into(), at(0))]).unwrap();
    let done = AtomicBool::new(false);
    let reads = std::thread::scope(|s| {
        s.spawn(|| {
            for i in 1..=150 {
                store.save_positions(&[("ana".into(), at(i))]).unwrap();
            }
            done.store(true, Ordering::Release);
        });
        let mut reads = 0u64;
        while !done.load(Ordering::Acquire) {
            let p = store.player_position("ana").unwrap().unwrap();
            assert!(one_save(p), "{p:?} after {reads} reads");
            for r in store.player_positions() {
                let (_, p) = r.unwrap();
                assert!(one_save(p), "{p:?} in a walk after {reads} reads");
            }
            reads += 1;
        }
        reads
    });
    assert!(reads > 0);
    assert_eq!(store.player_position("ana").unwrap(), Some(at(150)));
}

/// A starting server remembers the players known most recently, not the
/// first by name, and a database reads only those.
#[test]
fn the_positions_a_server_starts_with_are_the_most_recent() {
    use strata_server::store::StoredPosition;
    use strata_terrain::edit::{Fixed, FixedVec3};
    for place in crate::store_common::places("recent_positions") {
        let store = place.open();
        let at = |v: i32, known_ms: u64| StoredPosition {
            feet: FixedVec3::new(Fixed(v), Fixed(v), Fixed(v)),
            known_ms,
        };
        let saved = [
            ("ana", at(1, 300)),
            ("bo", at(2, 100)),
            ("cy", at(3, 500)),
            ("di", at(4, 300)),
            ("ed", at(5, 0)),
        ];
        let named: Vec<(String, StoredPosition)> =
            saved.iter().map(|(n, p)| (n.to_string(), *p)).collect();
        store.save_positions(&named).unwrap();
        let names = |max| -> Vec<String> {
            store
                .recent_player_positions(max)
                .unwrap()
                .into_iter()
                .map(|(n, _)| n)
                .collect()
        };
        assert_eq!(names(3), ["cy", "ana", "di"], "{}", place.backend());
        assert_eq!(names(9), ["cy", "ana", "di", "bo", "ed"]);
        assert_eq!(names(0), Vec::<String>::new());
        let got = store.recent_player_positions(1).unwrap();
        assert_eq!(got, [("cy".to_string(), at(3, 500))]);
    }
}

/// Chunks read together say what each read alone says: records alone,
/// records with deltas past them, chunks never stored, and a position
/// named twice.
#[test]
fn chunks_read_together_are_each_as_read_alone() {
    for (_place, store) in new_stores("chunks_read_together") {
        let (a, b, c, never) = (
            ChunkPos::new(0, 0, 0),
            ChunkPos::new(1, -1, 2),
            ChunkPos::new(-3, 0, 7),
            ChunkPos::new(9, 9, 9),
        );
        let mut seq = Seq::default();
        store
            .commit_batch(&seq.batch(&[vec![(a, terrain_chunk(1)), (b, terrain_chunk(2))]]))
            .unwrap();
        // b and c then move on by deltas.
        store
            .commit_batch(&seq.delta_batch(&[
                vec![(b, terrain_chunk(3))],
                vec![(b, terrain_chunk(4)), (c, terrain_chunk(5))],
            ]))
            .unwrap();
        store
            .commit_batch(&seq.delta_batch(&[vec![(c, terrain_chunk(6))]]))
            .unwrap();
        let wanted = [c, never, a, b, c];
        let together = store.load_chunks(&wanted).unwrap();
        let alone: Vec<_> = wanted
            .iter()
            .map(|&p| store.load_chunk(p).unwrap())
            .collect();
        let show = |v: &[Option<strata_server::store::StoredChunk>]| -> Vec<Option<(u64, Chunk)>> {
            v.iter()
                .map(|s| s.as_ref().map(|s| (s.version, s.chunk.clone())))
                .collect()
        };
        assert_eq!(show(&together), show(&alone));
        assert_eq!(
            show(&together),
            [
                Some((2, terrain_chunk(6))),
                None,
                Some((1, terrain_chunk(1))),
                Some((3, terrain_chunk(4))),
                Some((2, terrain_chunk(6))),
            ]
        );
        assert!(store.load_chunks(&[]).unwrap().is_empty());
    }
}

/// The edit log's oldest entries go once older than the cut: whole
/// commits' worth from its start, up to the first newer entry. The log
/// base moves with them, the rest reads as before, the store checks clean
/// and its last seq stays, and commits go on after a log pruned empty.
/// The checkpoint thread's call, with `[store] log_retention`, prunes
/// what is older than that.
#[test]
fn the_log_is_pruned_from_its_start_up_to_the_first_newer_entry() {
    use strata_server::store::prune_log;
    // `Seq` times entry n at T0 + n.
    const T0: u64 = 1_700_000_000_000;
    for (place, store) in new_stores("the_log_is_pruned") {
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(1, 0, 0));
        let mut seq = Seq::default();
        let commits: [Vec<Vec<(ChunkPos, Chunk)>>; 3] = [
            vec![vec![(a, terrain_chunk(1))], vec![(b, terrain_chunk(2))]],
            vec![vec![(a, terrain_chunk(3))]],
            vec![vec![(b, terrain_chunk(4))], vec![(a, terrain_chunk(5))]],
        ];
        for edits in &commits {
            store.commit_batch(&seq.delta_batch(edits)).unwrap();
        }
        let logged = |s: &dyn ChunkStore| -> Vec<u64> {
            s.edit_log(1..=10).map(|e| e.unwrap().seq).collect()
        };
        assert_eq!(store.log_base().unwrap(), 0);
        assert_eq!(store.prune_log(T0 + 1, 100).unwrap(), 0, "none older");
        // Older than seq 4: the first two commits, seqs 1 to 3.
        assert_eq!(
            store.prune_log(T0 + 4, 100).unwrap(),
            3,
            "{}",
            place.backend()
        );
        assert_eq!(store.log_base().unwrap(), 3);
        assert_eq!(logged(&*store), [4, 5]);
        assert_eq!(store.log_entry(2).unwrap(), None);
        assert_eq!(store.last_seq().unwrap(), 5);
        let report = store.check().unwrap();
        assert!(report.is_ok(), "{}: {:?}", place.backend(), report.issues);
        // The retention the checkpoint gives: these entries are from 2023.
        let month = std::time::Duration::from_secs(30 * 24 * 3600);
        let second = std::time::Duration::from_secs(1);
        assert_eq!(prune_log(&*store, month, second).unwrap(), 2);
        assert_eq!(store.log_base().unwrap(), 5);
        assert_eq!(logged(&*store), Vec::<u64>::new());
        assert_eq!(store.last_seq().unwrap(), 5);
        store
            .commit_batch(&seq.delta_batch(&[vec![(b, terrain_chunk(6))]]))
            .unwrap();
        assert_eq!(logged(&*store), [6]);
        assert_eq!(
            store.load_chunk(a).unwrap().unwrap().chunk,
            terrain_chunk(5)
        );
        let report = store.check().unwrap();
        assert!(report.is_ok(), "{}: {:?}", place.backend(), report.issues);
    }
}

/// A log longer than one prune's batch drains in one pass, batch after
/// batch, within the pass's budget.
#[test]
fn a_log_longer_than_a_batch_drains_in_one_pass() {
    use strata_server::store::{prune_log, LOG_PRUNE_BATCH};
    for (place, store) in new_stores("a_log_longer_than_a_batch") {
        let mut seq = Seq::default();
        let a = ChunkPos::new(0, 0, 0);
        let edits: Vec<Vec<(ChunkPos, Chunk)>> =
            (0..1000).map(|i| vec![(a, terrain_chunk(i % 7))]).collect();
        let commits = LOG_PRUNE_BATCH / 1000 + 2;
        for _ in 0..commits {
            store.commit_batch(&seq.batch(&edits)).unwrap();
        }
        let month = std::time::Duration::from_secs(30 * 24 * 3600);
        let budget = std::time::Duration::from_secs(60);
        let removed = prune_log(&*store, month, budget).unwrap();
        assert_eq!(removed, 1000 * commits as u64, "{}", place.backend());
        assert_eq!(store.log_base().unwrap(), 1000 * commits as u64);
        assert_eq!(store.edit_log(1..=u64::MAX >> 2).count(), 0);
    }
}
