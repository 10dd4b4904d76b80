//! Bad commit batches are refused with a reason and change nothing, on
//! every backend.

use crate::store_common;

use store_common::{places, terrain_chunk, Seq};
use strata_server::store::{ChunkStore, CommitBatch, StoreError, WorldMeta};
use strata_terrain::{Chunk, ChunkPos};

fn reason(r: Result<impl std::fmt::Debug, StoreError>) -> String {
    match r {
        Err(StoreError::InvalidBatch { reason }) => reason,
        other => panic!("expected InvalidBatch, got {other:?}"),
    }
}

const P: ChunkPos = ChunkPos::new(2, 0, -2);
const Q: ChunkPos = ChunkPos::new(-5, 1, 0);

#[test]
fn commit_needs_metadata() {
    for place in places("commit_needs_metadata") {
        commit_needs_metadata_on(&*place.open());
    }
}

fn commit_needs_metadata_on(store: &dyn ChunkStore) {
    let b = Seq::default().batch(&[vec![(P, Chunk::default())]]);
    assert!(matches!(store.commit_batch(&b), Err(StoreError::NoMeta)));
    assert_eq!(store.chunk_count().unwrap(), 0);
}

#[test]
fn inconsistent_batches_are_refused_and_change_nothing() {
    for place in places("inconsistent_batches") {
        inconsistent_batches_on(&*place.open());
    }
}

fn inconsistent_batches_on(store: &dyn ChunkStore) {
    store.init_meta(&WorldMeta::new(9, 1, "")).unwrap();
    let mut seq = Seq::default();
    let good = seq.batch(&[
        vec![(P, terrain_chunk(0))],
        vec![(P, terrain_chunk(1)), (Q, Chunk::default())],
    ]);

    let mut b = good.clone();
    b.last_seq = 7;
    assert!(reason(store.commit_batch(&b)).contains("last_seq 7"));

    let mut b = good.clone();
    b.entries[1].seq = 5;
    assert!(reason(store.commit_batch(&b)).contains("consecutive"));

    let mut b = good.clone();
    b.chunks.retain(|c| c.0 != Q);
    assert!(reason(store.commit_batch(&b)).contains("missing"));

    let mut b = good.clone();
    b.chunks.iter_mut().find(|c| c.0 == P).unwrap().1 = 1;
    assert!(reason(store.commit_batch(&b)).contains("entries end it at 2"));

    let mut b = good.clone();
    b.chunks
        .push((ChunkPos::new(9, 9, 9), 1, Chunk::default().into()));
    assert!(reason(store.commit_batch(&b)).contains("no entry changed it"));

    let mut b = good.clone();
    b.entries[1].changes[0].1 = 1;
    assert!(reason(store.commit_batch(&b)).contains("not above 1"));

    let b = CommitBatch {
        chunks: good.chunks.clone(),
        ..CommitBatch::default()
    };
    assert!(reason(store.commit_batch(&b)).contains("without any log entry"));

    // Deltas of a stored chunk must run from its version before the batch
    // to the last one the entries give it, each from where one ended.
    let mut span_seq = Seq {
        last_seq: 0,
        versions: [(P, 1)].into(),
        states: [(P, terrain_chunk(0))].into(),
    };
    let edits = [
        vec![(P, terrain_chunk(1))],
        vec![(P, terrain_chunk(2))],
        vec![(P, terrain_chunk(3))],
    ];
    let per_change = Seq {
        versions: span_seq.versions.clone(),
        states: span_seq.states.clone(),
        ..Seq::default()
    }
    .delta_batch(&edits);
    let spanning = span_seq.span_batch(&edits);
    assert_eq!(spanning.deltas.len(), 1);
    let mut b = per_change.clone();
    b.deltas.remove(1);
    assert!(reason(store.commit_batch(&b)).contains("from version 3 to 4, expected from 2"));
    let mut b = per_change.clone();
    b.deltas.pop();
    assert!(reason(store.commit_batch(&b)).contains("state is missing"));
    let mut b = spanning.clone();
    b.deltas[0].to_version = 5;
    assert!(reason(store.commit_batch(&b)).contains("to at most 4"));
    let mut b = spanning.clone();
    b.deltas[0].from_version = 2;
    assert!(reason(store.commit_batch(&b)).contains("expected from 1"));
    let mut b = spanning.clone();
    b.deltas.push(per_change.deltas[2].clone());
    assert!(reason(store.commit_batch(&b)).contains("expected from 4"));

    // Seqs must follow the stored last_seq.
    let mut b = good.clone();
    for (i, e) in b.entries.iter_mut().enumerate() {
        e.seq = 10 + i as u64;
    }
    b.last_seq = 11;
    assert!(reason(store.commit_batch(&b)).contains("does not follow"));

    assert_eq!(store.chunk_count().unwrap(), 0);
    assert_eq!(store.last_seq().unwrap(), 0);
    assert_eq!(store.edit_log(0..=u64::MAX).count(), 0);

    // The untouched batch still commits; an empty batch is a no-op.
    store.commit_batch(&good).unwrap();
    store.commit_batch(&CommitBatch::default()).unwrap();
    assert_eq!(store.last_seq().unwrap(), 2);

    // Replaying it (same seqs, same versions) is refused and changes nothing.
    assert!(reason(store.commit_batch(&good)).contains("does not follow"));
    // A batch that would lower a stored version is refused inside the transaction.
    let mut stale = seq.batch(&[vec![(P, terrain_chunk(2))]]);
    stale.entries[0].changes[0].1 = 2;
    stale.chunks[0].1 = 2;
    assert!(reason(store.commit_batch(&stale)).contains("stored at version 2"));
    assert_eq!(store.last_seq().unwrap(), 2);
    let p = store.load_chunk(P).unwrap().unwrap();
    assert_eq!((p.version, p.chunk), (2, terrain_chunk(1)));
    assert!(store.check().unwrap().is_ok());
}

#[test]
fn oversized_log_record_is_refused() {
    for place in places("oversized_log_record") {
        oversized_log_record_on(&*place.open());
    }
}

fn oversized_log_record_on(store: &dyn ChunkStore) {
    store.init_meta(&WorldMeta::new(9, 1, "")).unwrap();
    let mut b = Seq::default().batch(&[vec![(P, Chunk::default())]]);
    b.entries[0].player = "x".repeat(strata_server::store::MAX_LOG_RECORD_BYTES);
    let err = store.commit_batch(&b).unwrap_err();
    assert!(
        matches!(&err, StoreError::Encode { what: "log entry", reason } if reason.contains("seq 1")),
        "{err}"
    );
    assert_eq!(store.last_seq().unwrap(), 0);
    assert_eq!(store.chunk_count().unwrap(), 0);
}
