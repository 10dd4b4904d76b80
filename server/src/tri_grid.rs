//! A collision mesh's triangles binned on a coarse grid over the chunk, so
//! a ray cast tests only the triangles near the part of the ray inside the
//! mesh's bounds instead of all of them.
//!
//! The bins are conservative: a triangle is listed in every bin its bounding
//! box (grown by [`SLACK`]) overlaps, and a query returns every triangle in
//! every bin the query box overlaps. Any point of a triangle that lies in
//! the query box therefore brings that triangle along, so a ray cast over
//! the candidates finds exactly what it would over the whole mesh.

use strata_terrain::CHUNK_SIZE;

/// Side of a bin, in voxels.
pub const BIN: f64 = 4.0;
/// Bins along each axis; coordinates outside the chunk clamp to the edge bins.
pub const BINS: usize = CHUNK_SIZE as usize / BIN as usize;
/// Growth of every box, in voxels: far more than the rounding of a hit.
pub const SLACK: f64 = 1e-3;

/// Triangle indices by bin, stored flat.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriGrid {
    /// Bin `b` holds `tris[start[b]..start[b + 1]]`, ascending.
    start: Vec<u32>,
    tris: Vec<u32>,
}

/// The bin of a coordinate, clamped to the grid (monotonic, so a range of
/// coordinates maps onto a range of bins).
fn bin(x: f64) -> usize {
    (x / BIN).floor().clamp(0.0, (BINS - 1) as f64) as usize
}

/// [`bin`] for a vertex coordinate. Truncation toward zero equals the floor
/// wherever the clamp does not apply; `/ 4` is exact.
fn bin32(x: f32) -> u32 {
    ((x / BIN as f32) as i32).clamp(0, BINS as i32 - 1) as u32
}

/// Inclusive bin ranges, per axis, of the box `lo..=hi` grown by [`SLACK`].
fn bin_ranges(lo: [f64; 3], hi: [f64; 3]) -> [(usize, usize); 3] {
    std::array::from_fn(|i| (bin(lo[i] - SLACK), bin(hi[i] + SLACK)))
}

fn for_each_bin(r: [(usize, usize); 3], mut f: impl FnMut(usize)) {
    for z in r[2].0..=r[2].1 {
        for y in r[1].0..=r[1].1 {
            for x in r[0].0..=r[0].1 {
                f((z * BINS + y) * BINS + x);
            }
        }
    }
}

/// A triangle's bin ranges (its box grown by [`SLACK`]), 3 bits per bound.
fn packed_ranges(positions: &[[f32; 3]], tri: &[u32]) -> u32 {
    let (a, b, c) = (
        positions[tri[0] as usize],
        positions[tri[1] as usize],
        positions[tri[2] as usize],
    );
    let mut packed = 0;
    for i in 0..3 {
        let lo = bin32(a[i].min(b[i]).min(c[i]) - SLACK as f32);
        let hi = bin32(a[i].max(b[i]).max(c[i]) + SLACK as f32);
        packed |= (lo | hi << 3) << (6 * i);
    }
    packed
}

fn unpack(packed: u32) -> [(usize, usize); 3] {
    std::array::from_fn(|i| {
        let r = packed >> (6 * i);
        ((r & 7) as usize, (r >> 3 & 7) as usize)
    })
}

impl TriGrid {
    /// Bins the triangles of `indices` (three per triangle) over `positions`
    /// (chunk-local).
    pub fn build(positions: &[[f32; 3]], indices: &[u32]) -> Self {
        let ranges: Vec<u32> = indices
            .chunks_exact(3)
            .map(|tri| packed_ranges(positions, tri))
            .collect();
        // Counting sort: sizes, offsets, then fill in triangle order.
        let mut start = vec![0u32; BINS * BINS * BINS + 1];
        for &r in &ranges {
            for_each_bin(unpack(r), |b| start[b + 1] += 1);
        }
        for b in 1..start.len() {
            start[b] += start[b - 1];
        }
        let mut next: Vec<u32> = start[..start.len() - 1].to_vec();
        let mut tris = vec![0u32; *start.last().unwrap_or(&0) as usize];
        for (n, &r) in ranges.iter().enumerate() {
            for_each_bin(unpack(r), |b| {
                tris[next[b] as usize] = n as u32;
                next[b] += 1;
            });
        }
        Self { start, tris }
    }

    /// Every triangle with a bin overlapping the box `lo..=hi`, ascending
    /// and without repeats, into `out` (cleared first).
    pub fn candidates(&self, lo: [f64; 3], hi: [f64; 3], out: &mut Vec<u32>) {
        out.clear();
        if self.tris.is_empty() {
            return;
        }
        for_each_bin(bin_ranges(lo, hi), |b| {
            let (s, e) = (self.start[b] as usize, self.start[b + 1] as usize);
            out.extend_from_slice(&self.tris[s..e]);
        });
        out.sort_unstable();
        out.dedup();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_triangle_is_in_every_bin_its_box_overlaps_and_only_there() {
        // One triangle across the x = 4 and y = 4 bin faces, one in a corner.
        let positions = [
            [3.0, 3.0, 1.0],
            [5.0, 3.0, 1.0],
            [3.0, 5.0, 1.0],
            [30.0, 30.0, 30.0],
            [31.0, 30.0, 30.0],
            [30.0, 31.0, 30.0],
        ];
        let grid = TriGrid::build(&positions, &[0, 1, 2, 3, 4, 5]);
        let mut out = Vec::new();
        for (x, y) in [(1.0, 1.0), (6.0, 1.0), (1.0, 6.0), (6.0, 6.0)] {
            grid.candidates([x, y, 1.0], [x, y, 1.0], &mut out);
            assert_eq!(out, [0], "bin at ({x}, {y})");
        }
        grid.candidates([20.0; 3], [20.0; 3], &mut out);
        assert!(out.is_empty());
        // Outside the chunk clamps to the edge bins.
        grid.candidates([40.0; 3], [40.0; 3], &mut out);
        assert_eq!(out, [1]);
        grid.candidates([-5.0; 3], [40.0; 3], &mut out);
        assert_eq!(out, [0, 1], "ascending, each once");
    }

    #[test]
    fn an_empty_mesh_has_no_candidates() {
        let grid = TriGrid::build(&[], &[]);
        let mut out = vec![7];
        grid.candidates([0.0; 3], [32.0; 3], &mut out);
        assert!(out.is_empty());
    }
}
