//! Regular cells: Marching Cubes with Lengyel's crack-free tables, at any stride.
//!
//! Speed comes from bit rows: the solid flags of each row of strided samples are packed into
//! one `u64` (at most 33 samples), so the four sample rows under a row of cells tell with a
//! few word operations which cells have mixed corners; only those are visited, and each
//! cell's case is assembled from two bits of each row. Vertices are welded through two
//! z-layers of per-sample slots (one per axis): a vertex is made the first time any cell
//! touches its edge and reused by the other cells sharing that edge, so each sign-changing
//! edge yields exactly one vertex, without a hash map in the hot loop.

use super::builder::Builder;
use super::neighborhood::{index, Neighborhood};
use super::tables::{edge_endpoints, REGULAR_CELL_CLASS, REGULAR_CELL_DATA, REGULAR_VERTEX_DATA};

/// Marker of an empty vertex slot.
const NO_VERTEX: u32 = u32::MAX;

/// How a u8 density compares with the isovalue: solid iff `density > iso`.
#[derive(Clone, Copy)]
pub(crate) enum Threshold {
    AllSolid,
    NoneSolid,
    /// Solid iff `density > .0` (the floor of the isovalue; equivalent for u8 densities).
    Above(u8),
}

impl Threshold {
    pub(crate) fn new(iso: f32) -> Self {
        let f = iso.floor();
        if f < 0.0 {
            Threshold::AllSolid
        } else if f >= 255.0 {
            Threshold::NoneSolid
        } else {
            Threshold::Above(f as u8)
        }
    }
}

/// Solid bits of one row of `n` samples `stride` apart starting at internal index `start`.
#[inline]
fn row_bits(density: &[u8], start: usize, stride: usize, n: usize, t: u8) -> u64 {
    if stride == 1 {
        density[start..start + n]
            .iter()
            .enumerate()
            .fold(0u64, |m, (x, &d)| m | (u64::from(d > t) << x))
    } else {
        (0..n).fold(0u64, |m, x| {
            m | (u64::from(density[start + x * stride] > t) << x)
        })
    }
}

/// Meshes `cells[a]` cells of `stride` voxels per axis from local 0 into `b`.
pub(crate) fn mesh_regular(
    b: &mut Builder,
    nb: &Neighborhood,
    iso: f32,
    stride: i32,
    cells: [usize; 3],
) {
    if cells.contains(&0) {
        return;
    }
    let t = match Threshold::new(iso) {
        Threshold::Above(t) => t,
        // Every sample on the same side: no surface.
        Threshold::AllSolid | Threshold::NoneSolid => return,
    };
    let [gx, gy, gz] = cells.map(|c| c + 1);
    let density = nb.densities();
    let s = stride as usize;
    let full = (1u64 << gx) - 1;
    let mut rows = vec![0u64; gy * gz];
    let (mut any, mut all) = (0u64, full);
    for z in 0..gz {
        for y in 0..gy {
            let m = row_bits(density, index(0, (y * s) as i32, (z * s) as i32), s, gx, t);
            rows[z * gy + y] = m;
            any |= m;
            all &= m;
        }
    }
    if any == 0 || all == full {
        return; // no sign change anywhere: no surface
    }

    let layer = gx * gy * 3;
    let mut slots = [vec![NO_VERTEX; layer], vec![NO_VERTEX; layer]];
    let mut written: [Vec<usize>; 2] = [Vec::new(), Vec::new()];
    let cell_mask = (1u64 << cells[0]) - 1;
    let mut verts = [0u32; 12];
    for z in 0..cells[2] {
        if z > 0 {
            // Layer z+1 reuses the buffer of layer z-1: clear what that layer wrote.
            let l = (z + 1) & 1;
            for &i in &written[l] {
                slots[l][i] = NO_VERTEX;
            }
            written[l].clear();
        }
        for y in 0..cells[1] {
            let m00 = rows[z * gy + y];
            let m10 = rows[z * gy + y + 1];
            let m01 = rows[(z + 1) * gy + y];
            let m11 = rows[(z + 1) * gy + y + 1];
            let any = m00 | m10 | m01 | m11;
            let all = m00 & m10 & m01 & m11;
            let mut active = (any | (any >> 1)) & !(all & (all >> 1)) & cell_mask;
            while active != 0 {
                let x = active.trailing_zeros() as usize;
                active &= active - 1;
                let case = ((m00 >> x) & 3)
                    | ((m10 >> x) & 3) << 2
                    | ((m01 >> x) & 3) << 4
                    | ((m11 >> x) & 3) << 6;
                let data = &REGULAR_CELL_DATA[REGULAR_CELL_CLASS[case as usize] as usize];
                let entries = &REGULAR_VERTEX_DATA[case as usize];
                let n = data.get_vertex_count() as usize;
                for (v, &entry) in verts.iter_mut().zip(entries.iter()).take(n) {
                    let (ca, cb) = edge_endpoints(entry);
                    let axis = (ca ^ cb).trailing_zeros() as usize;
                    let (ox, oy, oz) = (x + (ca & 1), y + ((ca >> 1) & 1), z + ((ca >> 2) & 1));
                    let l = oz & 1;
                    let i = (oy * gx + ox) * 3 + axis;
                    if slots[l][i] == NO_VERTEX {
                        let lower = [(ox * s) as i32, (oy * s) as i32, (oz * s) as i32];
                        slots[l][i] = b.add_vertex(lower, axis, s as u32);
                        written[l].push(i);
                    }
                    *v = slots[l][i];
                }
                let tris = data.get_triangle_count() as usize;
                for tri in data.vertex_index[..tris * 3].chunks_exact(3) {
                    b.triangle(
                        verts[tri[0] as usize],
                        verts[tri[1] as usize],
                        verts[tri[2] as usize],
                    );
                }
            }
        }
    }
}
