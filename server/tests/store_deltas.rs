//! The small durable record: commits store deltas for chunks already
//! stored, reads replay them, a checkpoint folds them into chunk records
//! (also while commits run), and a reopened store replays what was not
//! folded. A delta that does not continue the stored chain is refused.
//! Every test runs on every backend.

use crate::store_common;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use store_common::{assert_reads, places, terrain_chunk, Place, Seq};
use strata_server::store::{pass_once, CheckpointPace, ChunkStore, WorldMeta};
use strata_terrain::ChunkPos;

const A: ChunkPos = ChunkPos { x: 1, y: 0, z: -2 };
const B: ChunkPos = ChunkPos { x: -4, y: 1, z: 3 };

fn open(place: &Place) -> Box<dyn ChunkStore> {
    let store = place.open();
    store.init_meta(&WorldMeta::new(5, 1, "")).unwrap();
    store
}

#[test]
fn deltas_replay_on_read_and_reopen_and_fold_at_a_checkpoint() {
    for place in places("deltas_replay") {
        deltas_replay_on(&place);
    }
}

fn deltas_replay_on(place: &Place) {
    let mut seq = Seq::default();
    {
        let store = open(place);
        // New chunks go whole, then each change of them as a delta.
        let first = seq.delta_batch(&[vec![(A, terrain_chunk(1)), (B, terrain_chunk(2))]]);
        assert_eq!((first.chunks.len(), first.deltas.len()), (2, 0));
        store.commit_batch(&first).unwrap();
        let next = seq.delta_batch(&[
            vec![(A, terrain_chunk(3))],
            vec![(A, terrain_chunk(4)), (B, terrain_chunk(5))],
        ]);
        assert_eq!((next.chunks.len(), next.deltas.len()), (0, 3));
        store.commit_batch(&next).unwrap();
        assert_eq!(store.delta_count().unwrap(), 3);
        assert_reads(&*store, A, 3, &terrain_chunk(4));
        assert_reads(&*store, B, 2, &terrain_chunk(5));
        assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
        // Closed with nothing folded (store_crash kills a process
        // mid-commit): the reopened store replays the deltas.
        drop(store);
    }
    let store = place.open();
    assert_eq!(store.delta_count().unwrap(), 3);
    assert_reads(&*store, A, 3, &terrain_chunk(4));
    assert_reads(&*store, B, 2, &terrain_chunk(5));

    let stats = store.checkpoint(1).unwrap();
    assert_eq!(stats.chunks, 1, "at most the chunks asked for");
    let stats = store.checkpoint(usize::MAX).unwrap();
    assert_eq!(stats.chunks, 1);
    assert_eq!(store.delta_count().unwrap(), 0);
    assert_eq!(store.checkpoint(usize::MAX).unwrap().chunks, 0);
    assert_reads(&*store, A, 3, &terrain_chunk(4));
    assert_reads(&*store, B, 2, &terrain_chunk(5));
    assert!(store.check().unwrap().is_ok());

    // The chain goes on from the folded record.
    store
        .commit_batch(&seq.delta_batch(&[vec![(A, terrain_chunk(6))]]))
        .unwrap();
    assert_reads(&*store, A, 4, &terrain_chunk(6));
    assert!(store.check().unwrap().is_ok());
}

#[test]
fn a_paced_pass_folds_in_slices_and_pauses_between_them() {
    for place in places("paced_pass") {
        paced_pass_on(&place);
    }
}

fn paced_pass_on(place: &Place) {
    let store = open(place);
    let chunks: Vec<ChunkPos> = (0..10).map(|i| ChunkPos::new(i, 0, -i)).collect();
    let mut seq = Seq::default();
    let whole: Vec<_> = chunks
        .iter()
        .map(|&p| vec![(p, terrain_chunk(1))])
        .collect();
    store.commit_batch(&seq.delta_batch(&whole)).unwrap();
    let changed: Vec<_> = (0..2u32)
        .flat_map(|round| {
            chunks
                .iter()
                .map(move |&p| vec![(p, terrain_chunk(2 + round))])
        })
        .collect();
    store.commit_batch(&seq.delta_batch(&changed)).unwrap();
    assert_eq!(store.delta_count().unwrap(), 20);

    let pace = |max_chunks, slice_chunks| CheckpointPace {
        every: std::time::Duration::from_secs(60),
        max_chunks,
        slice_chunks,
        log_retention: std::time::Duration::from_secs(3600),
    };
    // At most max_chunks a pass, in slices: 3 + 3 + 1.
    let first = pass_once(&*store, pace(7, 3), None).unwrap();
    assert_eq!(
        (first.folded.chunks, first.folded.deltas, first.slices),
        (7, 14, 3)
    );
    assert!(first.paused > std::time::Duration::ZERO, "{first:?}");
    assert!(!first.stopped);
    assert!(
        first.next.is_some(),
        "it listed max_chunks: the next goes on"
    );
    assert_eq!(store.delta_count().unwrap(), 6);
    // The rest, after the first pass's last chunk: one slice of 3, no
    // pause after the last slice, and the next pass starts over.
    let rest = pass_once(&*store, pace(7, 3), first.next).unwrap();
    assert_eq!((rest.folded.chunks, rest.slices), (3, 1), "{rest:?}");
    assert_eq!(rest.next, None);
    assert_eq!(rest.paused, std::time::Duration::ZERO);
    assert_eq!(store.delta_count().unwrap(), 0);
    assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
    for (p, v) in &seq.versions {
        assert_reads(&*store, *p, *v, &seq.states[p]);
    }
    let idle = pass_once(&*store, pace(usize::MAX, 3), None).unwrap();
    assert_eq!((idle.folded.chunks, idle.slices), (0, 0));
    // A chunk listed but folded meanwhile is skipped, uncounted.
    assert_eq!(store.fold_chunks(&chunks).unwrap().chunks, 0);
}

/// Chunks early in key order that change before every pass do not keep a
/// later one from being folded: each pass goes on where the last stopped.
#[test]
fn no_chunk_waits_behind_chunks_that_keep_changing() {
    for place in places("checkpoint_cursor") {
        let store = open(&place);
        let busy: Vec<ChunkPos> = (0..4).map(|i| ChunkPos::new(-10 + i, 0, 0)).collect();
        let late = ChunkPos::new(20, 0, 0);
        let mut seq = Seq::default();
        let mut every = busy.clone();
        every.push(late);
        let whole: Vec<_> = every.iter().map(|&p| vec![(p, terrain_chunk(1))]).collect();
        store.commit_batch(&seq.delta_batch(&whole)).unwrap();
        let change = |seq: &mut Seq, chunks: &[ChunkPos], salt: u32| {
            let edits: Vec<_> = chunks
                .iter()
                .map(|&p| vec![(p, terrain_chunk(salt))])
                .collect();
            store.commit_batch(&seq.delta_batch(&edits)).unwrap();
        };
        change(&mut seq, &[late], 2);
        let pace = CheckpointPace {
            every: std::time::Duration::from_secs(60),
            max_chunks: busy.len(),
            slice_chunks: busy.len(),
            log_retention: std::time::Duration::from_secs(3600),
        };
        let mut after = None;
        let mut passes = 0;
        loop {
            // The busy chunks change again before each pass.
            change(&mut seq, &busy, 3 + passes);
            let has_late = store
                .chunks_with_deltas(None, usize::MAX)
                .unwrap()
                .contains(&late);
            if !has_late {
                break;
            }
            after = pass_once(&*store, pace, after).unwrap().next;
            passes += 1;
            assert!(
                passes <= 2,
                "the late chunk still waits after {passes} passes"
            );
        }
        assert_reads(&*store, late, seq.versions[&late], &seq.states[&late]);
    }
}

#[test]
fn a_delta_across_several_changes_replays_folds_and_chains_on() {
    for place in places("delta_spans") {
        delta_spans_on(&place);
    }
}

fn delta_spans_on(place: &Place) {
    let mut seq = Seq::default();
    {
        let store = open(place);
        store
            .commit_batch(&seq.span_batch(&[vec![(A, terrain_chunk(1)), (B, terrain_chunk(2))]]))
            .unwrap();
        // A changed three times and B once: one delta each, A's from
        // version 1 to 4.
        let next = seq.span_batch(&[
            vec![(A, terrain_chunk(3))],
            vec![(A, terrain_chunk(4)), (B, terrain_chunk(5))],
            vec![(A, terrain_chunk(6))],
        ]);
        let spans: Vec<_> = next
            .deltas
            .iter()
            .map(|d| (d.pos, d.from_version, d.to_version))
            .collect();
        assert_eq!(spans, [(B, 1, 2), (A, 1, 4)]);
        store.commit_batch(&next).unwrap();
        // The next tick's delta starts where the span ended.
        store
            .commit_batch(
                &seq.span_batch(&[vec![(A, terrain_chunk(7))], vec![(A, terrain_chunk(8))]]),
            )
            .unwrap();
        assert_eq!(store.delta_count().unwrap(), 3);
        assert_reads(&*store, A, 6, &terrain_chunk(8));
        assert_reads(&*store, B, 2, &terrain_chunk(5));
        assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
    }
    let store = place.open();
    assert_reads(&*store, A, 6, &terrain_chunk(8));
    store.checkpoint(usize::MAX).unwrap();
    assert_eq!(store.delta_count().unwrap(), 0);
    assert_reads(&*store, A, 6, &terrain_chunk(8));
    assert_reads(&*store, B, 2, &terrain_chunk(5));
    assert!(store.check().unwrap().is_ok());
}

#[test]
fn a_delta_that_does_not_continue_the_stored_chain_is_refused() {
    for place in places("delta_chain_refused") {
        delta_chain_refused_on(&*open(&place));
    }
}

fn delta_chain_refused_on(store: &dyn ChunkStore) {
    let mut seq = Seq::default();
    store
        .commit_batch(&seq.delta_batch(&[vec![(A, terrain_chunk(1))]]))
        .unwrap();
    // Built from a version the store does not hold (as if one was lost).
    let mut ahead = Seq {
        last_seq: 1,
        versions: [(A, 2)].into(),
        states: [(A, terrain_chunk(9))].into(),
    };
    let gap = ahead.delta_batch(&[vec![(A, terrain_chunk(2))]]);
    let err = store.commit_batch(&gap).unwrap_err().to_string();
    assert!(err.contains("not stored at version 2"), "{err}");
    // A delta for a chunk the store never held.
    let mut stranger = Seq {
        last_seq: 1,
        versions: [(B, 1)].into(),
        states: [(B, terrain_chunk(9))].into(),
    };
    let err = store
        .commit_batch(&stranger.delta_batch(&[vec![(B, terrain_chunk(2))]]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("not stored at version 1"), "{err}");
    assert_eq!(store.last_seq().unwrap(), 1);
    assert_eq!(store.delta_count().unwrap(), 0);
    assert_reads(store, A, 1, &terrain_chunk(1));
    assert!(store.check().unwrap().is_ok());

    // Behind the newest version: the chain goes on to 3 in deltas not
    // folded yet, and a delta from 1 (the record's version) or a whole
    // write at 2 would fork it, every later read failing. Refused, nothing
    // written.
    for salt in 2..=3 {
        store
            .commit_batch(&seq.delta_batch(&[vec![(A, terrain_chunk(salt))]]))
            .unwrap();
    }
    let stale = |from: u64| Seq {
        last_seq: seq.last_seq,
        versions: [(A, from)].into(),
        states: [(A, terrain_chunk(from as u32))].into(),
    };
    // One delta across three changes, 1 to 4: no stored delta ends at 4.
    let behind = stale(1).span_batch(&[
        vec![(A, terrain_chunk(8))],
        vec![(A, terrain_chunk(9))],
        vec![(A, terrain_chunk(10))],
    ]);
    assert_eq!(behind.deltas.len(), 1);
    assert!(store.commit_batch(&behind).is_err());
    let whole = stale(1).batch(&[vec![(A, terrain_chunk(8))]]);
    assert!(store.commit_batch(&whole).is_err());
    assert_eq!(store.last_seq().unwrap(), seq.last_seq);
    assert_eq!(store.delta_count().unwrap(), 2);
    assert_reads(store, A, 3, &terrain_chunk(3));
    assert!(store.check().unwrap().is_ok());
}

#[test]
fn checkpoints_beside_commits_change_no_read() {
    for place in places("checkpoints_beside_commits") {
        checkpoints_beside_commits_on(&place);
    }
}

fn checkpoints_beside_commits_on(place: &Place) {
    let store: Arc<dyn ChunkStore> = Arc::from(open(place));
    let chunks: Vec<ChunkPos> = (0..6).map(|i| ChunkPos::new(i, 0, i % 2)).collect();
    let mut seq = Seq::default();
    let done = Arc::new(AtomicBool::new(false));
    let folder = {
        let (store, done) = (store.clone(), done.clone());
        std::thread::spawn(move || {
            let mut folded = 0;
            while !done.load(Ordering::Relaxed) {
                folded += store.checkpoint(2).unwrap().chunks;
            }
            folded
        })
    };
    for round in 0..60u32 {
        let edits: Vec<_> = chunks
            .iter()
            .enumerate()
            .filter(|(i, _)| (*i as u32 + round) % 3 != 0)
            .map(|(i, &p)| vec![(p, terrain_chunk(round * 10 + i as u32))])
            .collect();
        store.commit_batch(&seq.delta_batch(&edits)).unwrap();
        for (p, v) in &seq.versions {
            let loaded = store.load_chunk(*p).unwrap().unwrap();
            assert_eq!((loaded.version, &loaded.chunk), (*v, &seq.states[p]));
        }
    }
    done.store(true, Ordering::Relaxed);
    assert!(
        folder.join().unwrap() > 0,
        "the checkpoint ran during the commits"
    );
    assert!(store.check().unwrap().is_ok(), "{:?}", store.check());
    while store.checkpoint(usize::MAX).unwrap().chunks > 0 {}
    assert_eq!(store.delta_count().unwrap(), 0);
    for (p, v) in &seq.versions {
        assert_reads(&*store, *p, *v, &seq.states[p]);
    }
}
