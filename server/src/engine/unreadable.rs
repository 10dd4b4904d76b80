//! Stored chunks that could not be read (a body that does not decode, a
//! corrupt record): for a while their frames, and their neighbours' (whose
//! meshes read them), are left out of the streaming work, so one bad
//! record costs no store call per tick, nor every session's prebuild.

use std::time::{Duration, Instant};

use rustc_hash::{FxHashMap, FxHashSet};
use strata_terrain::ChunkPos;

use super::Engine;
use crate::sequencer::residency::with_neighbours;
use crate::store::StoreError;

/// Most chunks remembered as unreadable; past it, the one found longest
/// ago is forgotten (and found again when next needed).
pub const MAX_UNREADABLE_CHUNKS: usize = 1024;
/// How long a chunk found unreadable is left alone before it is read
/// again (an operator may have restored it meanwhile).
pub const UNREADABLE_RETRY: Duration = Duration::from_secs(30);

/// Chunks found unreadable, and when.
#[derive(Debug, Default)]
pub struct Unreadable {
    since: FxHashMap<ChunkPos, Instant>,
}

impl Unreadable {
    /// Remembers `pos` as unreadable from `now`; when full, the expired
    /// go, else the one found longest ago.
    pub fn note(&mut self, pos: ChunkPos, now: Instant) {
        if self.since.len() >= MAX_UNREADABLE_CHUNKS && !self.since.contains_key(&pos) {
            self.since.retain(|_, at| !expired(*at, now));
            if self.since.len() >= MAX_UNREADABLE_CHUNKS {
                if let Some(oldest) = self
                    .since
                    .iter()
                    .min_by_key(|(_, at)| **at)
                    .map(|(p, _)| *p)
                {
                    self.since.remove(&oldest);
                }
            }
        }
        self.since.insert(pos, now);
    }

    /// Whether `pos` was found unreadable less than [`UNREADABLE_RETRY`]
    /// before `now`.
    pub fn holds(&self, pos: ChunkPos, now: Instant) -> bool {
        self.since.get(&pos).is_some_and(|at| !expired(*at, now))
    }

    /// Whether any of `positions` [`Self::holds`].
    pub fn holds_any(&self, positions: &[ChunkPos], now: Instant) -> bool {
        !self.since.is_empty() && positions.iter().any(|p| self.holds(*p, now))
    }

    /// Whether `pos` or a neighbour (whose mesh reads it) [`Self::holds`].
    pub fn blocks(&self, pos: ChunkPos, now: Instant) -> bool {
        !self.since.is_empty() && with_neighbours(pos).any(|n| self.holds(n, now))
    }
}

fn expired(at: Instant, now: Instant) -> bool {
    now.saturating_duration_since(at) >= UNREADABLE_RETRY
}

/// Whether `pos` or a neighbour is one of `bad`.
pub fn near_any(pos: ChunkPos, bad: &FxHashSet<ChunkPos>) -> bool {
    !bad.is_empty() && with_neighbours(pos).any(|n| bad.contains(&n))
}

impl Engine {
    /// Makes `positions` resident, but those a bad record keeps out (found
    /// by halves, counted and remembered from `now`), which it returns:
    /// callers leave out what reads them ([`near_any`]; the memory alone
    /// may have had to forget some). Fails only on an error of the store
    /// itself.
    pub(super) fn make_resident_readable(
        &mut self,
        positions: &[ChunkPos],
        now: Instant,
    ) -> Result<FxHashSet<ChunkPos>, StoreError> {
        let e = match self.make_resident(positions) {
            Ok(()) => return Ok(FxHashSet::default()),
            Err(e) if !e.is_bad_record() => return Err(e),
            Err(e) => e,
        };
        crate::log_every::store_error("read", "a stored chunk does not read", &e);
        let mut bad = Vec::new();
        self.find_unreadable(positions, &mut bad)?;
        for &p in &bad {
            self.unreadable.note(p, now);
        }
        Ok(bad.into_iter().collect())
    }

    /// Loads `positions`, halving each part that fails on a bad record
    /// down to the chunks themselves, which go to `bad`.
    fn find_unreadable(
        &mut self,
        positions: &[ChunkPos],
        bad: &mut Vec<ChunkPos>,
    ) -> Result<(), StoreError> {
        match self.make_resident(positions) {
            Ok(()) => Ok(()),
            Err(e) if !e.is_bad_record() => Err(e),
            Err(_) if positions.len() == 1 => {
                bad.push(positions[0]);
                Ok(())
            }
            Err(_) => {
                let (a, b) = positions.split_at(positions.len() / 2);
                self.find_unreadable(a, bad)?;
                self.find_unreadable(b, bad)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_a_chunk_and_its_neighbours_for_a_while_within_a_bound() {
        let t = Instant::now();
        let mut u = Unreadable::default();
        let bad = ChunkPos::new(4, -2, 7);
        assert!(!u.blocks(bad, t));
        u.note(bad, t);
        assert!(u.blocks(bad, t));
        assert!(u.blocks(ChunkPos::new(5, -1, 6), t), "a neighbour");
        assert!(!u.blocks(ChunkPos::new(6, -2, 7), t), "two away");
        assert!(!u.blocks(bad, t + UNREADABLE_RETRY), "read again later");
        // Full: a new one takes the place of the one found longest ago.
        let later = t + std::time::Duration::from_millis(1);
        for i in 1..MAX_UNREADABLE_CHUNKS as i32 {
            u.note(ChunkPos::new(100 * i, 0, 0), later);
        }
        let late = ChunkPos::new(-50, 0, 0);
        u.note(late, later);
        assert!(u.holds(late, later));
        assert!(!u.holds(bad, later), "the oldest made room");
        assert!(u.holds_any(&[bad, ChunkPos::new(100, 0, 0)], later));
        let tick: FxHashSet<ChunkPos> = [bad].into_iter().collect();
        assert!(near_any(ChunkPos::new(3, -3, 8), &tick));
        assert!(!near_any(ChunkPos::new(2, -3, 8), &tick));
    }
}
