//! Joining cell segments into polylines by their shared edge keys.
//!
//! Keys are global, so segments from any number of tiles join the same way
//! as those of one grid. The output order is canonical: segments are sorted
//! by key first, open polylines come first (ordered by their start edge),
//! then loops, each starting at its smallest edge key. Equal segment sets
//! therefore give equal polylines whatever order they arrived in.

use super::{ContourError, EdgeKey, Polyline, Segment};

/// Stitches segments into polylines.
///
/// Every edge may start at most one segment and end at most one (true of
/// any Marching Squares output); otherwise [`ContourError::DuplicateEdge`].
pub fn stitch(mut segments: Vec<Segment>) -> Result<Vec<Polyline>, ContourError> {
    segments.sort_by_key(|s| (s.from, s.to));
    if let Some(w) = segments.windows(2).find(|w| w[0].from == w[1].from) {
        return Err(ContourError::DuplicateEdge(w[0].from));
    }
    let mut ends: Vec<EdgeKey> = segments.iter().map(|s| s.to).collect();
    ends.sort_unstable();
    if let Some(w) = ends.windows(2).find(|w| w[0] == w[1]) {
        return Err(ContourError::DuplicateEdge(w[0]));
    }

    let find = |key: EdgeKey| segments.binary_search_by(|s| s.from.cmp(&key)).ok();
    let mut visited = vec![false; segments.len()];
    let mut out = Vec::new();

    // Open polylines start where no segment ends: on the region border.
    for start in 0..segments.len() {
        if ends.binary_search(&segments[start].from).is_err() {
            out.push(walk(&segments, start, &mut visited, find));
        }
    }
    // Everything left lies on loops; visiting in key order starts each loop
    // at its smallest key.
    for start in 0..segments.len() {
        if !visited[start] {
            out.push(walk(&segments, start, &mut visited, find));
        }
    }
    Ok(out)
}

/// Follows segments from `start` until the chain ends or returns to `start`.
fn walk(
    segments: &[Segment],
    start: usize,
    visited: &mut [bool],
    find: impl Fn(EdgeKey) -> Option<usize>,
) -> Polyline {
    let mut points = vec![segments[start].a];
    let mut cur = start;
    let mut closed = false;
    loop {
        visited[cur] = true;
        points.push(segments[cur].b);
        match find(segments[cur].to) {
            Some(next) if next == start => {
                closed = true;
                break;
            }
            // With unique start and end keys a chain cannot run into another
            // chain; stopping on a visited segment keeps this total anyway.
            Some(next) if !visited[next] => cur = next,
            _ => break,
        }
    }
    if closed {
        // The last point is the loop's first point again.
        points.pop();
    }
    Polyline { points, closed }
}
