//! `check` finds planted damage and names the exact record. Damage is
//! planted by opening the sled database directly, as a bad disk or a bug
//! elsewhere would leave it.

use crate::store_common;

use std::path::Path;

use store_common::{terrain_chunk, Seq};
use strata_server::store::keys::{chunk_key, delta_key, seq_key};
use strata_server::store::{
    encode_chunk_value, CheckIssue, ChunkStore, SledStore, StoreError, WorldMeta, META_LAST_SEQ,
    STORE_FORMAT_VERSION, TREE_CHUNKS, TREE_DELTAS, TREE_LOG, TREE_META,
};
use strata_terrain::{Chunk, ChunkPos};

const A: ChunkPos = ChunkPos::new(0, 0, 0);
const B: ChunkPos = ChunkPos::new(-1, 2, -3);
const C: ChunkPos = ChunkPos::new(4, -4, 1);

/// A healthy store: seq 1 changes A, seq 2 changes A and B, seq 3 changes C.
fn healthy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let store = SledStore::open(dir.path()).unwrap();
    store.init_meta(&WorldMeta::new(5, 1, "")).unwrap();
    let mut seq = Seq::default();
    store
        .commit_batch(&seq.batch(&[
            vec![(A, terrain_chunk(1))],
            vec![(A, terrain_chunk(2)), (B, Chunk::default())],
        ]))
        .unwrap();
    store
        .commit_batch(&seq.batch(&[vec![(C, terrain_chunk(3))]]))
        .unwrap();
    let report = store.check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    assert_eq!((report.log_entries, report.chunks), (3, 3));
    dir
}

/// Runs `damage` on the raw sled trees, then checks through the store.
fn damaged(damage: impl FnOnce(&sled::Db)) -> (tempfile::TempDir, Vec<CheckIssue>) {
    let dir = healthy();
    plant(dir.path(), damage);
    let store = SledStore::open(dir.path()).unwrap();
    let report = store.check().unwrap();
    assert!(!report.is_ok());
    for i in &report.issues {
        // Every issue renders as a line naming its record.
        assert!(!i.to_string().is_empty());
    }
    drop(store);
    (dir, report.issues)
}

fn plant(dir: &Path, damage: impl FnOnce(&sled::Db)) {
    let db = strata_server::store::open_raw(dir).unwrap();
    damage(&db);
    db.flush().unwrap();
}

#[test]
fn garbage_chunk_bytes_are_reported_by_position() {
    let (dir, issues) = damaged(|db| {
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        let mut v = 2u64.to_be_bytes().to_vec();
        v.extend_from_slice(&[0x02, 0xde, 0xad, 0xbe, 0xef]);
        chunks.insert(chunk_key(A), v).unwrap();
        chunks.insert(chunk_key(B), &[1, 2, 3][..]).unwrap();
    });
    assert_eq!(issues.len(), 2, "{issues:?}");
    assert!(
        matches!(&issues[0], CheckIssue::BadChunkRecord { pos, reason } if *pos == B && reason.contains("3 bytes"))
    );
    assert!(
        matches!(&issues[1], CheckIssue::BadChunkRecord { pos, reason } if *pos == A && reason.contains("does not decode"))
    );
    assert!(issues[0].to_string().contains("chunk (-1, 2, -3)"));
    // Loading the damaged chunk is a typed error, not a panic.
    let store = SledStore::open(dir.path()).unwrap();
    assert!(matches!(store.load_chunk(A), Err(StoreError::Codec { .. })));
    assert!(matches!(
        store.load_chunk(B),
        Err(StoreError::Corrupt { .. })
    ));
    assert!(store.raw_chunks().any(|r| r.is_err()));
}

#[test]
fn orphan_chunk_is_reported() {
    let orphan = ChunkPos::new(100, -100, 7);
    let (_dir, issues) = damaged(|db| {
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        chunks
            .insert(chunk_key(orphan), encode_chunk_value(1, &terrain_chunk(9)))
            .unwrap();
    });
    assert_eq!(
        issues,
        vec![CheckIssue::OrphanChunk {
            pos: orphan,
            version: 1
        }]
    );
}

#[test]
fn missing_chunk_is_reported() {
    let (_dir, issues) = damaged(|db| {
        db.open_tree(TREE_CHUNKS)
            .unwrap()
            .remove(chunk_key(C))
            .unwrap();
    });
    assert_eq!(
        issues,
        vec![CheckIssue::MissingChunk {
            pos: C,
            logged_version: 1,
            seq: 3
        }]
    );
}

#[test]
fn version_mismatch_is_reported() {
    let (_dir, issues) = damaged(|db| {
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        chunks
            .insert(chunk_key(A), encode_chunk_value(5, &terrain_chunk(2)))
            .unwrap();
    });
    assert_eq!(
        issues,
        vec![CheckIssue::VersionMismatch {
            pos: A,
            stored: 5,
            logged: 2,
            seq: 2
        }]
    );
}

/// Rewrites the log as a format-2 store holds it: one record per entry,
/// keyed by its seq, instead of one page per commit.
fn as_single_records(db: &sled::Db) {
    let log = db.open_tree(TREE_LOG).unwrap();
    for r in log.iter().collect::<Vec<_>>() {
        let (k, v) = r.unwrap();
        if k.len() != 16 {
            continue;
        }
        let mut seq = u64::from_be_bytes(k[..8].try_into().unwrap());
        let mut rest = &v[..];
        while !rest.is_empty() {
            let len = u32::from_le_bytes(rest[..4].try_into().unwrap()) as usize;
            log.insert(seq_key(seq), &rest[4..4 + len]).unwrap();
            rest = &rest[4 + len..];
            seq += 1;
        }
        log.remove(k).unwrap();
    }
}

#[test]
fn log_pages_and_single_records_read_as_one_log() {
    let dir = tempfile::tempdir().unwrap();
    let mut seq = Seq::default();
    {
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(5, 1, "")).unwrap();
        store
            .commit_batch(&seq.batch(&[vec![(A, terrain_chunk(1))], vec![(B, terrain_chunk(2))]]))
            .unwrap();
    }
    // Seqs 1 and 2 as a format-2 store wrote them, then a page of 3..=5.
    plant(dir.path(), as_single_records);
    let store = SledStore::open(dir.path()).unwrap();
    store
        .commit_batch(&seq.batch(&[
            vec![(A, terrain_chunk(3))],
            vec![(C, terrain_chunk(4))],
            vec![(B, terrain_chunk(5))],
        ]))
        .unwrap();
    let seqs = |lo: u64, hi: u64| -> Vec<u64> {
        store.edit_log(lo..=hi).map(|e| e.unwrap().seq).collect()
    };
    assert_eq!(seqs(1, 5), [1, 2, 3, 4, 5]);
    assert_eq!(seqs(2, 4), [2, 3, 4]);
    assert_eq!(seqs(4, 4), [4]);
    assert_eq!(seqs(5, 99), [5]);
    assert!(seqs(6, 9).is_empty());
    for s in 1..=5 {
        assert_eq!(store.log_entry(s).unwrap().unwrap().seq, s);
    }
    assert!(store.log_entry(6).unwrap().is_none());
    assert!(store.log_entry(0).unwrap().is_none());
    let report = store.check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    assert_eq!(report.log_entries, 5);
    drop(store);

    // A page cut short is reported at its first seq, and reads of it fail.
    plant(dir.path(), |db| {
        let log = db.open_tree(TREE_LOG).unwrap();
        let (k, v) = log.last().unwrap().unwrap();
        assert_eq!(k.len(), 16);
        log.insert(k, &v[..v.len() - 1]).unwrap();
    });
    let store = SledStore::open(dir.path()).unwrap();
    let issues = store.check().unwrap().issues;
    assert!(
        matches!(&issues[0], CheckIssue::BadLogRecord { seq: 3, reason } if reason.contains("page")),
        "{issues:?}"
    );
    assert!(store.edit_log(4..=4).any(|e| e.is_err()));
    assert!(matches!(
        store.log_entry(4),
        Err(StoreError::Corrupt { .. })
    ));
    assert_eq!(seqs_ok(&store, 1, 2), [1, 2]);
}

fn seqs_ok(store: &SledStore, lo: u64, hi: u64) -> Vec<u64> {
    store.edit_log(lo..=hi).map(|e| e.unwrap().seq).collect()
}

#[test]
fn log_damage_is_reported_by_seq() {
    let (_dir, issues) = damaged(|db| {
        as_single_records(db);
        let log = db.open_tree(TREE_LOG).unwrap();
        log.insert(seq_key(2), &[0xff; 5][..]).unwrap();
        log.remove(seq_key(3)).unwrap();
        log.insert(seq_key(5), log.get(seq_key(1)).unwrap().unwrap())
            .unwrap();
    });
    // seq 2 garbage, seq 5 after a gap and holding seq 1's record, C no
    // longer logged, B never logged, and meta last_seq 3 vs log 5.
    assert!(
        matches!(&issues[0], CheckIssue::BadLogRecord { seq: 2, .. }),
        "{issues:?}"
    );
    assert_eq!(
        issues[1],
        CheckIssue::LogGap {
            expected: 3,
            found: 5
        }
    );
    assert!(
        matches!(&issues[2], CheckIssue::BadLogRecord { seq: 5, reason } if reason.contains("record says seq 1"))
    );
    assert!(issues.contains(&CheckIssue::OrphanChunk { pos: B, version: 1 }));
    assert!(issues.contains(&CheckIssue::OrphanChunk { pos: C, version: 1 }));
    assert!(issues.contains(&CheckIssue::LastSeqMismatch { meta: 3, log: 5 }));
}

#[test]
fn last_seq_mismatch_and_bad_meta_are_reported() {
    let (_dir, issues) = damaged(|db| {
        let meta = db.open_tree(TREE_META).unwrap();
        meta.insert(META_LAST_SEQ, &9u64.to_be_bytes()[..]).unwrap();
    });
    assert_eq!(
        issues,
        vec![CheckIssue::LastSeqMismatch { meta: 9, log: 3 }]
    );
    let (dir, issues) = damaged(|db| {
        let meta = db.open_tree(TREE_META).unwrap();
        meta.insert(META_LAST_SEQ, &[1u8, 2][..]).unwrap();
    });
    assert!(
        matches!(&issues[0], CheckIssue::BadMeta { reason } if reason.contains("last_seq")),
        "{issues:?}"
    );
    // The store still opens (so check can run); reading the meta is an error.
    let store = SledStore::open(dir.path()).unwrap();
    assert!(matches!(store.load_meta(), Err(StoreError::Corrupt { .. })));
}

/// Rewrites the world record of the store in `dir` with `format_version`.
fn set_format(dir: &std::path::Path, format_version: u32) {
    plant(dir, |db| {
        let meta = db.open_tree(TREE_META).unwrap();
        let m = WorldMeta::new(5, 1, "");
        let json = serde_json::json!({
            "format_version": format_version,
            "seed": m.seed,
            "generator_version": m.generator_version,
            "generator_params": m.generator_params,
        });
        meta.insert(
            strata_server::store::META_WORLD,
            serde_json::to_vec(&json).unwrap(),
        )
        .unwrap();
    });
}

#[test]
fn unknown_format_version_refuses_to_open() {
    let dir = healthy();
    set_format(dir.path(), 99);
    let r = SledStore::open(dir.path());
    assert!(
        matches!(
            r,
            Err(StoreError::UnsupportedFormat {
                found: 99,
                supported: STORE_FORMAT_VERSION
            })
        ),
        "{r:?}"
    );
}

#[test]
fn stores_of_formats_1_to_3_are_upgraded_when_opened() {
    for old in [1, 2, 3] {
        let dir = healthy();
        set_format(dir.path(), old);
        let store = SledStore::open(dir.path()).unwrap();
        let meta = store.load_meta().unwrap().unwrap();
        assert_eq!(meta.format_version, STORE_FORMAT_VERSION);
        assert!(store.check().unwrap().is_ok());
        drop(store);
        // Upgraded on disk: opened again, it is at the new format.
        let store = SledStore::open(dir.path()).unwrap();
        assert_eq!(store.load_meta().unwrap().unwrap().format_version, 4);
    }
}

#[test]
fn falling_versions_and_bad_keys_are_reported() {
    let (_dir, issues) = damaged(|db| {
        // Seq 4 moves A back to version 1 (the log format is documented as
        // bincode 2 serde standard config, so a test can write it).
        let entry = strata_server::store::LogEntry {
            seq: 4,
            player: "mallory".into(),
            time_ms: 0,
            edit: store_common::mine_at(0, 0, 0),
            changes: vec![(A, 1)],
        };
        let bytes = bincode::serde::encode_to_vec(&entry, bincode::config::standard()).unwrap();
        db.open_tree(TREE_LOG)
            .unwrap()
            .insert(seq_key(4), bytes)
            .unwrap();
        let meta = db.open_tree(TREE_META).unwrap();
        meta.insert(META_LAST_SEQ, &4u64.to_be_bytes()[..]).unwrap();
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        chunks.insert(&b"short"[..], &b"x"[..]).unwrap();
    });
    assert_eq!(
        issues,
        vec![
            CheckIssue::VersionNotIncreasing {
                seq: 4,
                pos: A,
                to_version: 1,
                previous: 2
            },
            CheckIssue::BadChunkKey {
                key: "\"short\"".into()
            },
        ]
    );
}

#[test]
fn a_broken_delta_chain_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    {
        let store = SledStore::open(dir.path()).unwrap();
        store.init_meta(&WorldMeta::new(5, 1, "")).unwrap();
        let mut seq = Seq::default();
        for salt in 1..=3 {
            store
                .commit_batch(&seq.delta_batch(&[vec![(A, terrain_chunk(salt))]]))
                .unwrap();
        }
        assert_eq!(store.delta_count().unwrap(), 2);
        assert!(store.check().unwrap().is_ok());
    }
    // Lose the delta to version 2: the one to 3 no longer continues the chain.
    plant(dir.path(), |db| {
        db.open_tree(TREE_DELTAS)
            .unwrap()
            .remove(delta_key(A, 2))
            .unwrap();
    });
    let store = SledStore::open(dir.path()).unwrap();
    // A checkpoint reports the chunk and counts it skipped, not folded.
    let folded = store.fold_chunks(&[A]).unwrap();
    assert_eq!((folded.chunks, folded.skipped), (0, 1), "{folded:?}");
    let issues = store.check().unwrap().issues;
    assert!(
        issues.iter().any(|i| matches!(
            i,
            CheckIssue::BadDelta {
                pos: A,
                to_version: 3,
                ..
            }
        )),
        "{issues:?}"
    );
    assert!(
        issues.iter().any(|i| matches!(
            i,
            CheckIssue::VersionMismatch {
                pos: A,
                stored: 1,
                logged: 3,
                ..
            }
        )),
        "{issues:?}"
    );
    assert!(
        store.load_chunk(A).is_err(),
        "a read refuses the broken chain"
    );
}
