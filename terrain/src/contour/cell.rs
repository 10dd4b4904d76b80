//! The Marching Squares case table and per-cell segment emission.
//!
//! Corners (seed 004's naming): `a = (x, y)`, `b = (x + 1, y)`,
//! `c = (x, y + 1)`, `d = (x + 1, y + 1)`; case bits a=1, b=2, c=4, d=8.
//! Edges are numbered counter-clockwise: 0 bottom (a-b), 1 right (b-d),
//! 2 top (c-d), 3 left (a-c).
//!
//! The table is derived, not hand-typed: walking the cell border
//! counter-clockwise, an edge where the walk leaves the inside is an *exit*
//! and one where it enters is an *entry*. A segment runs from an exit to an
//! entry, which puts the inside on its left. A cell with one exit pairs it
//! with its one entry; a saddle (two of each) pairs each exit with the entry
//! just before it (inside corners separated) or just after it (connected).

use super::{EdgeAxis, EdgeKey, Segment};

/// Cell corners in counter-clockwise order, as case bits (a, b, d, c).
const CCW_CORNER_BITS: [u8; 4] = [1, 2, 8, 4];

/// Up to two segments per case, as (from edge, to edge).
#[derive(Debug, Clone, Copy)]
pub(crate) struct CaseSegments {
    pub count: u8,
    pub edges: [[u8; 2]; 2],
}

const fn build_table(connect_saddles: bool) -> [CaseSegments; 16] {
    let mut table = [CaseSegments {
        count: 0,
        edges: [[0; 2]; 2],
    }; 16];
    let mut case = 0;
    while case < 16 {
        let mut exits = [0u8; 2];
        let mut entries = [0u8; 2];
        let (mut ne, mut nn) = (0, 0);
        let mut k = 0;
        while k < 4 {
            // Edge k joins CCW corner k to corner k + 1.
            let here = (case as u8) & CCW_CORNER_BITS[k] != 0;
            let next = (case as u8) & CCW_CORNER_BITS[(k + 1) % 4] != 0;
            if here && !next {
                exits[ne] = k as u8;
                ne += 1;
            } else if !here && next {
                entries[nn] = k as u8;
                nn += 1;
            }
            k += 1;
        }
        let mut out = CaseSegments {
            count: ne as u8,
            edges: [[0; 2]; 2],
        };
        if ne == 1 {
            out.edges[0] = [exits[0], entries[0]];
        } else if ne == 2 {
            let mut i = 0;
            while i < 2 {
                let e = exits[i];
                // The neighbouring edges of exit e in CCW order.
                let wanted = if connect_saddles {
                    (e + 1) % 4
                } else {
                    (e + 3) % 4
                };
                out.edges[i] = [e, wanted];
                i += 1;
            }
        }
        table[case] = out;
        case += 1;
    }
    table
}

/// Case table when a saddle's centre is outside: inside corners separated.
pub(crate) const SEPARATED: [CaseSegments; 16] = build_table(false);
/// Case table when a saddle's centre is inside: inside corners connected.
pub(crate) const CONNECTED: [CaseSegments; 16] = build_table(true);

/// Global key of edge `e` of the cell whose lower corner is `(x, y)`.
/// The caller guarantees `x + 1` and `y + 1` do not overflow (cells only
/// exist strictly inside a region).
#[inline]
fn edge_key(x: i32, y: i32, e: u8) -> EdgeKey {
    match e {
        0 => EdgeKey {
            x,
            y,
            axis: EdgeAxis::X,
        },
        1 => EdgeKey {
            x: x + 1,
            y,
            axis: EdgeAxis::Y,
        },
        2 => EdgeKey {
            x,
            y: y + 1,
            axis: EdgeAxis::X,
        },
        _ => EdgeKey {
            x,
            y,
            axis: EdgeAxis::Y,
        },
    }
}

/// Where the contour crosses the edge from `lo` (at `p`) to `hi` (at `p + 1`
/// along the edge axis), as the offset in `[0, 1]` from the lower sample.
#[inline]
fn crossing(lo: f32, hi: f32, iso: f32) -> f32 {
    // The edge crosses, so lo != hi and the quotient is finite for finite
    // inputs; clamping guards against rounding just outside [0, 1].
    let t = (iso - lo) / (hi - lo);
    t.clamp(0.0, 1.0)
}

/// The case of a cell with corner values `v` (a, b, c, d).
#[cfg(test)]
fn case_of(v: [f32; 4], iso: f32) -> u8 {
    u8::from(v[0] > iso)
        | u8::from(v[1] > iso) << 1
        | u8::from(v[2] > iso) << 2
        | u8::from(v[3] > iso) << 3
}

/// Appends the segments of one cell. `v` holds the corner values a, b, c, d
/// and `case` their inside bits (as computed by the caller's row sweep).
#[inline]
pub(crate) fn emit_cell(x: i32, y: i32, case: u8, v: [f32; 4], iso: f32, out: &mut Vec<Segment>) {
    let case = usize::from(case & 15);
    let table = if case == 6 || case == 9 {
        // Saddle: decide by the cell-centre average (a tie counts as outside,
        // like a sample equal to iso).
        let centre = (v[0] + v[1] + v[2] + v[3]) * 0.25;
        if centre > iso {
            &CONNECTED
        } else {
            &SEPARATED
        }
    } else {
        &SEPARATED
    };
    let (fx, fy) = (x as f32, y as f32);
    let point = |e: u8| -> [f32; 2] {
        match e {
            0 => [fx + crossing(v[0], v[1], iso), fy],
            1 => [fx + 1.0, fy + crossing(v[1], v[3], iso)],
            2 => [fx + crossing(v[2], v[3], iso), fy + 1.0],
            _ => [fx, fy + crossing(v[0], v[2], iso)],
        }
    };
    let segs = table[case];
    for &[f, t] in &segs.edges[..usize::from(segs.count)] {
        out.push(Segment {
            from: edge_key(x, y, f),
            to: edge_key(x, y, t),
            a: point(f),
            b: point(t),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every segment of every case has an inside corner on its left.
    #[test]
    fn table_puts_inside_on_the_left() {
        let corner_pos = [[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]];
        for case in 1..15usize {
            for &centre_inside in &[false, true] {
                let (hi, lo) = (200.0, 50.0);
                let mut v = [lo; 4];
                for (i, item) in v.iter_mut().enumerate() {
                    if case & (1 << i) != 0 {
                        *item = hi;
                    }
                }
                if case == 6 || case == 9 {
                    // Push the centre average to the requested side.
                    let bump = if centre_inside { 60.0 } else { -60.0 };
                    for item in v.iter_mut() {
                        *item += bump;
                    }
                }
                let mut out = Vec::new();
                emit_cell(0, 0, case_of(v, 127.5), v, 127.5, &mut out);
                let expected = if case == 6 || case == 9 { 2 } else { 1 };
                assert_eq!(out.len(), expected, "case {case}");
                for s in &out {
                    let mid = [(s.a[0] + s.b[0]) / 2.0, (s.a[1] + s.b[1]) / 2.0];
                    let dir = [s.b[0] - s.a[0], s.b[1] - s.a[1]];
                    let left = [-dir[1], dir[0]];
                    // The nearest corner on the left side must be inside.
                    let mut best = (f32::MAX, 0usize);
                    for (i, p) in corner_pos.iter().enumerate() {
                        let rel = [p[0] - mid[0], p[1] - mid[1]];
                        if rel[0] * left[0] + rel[1] * left[1] > 0.0 {
                            let d = rel[0] * rel[0] + rel[1] * rel[1];
                            if d < best.0 {
                                best = (d, i);
                            }
                        }
                    }
                    assert!(
                        v[best.1] > 127.5,
                        "case {case}: corner {} left of segment",
                        best.1
                    );
                }
            }
        }
    }

    #[test]
    fn saddle_tables_differ_only_on_saddles() {
        for case in 0..16 {
            let (s, c) = (SEPARATED[case], CONNECTED[case]);
            if case == 6 || case == 9 {
                assert_eq!(s.count, 2);
                assert_ne!(s.edges, c.edges);
            } else {
                assert_eq!(s.count, c.count);
                assert_eq!(s.edges, c.edges);
            }
        }
    }
}
