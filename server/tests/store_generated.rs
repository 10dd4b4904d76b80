//! A chunk's first changes stored as deltas from its generated state: a
//! store with the world's generator attached writes a "generated" record
//! and the delta; reads rebuild the chunk through the generator, a
//! checkpoint writes it whole, and a store without the generator says
//! what it needs instead of guessing. Every test runs on every backend.

use crate::store_common;

use std::sync::Arc;

use store_common::{assert_reads, places, terrain_chunk, Place, Seq};
use strata_server::store::{ChunkStore, StoreError, WorldMeta};
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{ChunkPos, Voxel};

const A: ChunkPos = ChunkPos { x: 1, y: 0, z: -2 };
/// Below y = 0, where the flat generator's ground is.
const B: ChunkPos = ChunkPos { x: -4, y: -1, z: 3 };

fn flat(ground: u8) -> FlatGenerator {
    FlatGenerator {
        ground: Voxel::solid(ground),
    }
}

fn open(place: &Place, generator: Option<FlatGenerator>) -> Box<dyn ChunkStore> {
    let store = place.open();
    store.init_meta(&WorldMeta::new(5, 1, "")).unwrap();
    if let Some(g) = generator {
        store.attach_generator(Arc::new(g));
    }
    store
}

fn assert_clean(store: &dyn ChunkStore) {
    let report = store.check().unwrap();
    assert!(report.issues.is_empty(), "{:?}", report.issues);
}

#[test]
fn first_changes_are_stored_from_generated_and_a_checkpoint_writes_them_whole() {
    for place in places("generated_first_changes") {
        first_changes_on(&place);
    }
}

fn first_changes_on(place: &Place) {
    let g = flat(ids::STONE);
    let mut seq = Seq::default();
    let (a1, b1, a2) = (terrain_chunk(1), terrain_chunk(2), terrain_chunk(3));
    {
        let store = open(place, Some(g));
        let first = seq.generated_batch(&[vec![(A, a1.clone()), (B, b1.clone())]], &g);
        assert_eq!((first.chunks.len(), first.generated.len()), (2, 2));
        store.commit_batch(&first).unwrap();
        // Two deltas after "generated" records, no whole state.
        assert_eq!(store.delta_count().unwrap(), 2);
        assert_eq!(store.chunk_count().unwrap(), 2);
        assert_reads(&*store, A, 1, &a1);
        assert_reads(&*store, B, 1, &b1);
        assert_clean(&*store);
        // Later changes follow the first delta's chain.
        store
            .commit_batch(&seq.delta_batch(&[vec![(A, a2.clone())]]))
            .unwrap();
        assert_reads(&*store, A, 2, &a2);
        assert_clean(&*store);
    }
    {
        // Reopened without the generator: the store cannot rebuild the
        // base, and says so; nothing is guessed.
        let store = open(place, None);
        for pos in [A, B] {
            match store.load_chunk(pos) {
                Err(StoreError::NeedsGenerator { pos: p }) => assert_eq!(p, pos),
                other => panic!("{}: {pos:?}: {other:?}", place.backend()),
            }
        }
        assert!(matches!(
            store.raw_chunk(B),
            Err(StoreError::NeedsGenerator { .. })
        ));
        assert!(matches!(
            store.raw_chunks().find(|r| r.is_err()),
            Some(Err(StoreError::NeedsGenerator { .. }))
        ));
        // What needs no chunk contents still works.
        let listed: Vec<_> = store.modified_chunks().map(|r| r.unwrap()).collect();
        assert_eq!(listed.len(), 2, "{listed:?}");
        assert_clean(&*store);
    }
    {
        let store = open(place, Some(g));
        assert_reads(&*store, A, 2, &a2);
        assert_reads(&*store, B, 1, &b1);
        let folded = store.checkpoint(usize::MAX).unwrap();
        assert_eq!(folded.chunks, 2);
        assert_eq!(store.delta_count().unwrap(), 0);
    }
    // Folded: the records are whole, and no generator is needed.
    let store = open(place, None);
    assert_reads(&*store, A, 2, &a2);
    assert_reads(&*store, B, 1, &b1);
    assert_clean(&*store);
}

#[test]
fn a_chunk_stored_already_is_not_stored_again_from_generated() {
    for place in places("generated_twice") {
        let g = flat(ids::STONE);
        let store = open(&place, Some(g));
        let mut seq = Seq::default();
        let a1 = terrain_chunk(1);
        store
            .commit_batch(&seq.generated_batch(&[vec![(A, a1.clone())]], &g))
            .unwrap();
        // A second writer that takes A for new: its batch is refused whole.
        let mut other = Seq {
            last_seq: seq.last_seq,
            ..Seq::default()
        };
        let again = other.generated_batch(&[vec![(A, terrain_chunk(7))]], &g);
        assert!(
            matches!(
                store.commit_batch(&again),
                Err(StoreError::InvalidBatch { .. })
            ),
            "{}",
            place.backend()
        );
        assert_eq!(store.last_seq().unwrap(), seq.last_seq);
        assert_reads(&*store, A, 1, &a1);
        assert_clean(&*store);
    }
}

#[test]
fn a_delta_from_generated_must_match_a_chunk_written_whole() {
    for place in places("generated_mismatch") {
        let g = flat(ids::STONE);
        let store = open(&place, Some(g));
        let mut seq = Seq::default();
        let mut b = seq.generated_batch(&[vec![(A, terrain_chunk(1))]], &g);
        b.generated[0].to_version = 2;
        let err = store.commit_batch(&b).unwrap_err();
        assert!(err.to_string().contains("not written whole"), "{err}");
        let mut b = seq.generated_batch(&[vec![(B, terrain_chunk(2))]], &g);
        b.generated.push(b.generated[0].clone());
        let err = store.commit_batch(&b).unwrap_err();
        assert!(
            err.to_string().contains("two deltas from generated"),
            "{err}"
        );
        assert_eq!(store.last_seq().unwrap(), 0);
        assert_eq!(store.chunk_count().unwrap(), 0);
    }
}

#[test]
fn another_generator_never_yields_a_wrong_chunk() {
    for place in places("generated_other_generator") {
        let g = flat(ids::STONE);
        let mut seq = Seq::default();
        {
            let store = open(&place, Some(g));
            store
                .commit_batch(&seq.generated_batch(&[vec![(B, terrain_chunk(2))]], &g))
                .unwrap();
        }
        // The delta's base hash is the stone ground's: dirt is refused.
        let store = open(&place, Some(flat(ids::DIRT)));
        let err = store.load_chunk(B).unwrap_err();
        assert!(
            matches!(err, StoreError::Corrupt { .. }),
            "{}: {err}",
            place.backend()
        );
    }
}

/// A chunk whose records do not read (here: a generated one, reopened
/// without the generator) is left unfolded, and the checkpoint folds the
/// other chunks all the same: one bad chunk never stops every later pass.
#[test]
fn a_chunk_that_does_not_read_does_not_stop_the_checkpoint() {
    for place in places("generated_checkpoint_skips") {
        let g = flat(ids::STONE);
        let mut seq = Seq::default();
        let (b1, b2) = (terrain_chunk(2), terrain_chunk(3));
        {
            let store = open(&place, Some(g));
            // A from generated; B stored whole first, then changed by a delta.
            store
                .commit_batch(&seq.generated_batch(&[vec![(A, terrain_chunk(1))]], &g))
                .unwrap();
            store
                .commit_batch(&seq.delta_batch(&[vec![(B, b1)]]))
                .unwrap();
            store
                .commit_batch(&seq.delta_batch(&[vec![(B, b2.clone())]]))
                .unwrap();
            assert_eq!(store.delta_count().unwrap(), 2);
        }
        let store = open(&place, None);
        let folded = store.checkpoint(usize::MAX).unwrap();
        assert_eq!(
            (folded.chunks, folded.skipped),
            (1, 1),
            "{}",
            place.backend()
        );
        assert_eq!(store.delta_count().unwrap(), 1, "A's delta stays");
        let loaded = store.load_chunk(B).unwrap().unwrap();
        assert_eq!((loaded.version, loaded.chunk), (2, b2.clone()));
        drop(store);
        // With the generator back, the next pass folds A too.
        let store = open(&place, Some(g));
        let folded = store.checkpoint(usize::MAX).unwrap();
        assert_eq!((folded.chunks, folded.skipped), (1, 0));
        assert_eq!(store.delta_count().unwrap(), 0);
    }
}
