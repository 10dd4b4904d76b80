//! Surface heights of recently generated chunk columns. Every chunk of a
//! column, from the bedrock floor to the sky, needs the same 32 × 32
//! heights, and computing them is about a third of a surface chunk's
//! generation; a column's chunks are usually asked for close together
//! (a view, a mesh neighbourhood, a cold start).

use std::sync::{Arc, Mutex};

use crate::pos::CHUNK_SIZE;

/// Columns remembered: a direct-mapped table, so a lookup is one slot and
/// the memory is bounded (about 8 KB a column).
pub const HEIGHT_COLUMNS: usize = 256;

const SIZE: usize = CHUNK_SIZE as usize;

/// One column's heights, x fastest.
pub type Heights = [f64; SIZE * SIZE];

type Slot = Option<((i32, i32), Arc<Heights>)>;

#[derive(Debug)]
pub(crate) struct ColumnHeights {
    slots: Mutex<Vec<Slot>>,
}

impl Default for ColumnHeights {
    fn default() -> Self {
        Self {
            slots: Mutex::new(vec![None; HEIGHT_COLUMNS]),
        }
    }
}

impl ColumnHeights {
    /// The heights of chunk column `(cx, cz)`, computed by `compute` (outside
    /// the lock) unless remembered. The values are `compute`'s, bit for bit.
    pub(crate) fn get(&self, cx: i32, cz: i32, compute: impl FnOnce() -> Heights) -> Arc<Heights> {
        let slot = slot_of(cx, cz);
        if let Some(h) = self.lock()[slot]
            .as_ref()
            .filter(|(at, _)| *at == (cx, cz))
            .map(|(_, h)| h.clone())
        {
            return h;
        }
        let heights = Arc::new(compute());
        self.lock()[slot] = Some(((cx, cz), heights.clone()));
        heights
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Slot>> {
        // A panic elsewhere while holding the lock left whole slots behind:
        // every slot is a complete entry or empty.
        self.slots.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Columns tile the table 16 × 16: the columns of any 16 × 16 block of
/// the world land in different slots.
fn slot_of(cx: i32, cz: i32) -> usize {
    (cx.rem_euclid(TILE) * TILE + cz.rem_euclid(TILE)) as usize
}

/// Side of the block of columns the table holds at once.
const TILE: i32 = 16;
const _: () = assert!((TILE * TILE) as usize == HEIGHT_COLUMNS);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remembers_a_column_until_another_takes_its_slot() {
        let c = ColumnHeights::default();
        let ramp = |v: f64| [v; SIZE * SIZE];
        assert_eq!(c.get(3, -4, || ramp(1.0))[0], 1.0);
        // Remembered: the second computation is not run.
        assert_eq!(c.get(3, -4, || ramp(2.0))[0], 1.0);
        // A column sharing the slot replaces it.
        let (mut x, mut z) = (3, -4);
        while (x, z) == (3, -4) || slot_of(x, z) != slot_of(3, -4) {
            x += 1;
            z -= 3;
        }
        assert_eq!(c.get(x, z, || ramp(3.0))[0], 3.0);
        assert_eq!(c.get(3, -4, || ramp(4.0))[0], 4.0);
    }

    #[test]
    fn a_block_of_columns_uses_every_slot_once() {
        for (x0, z0) in [(0, 0), (-9, 5), (i32::MIN, i32::MAX - 16)] {
            let mut seen = std::collections::HashSet::new();
            for x in x0..x0 + TILE {
                for z in z0..z0 + TILE {
                    assert!(seen.insert(slot_of(x, z)), "({x}, {z})");
                }
            }
            assert_eq!(seen.len(), HEIGHT_COLUMNS);
        }
    }
}
