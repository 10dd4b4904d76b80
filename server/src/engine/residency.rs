//! Loading stored chunks into the sequencer before anything reads them.

use strata_terrain::ChunkPos;

use super::Engine;
use crate::store::StoreError;

impl Engine {
    /// Makes every listed chunk resident: stored ones are loaded, the rest
    /// are marked as generated (version 0).
    pub(super) fn make_resident(&mut self, positions: &[ChunkPos]) -> Result<(), StoreError> {
        for &pos in positions {
            if self.seq.is_resident(pos) {
                continue;
            }
            if !self.versions.contains_key(&pos) {
                self.seq.mark_absent(pos);
                continue;
            }
            match self.store.load_chunk(pos)? {
                Some(stored) => self
                    .seq
                    .insert_stored_chunk(pos, stored.chunk, stored.version),
                None => self.seq.mark_absent(pos),
            }
        }
        Ok(())
    }
}
