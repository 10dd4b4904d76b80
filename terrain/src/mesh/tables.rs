//! Access to Eric Lengyel's Transvoxel tables (crate `transvoxel-data`), and their conventions.
//!
//! Regular cells: corner `i` sits at `(i & 1, (i >> 1) & 1, (i >> 2) & 1)` in (x, y, z), and
//! case bit `i` is set when corner `i` is solid. (This differs from seed 001's 0..7 ring
//! numbering; only Lengyel's numbering is used here.) Each vertex entry's low byte holds the two
//! corner indices of its edge as nibbles, lower corner first; with set bits meaning "solid", the
//! listed triangles are counter-clockwise seen from air.
//!
//! Transition cells: samples 0..=8 form a 3x3 grid on the full-resolution face, sample `k` at
//! half-cell steps `(k % 3, k / 3)` along the face axes (u, v); samples 9, A, B, C are copies of
//! 0, 2, 6, 8 on the low-resolution side, one transition width inward (w). The 9-bit case
//! walks the face perimeter then the centre (see [`TRANSITION_CASE_SAMPLES`]). Triangles are
//! counter-clockwise from air in a right-handed (u, v, w) frame unless the class's high bit is
//! set, which reverses them.

pub(crate) use transvoxel_data::regular_cell_data::{
    REGULAR_CELL_CLASS, REGULAR_CELL_DATA, REGULAR_VERTEX_DATA,
};
pub(crate) use transvoxel_data::transition_cell_data::{
    TRANSITION_CELL_CLASS, TRANSITION_CELL_DATA, TRANSITION_VERTEX_DATA,
};

/// Sample index of each transition case bit, bit 0 first.
pub(crate) const TRANSITION_CASE_SAMPLES: [usize; 9] = [0, 1, 2, 5, 8, 7, 6, 3, 4];

/// Class flag that reverses a transition cell's winding.
pub(crate) const TRANSITION_REVERSE_FLAG: u8 = 0x80;

/// Full-resolution sample standing in for each transition sample 0..=12 (9..=12 copy corners).
pub(crate) const TRANSITION_SAMPLE_SOURCE: [usize; 13] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 0, 2, 6, 8];

/// The two endpoints (lower-numbered nibble first) encoded in a vertex entry's low byte.
#[inline]
pub(crate) const fn edge_endpoints(entry: u16) -> (usize, usize) {
    (((entry >> 4) & 0xF) as usize, (entry & 0xF) as usize)
}
