//! Loading stored chunks into the sequencer before anything reads them,
//! and dropping them again when memory holds too many.

use std::time::{Duration, Instant};

use strata_terrain::ChunkPos;

use super::Engine;
use crate::metrics as m;
use crate::store::StoreError;

/// Chunks held in memory (loaded plus known-absent) before cold ones are dropped.
pub const DEFAULT_RESIDENT_CHUNKS: usize = 8192;
/// Smallest allowed `engine.resident_chunks`.
pub const MIN_RESIDENT_CHUNKS: usize = 27;
/// Chunks within this many chunks of a player are never dropped.
pub const HOT_RADIUS: u8 = 2;
/// Least time between two eviction passes.
pub const EVICT_INTERVAL: Duration = Duration::from_secs(1);

impl Engine {
    /// Makes every listed chunk resident: stored ones are loaded, all in
    /// one read (one round trip to a database), the rest are marked as
    /// generated (version 0).
    pub(super) fn make_resident(&mut self, positions: &[ChunkPos]) -> Result<(), StoreError> {
        let mut stored = Vec::new();
        for &pos in positions {
            if self.seq.is_resident(pos) {
                continue;
            }
            if self.versions.contains_key(&pos) {
                stored.push(pos);
            } else {
                self.seq.mark_absent(pos);
            }
        }
        if stored.is_empty() {
            return Ok(());
        }
        stored.sort_unstable();
        stored.dedup();
        let loaded = self.store.load_chunks(&stored);
        self.store_answered(&loaded);
        for (pos, loaded) in stored.iter().zip(loaded?) {
            match loaded {
                Some(s) => self.seq.insert_stored_chunk(*pos, s.chunk, s.version),
                None => self.seq.mark_absent(*pos),
            }
        }
        Ok(())
    }
}

impl Engine {
    /// Drops chunks far from every player once more than
    /// `engine.resident_chunks` are held. Modified chunks are durable in the
    /// store by now (this runs after the tick's commit) and load again when
    /// needed. What queued edits read is kept.
    pub(super) fn evict_cold(&mut self) {
        let resident = self.seq.resident();
        metrics::gauge!(m::RESIDENT_CHUNKS).set(resident as f64);
        if resident <= self.cfg.resident_chunks
            || self
                .last_evict
                .is_some_and(|t| t.elapsed() < EVICT_INTERVAL)
        {
            return;
        }
        let dropped = self.seq.evict_far_from_players(HOT_RADIUS);
        let n = dropped.len();
        // Freeing thousands of chunks is the worker's time, not the tick's.
        if n > 0 {
            self.pool.spawn(move || drop(dropped));
        }
        self.last_evict = Some(Instant::now());
        tracing::debug!(
            dropped = n,
            kept = self.seq.resident(),
            "evicted cold chunks"
        );
        metrics::gauge!(m::RESIDENT_CHUNKS).set(self.seq.resident() as f64);
    }
}
