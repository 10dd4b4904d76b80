//! Joining cell segments into polylines by their shared edge keys.
//!
//! Keys are global, so segments from any number of tiles join the same way
//! as those of one grid. The output order is canonical: open polylines come
//! first, ordered by their first edge key, then loops, each rotated to start
//! at its smallest edge key and ordered by it. Equal segment sets therefore
//! give equal polylines whatever order they arrived in (tile order, thread
//! scheduling).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use super::{ContourError, EdgeKey, Polyline, Segment};

/// A fast multiplicative hasher for edge keys (FxHash's mixing step). Only
/// used for lookups, never iterated, so it cannot affect output order.
#[derive(Debug, Default, Clone, Copy)]
struct KeyHasher(u64);

const MIX: u64 = 0x51_7c_c1_b7_27_22_0a_95;

impl KeyHasher {
    #[inline]
    fn add(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(MIX);
    }
}

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.add(u64::from(b));
        }
    }

    fn write_u32(&mut self, v: u32) {
        self.add(u64::from(v));
    }

    fn write_i32(&mut self, v: i32) {
        self.add(u64::from(v as u32));
    }

    fn write_u64(&mut self, v: u64) {
        self.add(v);
    }

    fn write_usize(&mut self, v: usize) {
        self.add(v as u64);
    }

    fn write_isize(&mut self, v: isize) {
        self.add(v as u64);
    }
}

type KeyMap<V> = HashMap<EdgeKey, V, BuildHasherDefault<KeyHasher>>;

/// Stitches segments into polylines.
///
/// Every edge may start at most one segment and end at most one (true of
/// any Marching Squares output); otherwise [`ContourError::DuplicateEdge`].
pub fn stitch(segments: Vec<Segment>) -> Result<Vec<Polyline>, ContourError> {
    const NONE: usize = usize::MAX;
    let n = segments.len();
    // Per edge: the segment starting there and the one ending there.
    let mut ends: KeyMap<[usize; 2]> = KeyMap::default();
    ends.reserve(n + n / 8);
    for (i, s) in segments.iter().enumerate() {
        for (key, side) in [(s.from, 0), (s.to, 1)] {
            let slot = &mut ends.entry(key).or_insert([NONE; 2])[side];
            if *slot != NONE {
                return Err(ContourError::DuplicateEdge(key));
            }
            *slot = i;
        }
    }
    // Each segment's successor, and whether something leads into it.
    // (Every key was inserted above; `get` just keeps this panic-free.)
    let at = |key: &EdgeKey, side: usize| ends.get(key).map_or(NONE, |e| e[side]);
    let next: Vec<usize> = segments.iter().map(|s| at(&s.to, 0)).collect();
    let has_pred: Vec<bool> = segments.iter().map(|s| at(&s.from, 1) != NONE).collect();
    drop(ends);

    let mut visited = vec![false; n];
    let mut open: Vec<(EdgeKey, Polyline)> = Vec::new();
    let mut loops: Vec<(EdgeKey, Polyline)> = Vec::new();
    // Open polylines start where no segment ends: on the region border.
    for start in 0..n {
        if !has_pred[start] {
            let (line, _, _) = walk(&segments, &next, start, &mut visited);
            open.push((segments[start].from, line));
        }
    }
    // Everything left lies on loops.
    for start in 0..n {
        if !visited[start] {
            let (mut line, min_at, min_key) = walk(&segments, &next, start, &mut visited);
            line.points.rotate_left(min_at);
            loops.push((min_key, line));
        }
    }
    open.sort_by_key(|(k, _)| *k);
    loops.sort_by_key(|(k, _)| *k);
    Ok(open.into_iter().chain(loops).map(|(_, l)| l).collect())
}

/// Follows segments from `start` until the chain ends or returns to
/// `start`. Also returns the smallest start key met and its position in
/// the points, where a loop is rotated to begin.
fn walk(
    segments: &[Segment],
    next: &[usize],
    start: usize,
    visited: &mut [bool],
) -> (Polyline, usize, EdgeKey) {
    let mut points = vec![segments[start].a];
    let (mut cur, mut closed) = (start, false);
    let (mut min_key, mut min_at) = (segments[start].from, 0);
    loop {
        visited[cur] = true;
        points.push(segments[cur].b);
        let nx = next[cur];
        if nx == start {
            closed = true;
            break;
        }
        // With unique start and end keys a chain cannot run into another
        // chain; stopping on a visited segment keeps this total anyway.
        if nx >= segments.len() || visited[nx] {
            break;
        }
        if segments[nx].from < min_key {
            min_key = segments[nx].from;
            min_at = points.len() - 1;
        }
        cur = nx;
    }
    if closed {
        // The last point is the loop's first point again.
        points.pop();
    }
    (Polyline { points, closed }, min_at, min_key)
}
