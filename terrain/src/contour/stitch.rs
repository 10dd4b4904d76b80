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

use super::{ContourError, EdgeAxis, EdgeKey, Polyline, Segment};

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

/// Largest dense edge index, in edge slots (16 bytes each: 32 MiB).
const DENSE_INDEX_MAX_SLOTS: u64 = 1 << 21;
/// A dense index is used only while it has at most this many slots per
/// segment; sparser key sets (a few far-apart pieces) use a hash map.
const DENSE_SLOTS_PER_SEGMENT: u64 = 64;

const NONE: usize = usize::MAX;

/// Per edge: the segment starting there and the one ending there.
///
/// Contours of a grid cover a compact key range, so a flat array over the
/// keys' bounding box is the fast path; the hash map covers the rest. Both
/// are only looked up, so the choice never changes the output.
enum EdgeIndex {
    Dense {
        min: [i64; 2],
        width: u64,
        slots: Vec<[usize; 2]>,
    },
    Hash(KeyMap<[usize; 2]>),
}

impl EdgeIndex {
    fn for_segments(segments: &[Segment]) -> Self {
        let mut min = [i64::MAX; 2];
        let mut max = [i64::MIN; 2];
        for k in segments.iter().flat_map(|s| [s.from, s.to]) {
            let p = [i64::from(k.x), i64::from(k.y)];
            for a in 0..2 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        let n = segments.len() as u64;
        if n > 0 {
            // Spans fit in u64: both ends are i32.
            let width = (max[0] - min[0] + 1) as u64;
            let height = (max[1] - min[1] + 1) as u64;
            let count = width.saturating_mul(height).saturating_mul(2);
            if count <= DENSE_INDEX_MAX_SLOTS && count <= n.saturating_mul(DENSE_SLOTS_PER_SEGMENT)
            {
                return EdgeIndex::Dense {
                    min,
                    width,
                    slots: vec![[NONE; 2]; count as usize],
                };
            }
        }
        let mut map = KeyMap::default();
        map.reserve(segments.len() + segments.len() / 8);
        EdgeIndex::Hash(map)
    }

    /// Slot of a key inside the dense box (all keys are, by construction).
    #[inline]
    fn dense_slot(min: [i64; 2], width: u64, k: EdgeKey) -> usize {
        let dx = (i64::from(k.x) - min[0]) as u64;
        let dy = (i64::from(k.y) - min[1]) as u64;
        ((dy * width + dx) * 2 + u64::from(k.axis == EdgeAxis::Y)) as usize
    }

    fn entry(&mut self, k: EdgeKey) -> Option<&mut [usize; 2]> {
        match self {
            EdgeIndex::Dense { min, width, slots } => {
                slots.get_mut(Self::dense_slot(*min, *width, k))
            }
            EdgeIndex::Hash(map) => Some(map.entry(k).or_insert([NONE; 2])),
        }
    }

    fn get(&self, k: EdgeKey) -> [usize; 2] {
        let found = match self {
            EdgeIndex::Dense { min, width, slots } => slots.get(Self::dense_slot(*min, *width, k)),
            EdgeIndex::Hash(map) => map.get(&k),
        };
        found.copied().unwrap_or([NONE; 2])
    }
}

/// Stitches segments into polylines.
///
/// Every edge may start at most one segment and end at most one (true of
/// any Marching Squares output); otherwise [`ContourError::DuplicateEdge`].
pub fn stitch(segments: Vec<Segment>) -> Result<Vec<Polyline>, ContourError> {
    let n = segments.len();
    let mut ends = EdgeIndex::for_segments(&segments);
    for (i, s) in segments.iter().enumerate() {
        for (key, side) in [(s.from, 0), (s.to, 1)] {
            // Every key lies in the index (dense box or map).
            if let Some(slot) = ends.entry(key) {
                if slot[side] != NONE {
                    return Err(ContourError::DuplicateEdge(key));
                }
                slot[side] = i;
            }
        }
    }
    // Each segment's successor, and whether something leads into it.
    let next: Vec<usize> = segments.iter().map(|s| ends.get(s.to)[0]).collect();
    let has_pred: Vec<bool> = segments
        .iter()
        .map(|s| ends.get(s.from)[1] != NONE)
        .collect();
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
