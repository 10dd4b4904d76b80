//! A set of chunk positions kept as bits of 4×4×4-chunk cells: the chunks
//! an eviction pass keeps. Adding a box costs a map update per cell it
//! touches (eight at most for a player's 5×5×5), not one per chunk, so
//! thousands of players make a set in well under a millisecond.

use rustc_hash::FxHashMap;

use strata_terrain::ChunkPos;

/// Chunks per cell along each axis (a cell is 64 chunks, one `u64`).
const CELL: i64 = 4;

/// A set of chunks, built from boxes and looked up one chunk at a time.
#[derive(Debug, Default)]
pub struct ChunkBits {
    cells: FxHashMap<(i32, i32, i32), u64>,
}

impl ChunkBits {
    /// Adds every chunk `radius` chunks or less from `c` along each axis
    /// (a cube), as far as chunk coordinates go.
    pub fn insert_cube(&mut self, c: ChunkPos, radius: u8) {
        let r = i32::from(radius);
        let lo = ChunkPos::new(
            c.x.saturating_sub(r),
            c.y.saturating_sub(r),
            c.z.saturating_sub(r),
        );
        let hi = ChunkPos::new(
            c.x.saturating_add(r),
            c.y.saturating_add(r),
            c.z.saturating_add(r),
        );
        self.insert_box(lo, hi);
    }

    /// Adds every chunk of the box from `lo` to `hi`, both included.
    pub fn insert_box(&mut self, lo: ChunkPos, hi: ChunkPos) {
        let axes = [(lo.x, hi.x), (lo.y, hi.y), (lo.z, hi.z)];
        if axes.iter().any(|(a, b)| a > b) {
            return;
        }
        let cells = |(a, b): (i32, i32)| cell_of(a)..=cell_of(b);
        for cz in cells(axes[2]) {
            let mz = axis_bits(axes[2], cz);
            for cy in cells(axes[1]) {
                let my = axis_bits(axes[1], cy);
                for cx in cells(axes[0]) {
                    let mx = axis_bits(axes[0], cx);
                    *self.cells.entry((cx, cy, cz)).or_default() |= cube_bits(mx, my, mz);
                }
            }
        }
    }

    pub fn contains(&self, p: ChunkPos) -> bool {
        self.cells
            .get(&(cell_of(p.x), cell_of(p.y), cell_of(p.z)))
            .is_some_and(|bits| bits >> bit_of(p) & 1 == 1)
    }
}

/// The cell holding chunk coordinate `v` (rounding down).
fn cell_of(v: i32) -> i32 {
    v.div_euclid(CELL as i32)
}

fn bit_of(p: ChunkPos) -> u32 {
    let local = |v: i32| v.rem_euclid(CELL as i32) as u32;
    local(p.x) | local(p.y) << 2 | local(p.z) << 4
}

/// The local coordinates (as 4 bits) of cell `cell` that `lo..=hi` covers.
fn axis_bits((lo, hi): (i32, i32), cell: i32) -> u8 {
    let base = i64::from(cell) * CELL;
    let a = (i64::from(lo) - base).max(0);
    let b = (i64::from(hi) - base).min(CELL - 1);
    ((1u8 << (b + 1)) - 1) & !((1u8 << a) - 1)
}

/// The bits of the cell's chunks whose local x, y and z are in `mx`, `my`
/// and `mz`.
fn cube_bits(mx: u8, my: u8, mz: u8) -> u64 {
    let mut bits = 0u64;
    for z in 0..CELL as u32 {
        for y in 0..CELL as u32 {
            if mz >> z & 1 == 1 && my >> y & 1 == 1 {
                bits |= u64::from(mx) << (z * 16 + y * 4);
            }
        }
    }
    bits
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::collections::HashSet;

    fn cube(c: ChunkPos, r: i32) -> HashSet<ChunkPos> {
        let mut s = HashSet::new();
        for dz in -r..=r {
            for dy in -r..=r {
                for dx in -r..=r {
                    if let Some(p) = c.offset(dx, dy, dz) {
                        s.insert(p);
                    }
                }
            }
        }
        s
    }

    #[test]
    fn holds_exactly_the_cubes_added() {
        let centres = [
            ChunkPos::new(0, 0, 0),
            ChunkPos::new(-1, 5, -9),
            ChunkPos::new(7, -3, 2),
            ChunkPos::new(-6, -6, -6),
            ChunkPos::new(3, 3, 3),
        ];
        for radius in 0..=3u8 {
            let mut bits = ChunkBits::default();
            let mut want = HashSet::new();
            for &c in &centres {
                bits.insert_cube(c, radius);
                want.extend(cube(c, i32::from(radius)));
            }
            for x in -14..=14 {
                for y in -14..=14 {
                    for z in -14..=14 {
                        let p = ChunkPos::new(x, y, z);
                        assert_eq!(bits.contains(p), want.contains(&p), "{p:?} r {radius}");
                    }
                }
            }
        }
    }

    #[test]
    fn boxes_at_the_ends_of_the_coordinates_stop_there() {
        let mut bits = ChunkBits::default();
        let (min, max) = (i32::MIN, i32::MAX);
        bits.insert_cube(ChunkPos::new(max, min, max - 1), 2);
        assert!(bits.contains(ChunkPos::new(max, min, max)));
        assert!(bits.contains(ChunkPos::new(max - 2, min + 2, max - 3)));
        assert!(!bits.contains(ChunkPos::new(max - 3, min, max)));
        assert!(!bits.contains(ChunkPos::new(max, min + 3, max)));
        assert!(!bits.contains(ChunkPos::new(max, min, max - 4)));
    }

    #[test]
    fn an_empty_box_adds_nothing() {
        let mut bits = ChunkBits::default();
        bits.insert_box(ChunkPos::new(1, 0, 0), ChunkPos::new(0, 0, 0));
        assert!(bits.cells.is_empty());
    }

    #[test]
    fn a_long_box_touches_each_cell_once() {
        let mut bits = ChunkBits::default();
        bits.insert_box(ChunkPos::new(-10, 2, 2), ChunkPos::new(21, 2, 2));
        assert_eq!(bits.cells.len(), 9, "cells -3 to 5 along x");
        assert!((-10..=21).all(|x| bits.contains(ChunkPos::new(x, 2, 2))));
        assert!(!bits.contains(ChunkPos::new(-11, 2, 2)));
        assert!(!bits.contains(ChunkPos::new(22, 2, 2)));
        assert!(!bits.contains(ChunkPos::new(0, 3, 2)));
    }
}
