//! Checks a commit batch against itself before anything is written.
//!
//! The store refuses a batch that would break the invariants `check`
//! verifies, so a sequencer bug surfaces as a typed error at the commit
//! that caused it instead of as a corrupt world found days later.

use std::collections::BTreeMap;

use strata_terrain::ChunkPos;

use super::error::StoreError;
use super::keys::show_pos;
use super::types::CommitBatch;

/// Most entries one batch may hold (a sequencer tick is far smaller).
pub const MAX_BATCH_ENTRIES: usize = 65_536;
/// Most chunks one batch may write.
pub const MAX_BATCH_CHUNKS: usize = 65_536;

/// Validates the batch on its own and returns, per changed chunk, the
/// lowest version the batch moves it to (the store must hold an older one).
pub fn validate(b: &CommitBatch) -> Result<BTreeMap<ChunkPos, u64>, StoreError> {
    if b.entries.len() > MAX_BATCH_ENTRIES {
        return Err(StoreError::batch(format!(
            "{} entries, limit {MAX_BATCH_ENTRIES}",
            b.entries.len()
        )));
    }
    if b.deltas.len() > MAX_BATCH_ENTRIES {
        return Err(StoreError::batch(format!(
            "{} deltas, limit {MAX_BATCH_ENTRIES}",
            b.deltas.len()
        )));
    }
    if b.chunks.len() > MAX_BATCH_CHUNKS {
        return Err(StoreError::batch(format!(
            "{} chunks, limit {MAX_BATCH_CHUNKS}",
            b.chunks.len()
        )));
    }
    let Some(first) = b.entries.first() else {
        if !b.chunks.is_empty() || !b.deltas.is_empty() || !b.generated.is_empty() {
            return Err(StoreError::batch("chunks without any log entry"));
        }
        return Ok(BTreeMap::new());
    };
    // (lowest, highest) to_version per chunk across the batch.
    let mut span: BTreeMap<ChunkPos, (u64, u64)> = BTreeMap::new();
    for (i, e) in b.entries.iter().enumerate() {
        let want = first.seq.checked_add(i as u64);
        if want != Some(e.seq) {
            return Err(StoreError::batch(format!(
                "entry {i} has seq {}, expected consecutive seqs from {}",
                e.seq, first.seq
            )));
        }
        for &(pos, v) in &e.changes {
            if v == 0 {
                return Err(StoreError::batch(format!(
                    "seq {} moves {} to version 0",
                    e.seq,
                    show_pos(pos)
                )));
            }
            match span.get_mut(&pos) {
                Some((_, hi)) if v <= *hi => {
                    return Err(StoreError::batch(format!(
                        "seq {} moves {} to version {v}, not above {hi}",
                        e.seq,
                        show_pos(pos)
                    )))
                }
                Some((_, hi)) => *hi = v,
                None => {
                    span.insert(pos, (v, v));
                }
            }
        }
    }
    let last = b.entries.last().map_or(0, |e| e.seq);
    if b.last_seq != last {
        return Err(StoreError::batch(format!(
            "last_seq {} but the last entry is seq {last}",
            b.last_seq
        )));
    }
    let mut seen = BTreeMap::new();
    for (pos, v, _) in &b.chunks {
        if seen.insert(*pos, *v).is_some() {
            return Err(StoreError::batch(format!(
                "{} written twice",
                show_pos(*pos)
            )));
        }
        match span.get(pos) {
            None => {
                return Err(StoreError::batch(format!(
                    "{} is written but no entry changed it",
                    show_pos(*pos)
                )))
            }
            Some(&(_, hi)) if hi != *v => {
                return Err(StoreError::batch(format!(
                    "{} written at version {v}, but the entries end it at {hi}",
                    show_pos(*pos)
                )))
            }
            Some(_) => {}
        }
    }
    // A whole state's other form: its change from the generated state.
    let mut generated = BTreeMap::new();
    for d in &b.generated {
        if seen.get(&d.pos) != Some(&d.to_version) || d.from_version != 0 {
            return Err(StoreError::batch(format!(
                "a delta from generated {} to version {} (from {}), which is not written whole there",
                show_pos(d.pos),
                d.to_version,
                d.from_version
            )));
        }
        if span.get(&d.pos).is_none_or(|&(lo, _)| lo != 1) {
            return Err(StoreError::batch(format!(
                "{} is stored from generated, but the entries do not start it at version 1",
                show_pos(d.pos)
            )));
        }
        if generated.insert(d.pos, ()).is_some() {
            return Err(StoreError::batch(format!(
                "{} has two deltas from generated",
                show_pos(d.pos)
            )));
        }
    }
    // Every other changed chunk: its deltas, in order, each from where the
    // last one ended (one per change, or one across several), from the
    // version before the batch's first change of it to its last.
    let mut next: BTreeMap<ChunkPos, u64> = BTreeMap::new();
    for d in &b.deltas {
        let Some(&(lo, hi)) = span.get(&d.pos) else {
            return Err(StoreError::batch(format!(
                "a delta for {}, which no entry changed",
                show_pos(d.pos)
            )));
        };
        if seen.contains_key(&d.pos) {
            return Err(StoreError::batch(format!(
                "{} is written whole and as a delta",
                show_pos(d.pos)
            )));
        }
        let from = *next.get(&d.pos).unwrap_or(&(lo - 1));
        if d.from_version != from || d.to_version <= from || d.to_version > hi {
            return Err(StoreError::batch(format!(
                "delta for {} from version {} to {}, expected from {from} to at most {hi}",
                show_pos(d.pos),
                d.from_version,
                d.to_version
            )));
        }
        next.insert(d.pos, d.to_version);
    }
    for (pos, &(_, hi)) in &span {
        let complete = seen.contains_key(pos) || next.get(pos) == Some(&hi);
        if !complete {
            return Err(StoreError::batch(format!(
                "{} changed by an entry but its state is missing",
                show_pos(*pos)
            )));
        }
    }
    Ok(span.into_iter().map(|(p, (lo, _))| (p, lo)).collect())
}
