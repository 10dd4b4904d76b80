//! Regular cells: Marching Cubes with Lengyel's crack-free tables, at any stride.
//!
//! Speed comes from bit rows: the solid flags of each row of strided samples are packed into
//! one `u64` (at most 33 samples), so the four sample rows under a row of cells tell with a
//! few word operations which cells have mixed corners; only those are visited, and each
//! cell's case is assembled from two bits of each row. Welding: an edge pass first gives
//! every sign-changing sample edge exactly one vertex (found with the same word operations:
//! XOR of neighbouring bits or rows) and stores its index in two z-layers of per-sample slots
//! (one per axis); cells then only read slots. No hash map, no per-cell "seen?" branch.

use crate::pos::CHUNK_SIZE;

use super::builder::Builder;
use super::neighborhood::{index, Neighborhood};
use super::tables::{edge_endpoints, REGULAR_CELL_CLASS, REGULAR_CELL_DATA, REGULAR_VERTEX_DATA};

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

/// High bit of every byte of a word.
const HIGH_BITS: u64 = 0x8080_8080_8080_8080;
/// Gathers bit 0 of each byte into the top byte (byte i lands on bit 56 + i).
const GATHER: u64 = 0x0102_0408_1020_4080;

/// Bit i set iff byte i of `d` is >= byte i of `c` (unsigned), for 8 bytes at once (SWAR).
#[inline]
fn bytes_at_least(d: u64, c: u64) -> u64 {
    // Compare the low 7 bits without borrows crossing bytes, then settle by the high bits.
    let low = (d | HIGH_BITS).wrapping_sub(c & !HIGH_BITS);
    let ge = ((d & !c) | (!(d ^ c) & low)) & HIGH_BITS;
    (ge >> 7).wrapping_mul(GATHER) >> 56
}

/// Solid bits (`density > t`) of one row of `n` samples `stride` apart from index `start`.
#[inline]
pub(crate) fn row_bits(density: &[u8], start: usize, stride: usize, n: usize, t: u8) -> u64 {
    if stride == 1 {
        let row = &density[start..start + n];
        let c = u64::from_le_bytes([t + 1; 8]);
        let mut m = 0u64;
        let mut words = row.chunks_exact(8);
        for (k, w) in words.by_ref().enumerate() {
            let d = u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]);
            m |= bytes_at_least(d, c) << (8 * k);
        }
        let done = n - words.remainder().len();
        for (x, &d) in words.remainder().iter().enumerate() {
            m |= u64::from(d > t) << (done + x);
        }
        m
    } else {
        (0..n).fold(0u64, |m, x| {
            m | (u64::from(density[start + x * stride] > t) << x)
        })
    }
}

/// Working memory of one meshing call, kept per thread between calls: allocating and freeing
/// it every chunk made the allocator hand pages back to the kernel and fault them in again.
/// Contents never leak between calls (a call reads only what it wrote first), so output
/// does not depend on what the thread meshed before.
#[derive(Default)]
struct Scratch {
    rows: Vec<u64>,
    slots: Vec<u32>,
    cells: CellScratch,
}

/// Slots per sample row, whatever the chunk's size: with a fixed layout the slot offset of
/// every cell edge is a compile-time constant ([`EDGE_SLOTS`]).
pub(crate) const PITCH: usize = 33;
/// Slots of one sample layer (three axes per sample).
pub(crate) const LAYER: usize = PITCH * PITCH * 3;
/// Slots of two sample layers, rounded up to a power of two so that masked indices need no
/// bounds checks.
pub(crate) const SLOTS: usize = 8192;
const _: () = assert!(SLOTS >= 2 * LAYER);

/// Indices of one layer of cells before they are appended (at most 32 x 32 cells of five
/// triangles; a power of two, for masked indices).
pub(crate) const CELL_INDICES: usize = 16384;
const _: () = assert!(CELL_INDICES >= 32 * 32 * 15);

/// Buffer of [`CELL_INDICES`] indices.
pub(crate) struct CellScratch(pub(crate) Box<[u32; CELL_INDICES]>);

impl Default for CellScratch {
    fn default() -> Self {
        Self(Box::new([0; CELL_INDICES]))
    }
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::default();
}

/// Meshes `cells[a]` cells of `stride` voxels per axis from local 0 into `b`.
pub(crate) fn mesh_regular(
    b: &mut Builder,
    nb: &Neighborhood,
    iso: f32,
    stride: i32,
    cells: [usize; 3],
) {
    SCRATCH.with(|s| match s.try_borrow_mut() {
        Ok(mut scratch) => mesh_regular_in(&mut scratch, b, nb, iso, stride, cells),
        // Only reachable by re-entrancy; fresh memory gives the same result.
        Err(_) => mesh_regular_in(&mut Scratch::default(), b, nb, iso, stride, cells),
    })
}

fn mesh_regular_in(
    scratch: &mut Scratch,
    b: &mut Builder,
    nb: &Neighborhood,
    iso: f32,
    stride: i32,
    cells: [usize; 3],
) {
    if !sign_rows(&mut scratch.rows, nb, iso, stride, cells, 0..cells[2] + 1) {
        return; // no sign change anywhere: no surface
    }
    let rows = &scratch.rows;
    let [gx, gy, _] = cells.map(|c| c + 1);
    let s = stride as usize;
    let full = (1u64 << gx) - 1;

    // Reserve output space: about one vertex and two triangles per mixed cell.
    let mut mixed = 0usize;
    for z in 0..cells[2] {
        for y in 0..cells[1] {
            let r = [
                rows[z * gy + y],
                rows[z * gy + y + 1],
                rows[(z + 1) * gy + y],
                rows[(z + 1) * gy + y + 1],
            ];
            let any = r[0] | r[1] | r[2] | r[3];
            let all = r[0] & r[1] & r[2] & r[3];
            mixed += ((any | (any >> 1)) & !(all & (all >> 1)) & ((1u64 << cells[0]) - 1))
                .count_ones() as usize;
        }
    }
    // With slack: growing a vector mid-pass copies it.
    b.reserve(mixed + mixed / 4, mixed * 2 + mixed / 2);

    // Vertex slots of two sample z-layers, one after the other: layer `z & 1` holds layer z.
    // No need to clear: every slot a cell reads is written first in this call.
    scratch.slots.resize(SLOTS, 0);
    let slots: &mut [u32; SLOTS] = (&mut scratch.slots[..]).try_into().expect("SLOTS long");
    let grid = Grid {
        rows,
        gy,
        stride: s,
        cell_mask: (1u64 << cells[0]) - 1,
        full,
    };
    let part = |z: usize| (z & 1) * LAYER..(z & 1) * LAYER + LAYER;
    // Edge pass first (flying-edges style): every sign-changing edge of a sample layer gets
    // its vertex before the cells that use it, so the cell loop only reads slots. Slots of
    // edges without a sign change keep stale values, but no cell case reads them.
    grid.emit_xy(b, &mut slots[part(0)], 0, cells[1]);
    for z in 0..cells[2] {
        grid.emit_z(b, &mut slots[part(z)], z);
        grid.emit_xy(b, &mut slots[part(z + 1)], z + 1, cells[1]);
        cell_layer(&grid, z, slots, &mut scratch.cells.0, &mut b.mesh.indices);
    }
}

/// Fills `rows` with the solid bits of the rows of strided samples (`gy` rows a layer, see
/// [`Grid`]) of the sample layers `layers` (the other rows keep stale values); false when no
/// sample of those layers differs from another (no surface there).
fn sign_rows(
    rows: &mut Vec<u64>,
    nb: &Neighborhood,
    iso: f32,
    stride: i32,
    cells: [usize; 3],
    layers: std::ops::Range<usize>,
) -> bool {
    if cells.contains(&0) {
        return false;
    }
    let t = match Threshold::new(iso) {
        Threshold::Above(t) => t,
        // Every sample on the same side: no surface.
        Threshold::AllSolid | Threshold::NoneSolid => return false,
    };
    debug_assert!(t < u8::MAX, "Threshold::new keeps t below 255");
    let [gx, gy, gz] = cells.map(|c| c + 1);
    let density = nb.densities();
    let s = stride as usize;
    let full = (1u64 << gx) - 1;
    rows.resize(gy * gz, 0);
    let (mut any, mut all) = (0u64, full);
    for z in layers {
        for y in 0..gy {
            let m = row_bits(density, index(0, (y * s) as i32, (z * s) as i32), s, gx, t);
            rows[z * gy + y] = m;
            any |= m;
            all &= m;
        }
    }
    any != 0 && all != full
}

/// Cell layers of a whole LOD-0 chunk.
pub(crate) const LAYERS: usize = CHUNK_SIZE as usize;
/// Vertex groups of a whole LOD-0 chunk, in the order they are made: the x and y edges of
/// sample layer 0 (`X0`), the z edges from layer 0 to 1 (`Z0`), `X1`, `Z1`, ..., `X32`.
/// Group `2k` is `Xk`, group `2k + 1` is `Zk`.
pub(crate) const GROUPS: usize = 2 * LAYERS + 1;

/// Where each vertex group and each cell layer's indices start in a whole LOD-0 chunk mesh
/// (the counts before them, then the totals).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Marks {
    pub(crate) vertices: [u32; GROUPS + 1],
    pub(crate) indices: [u32; LAYERS + 1],
}

impl Default for Marks {
    fn default() -> Self {
        Self {
            vertices: [0; GROUPS + 1],
            indices: [0; LAYERS + 1],
        }
    }
}

/// Meshes cell layers `from..to` of a whole LOD-0 chunk into `b`, recording in `marks` where
/// groups `X{from}` to `X{to}` and cell layers `from..to` start. `b` must hold exactly the
/// vertex groups before `X{from}` and the indices of the cell layers before `from`, as
/// meshing the whole chunk would have made them. False (and `b` untouched) when the chunk
/// has no surface at all (checked only when meshing the whole chunk): its mesh is empty.
pub(crate) fn mesh_lod0_layers(
    b: &mut Builder,
    nb: &Neighborhood,
    iso: f32,
    from: usize,
    to: usize,
    marks: &mut Marks,
) -> bool {
    debug_assert!(from <= to && to <= LAYERS);
    let mut run = |scratch: &mut Scratch| {
        let cells = [LAYERS; 3];
        // Only the layers meshed are read. With no sign change among them, the layers
        // copied around them have none either only if they are the whole chunk.
        let surface = sign_rows(&mut scratch.rows, nb, iso, 1, cells, from..to + 1);
        if !surface && from == 0 && to == LAYERS {
            return false;
        }
        let gy = LAYERS + 1;
        let full = (1u64 << gy) - 1;
        let grid = Grid {
            rows: &scratch.rows,
            gy,
            stride: 1,
            cell_mask: (1u64 << LAYERS) - 1,
            full,
        };
        scratch.slots.resize(SLOTS, 0);
        let slots: &mut [u32; SLOTS] = (&mut scratch.slots[..]).try_into().expect("SLOTS long");
        let part = |z: usize| (z & 1) * LAYER..(z & 1) * LAYER + LAYER;
        let count = |b: &Builder| b.mesh.keys.len() as u32;
        marks.vertices[2 * from] = count(b);
        grid.emit_xy(b, &mut slots[part(from)], from, LAYERS);
        for z in from..to {
            marks.vertices[2 * z + 1] = count(b);
            grid.emit_z(b, &mut slots[part(z)], z);
            marks.vertices[2 * z + 2] = count(b);
            grid.emit_xy(b, &mut slots[part(z + 1)], z + 1, LAYERS);
            marks.indices[z] = b.mesh.indices.len() as u32;
            cell_layer(&grid, z, slots, &mut scratch.cells.0, &mut b.mesh.indices);
        }
        true
    };
    SCRATCH.with(|s| match s.try_borrow_mut() {
        Ok(mut scratch) => run(&mut scratch),
        Err(_) => run(&mut Scratch::default()),
    })
}

/// Pushes the triangles of the mixed cells of cell layer `z`, reading vertex ids from
/// `slots` (two sample layers; layer `z & 1` holds sample layer z).
pub(crate) fn cell_layer(
    grid: &Grid,
    z: usize,
    slots: &[u32; SLOTS],
    buf: &mut [u32; CELL_INDICES],
    out: &mut Vec<u32>,
) {
    let (rows, gy) = (grid.rows, grid.gy);
    let edge_slots = &EDGE_SLOTS[z & 1];
    // Indices go to a local buffer, appended once per layer: pushing each one reloaded the
    // vector's length and capacity from memory. Masks stand in for bounds checks.
    let mut n = 0;
    for y in 0..gy - 1 {
        let m00 = rows[z * gy + y];
        let m10 = rows[z * gy + y + 1];
        let m01 = rows[(z + 1) * gy + y];
        let m11 = rows[(z + 1) * gy + y + 1];
        let any = m00 | m10 | m01 | m11;
        let all = m00 & m10 & m01 & m11;
        let mut active = (any | (any >> 1)) & !(all & (all >> 1)) & grid.cell_mask;
        while active != 0 {
            let x = active.trailing_zeros() as usize;
            active &= active - 1;
            let case = ((m00 >> x) & 3)
                | ((m10 >> x) & 3) << 2
                | ((m01 >> x) & 3) << 4
                | ((m11 >> x) & 3) << 6;
            let tris = &CASE_TRIANGLES[case as usize];
            let base = (y * PITCH + x) * 3;
            for tri in tris.edges[..usize::from(tris.len)].chunks_exact(3) {
                for &e in tri {
                    let at = base + usize::from(edge_slots[usize::from(e & 31)]);
                    buf[n & (CELL_INDICES - 1)] = slots[at & (SLOTS - 1)];
                    n += 1;
                }
            }
        }
    }
    out.extend_from_slice(&buf[..n]);
}

/// Slot offset of each cell edge (`lower corner << 2 | axis`, see [`CaseTriangles`]) from the
/// cell's lower corner, for cells whose lower sample layer is slot layer 0 and 1.
static EDGE_SLOTS: [[u16; 32]; 2] = {
    let mut out = [[0; 32]; 2];
    let mut e = 0;
    while e < 32 {
        let (corner, axis) = (e >> 2, e & 3);
        let mut parity = 0;
        while parity < 2 {
            let layer = ((corner >> 2) + parity) & 1;
            let at = layer * LAYER + (((corner >> 1) & 1) * PITCH + (corner & 1)) * 3 + axis;
            out[parity][e] = at as u16;
            parity += 1;
        }
        e += 1;
    }
    out
};

/// One regular case's triangles with each vertex named by its cell edge, as
/// `lower corner << 2 | axis` (Lengyel's corner numbering, see `tables.rs`).
struct CaseTriangles {
    /// Entries used: three per triangle.
    len: u8,
    edges: [u8; 15],
}

/// [`CaseTriangles`] of every regular case, flattened from Lengyel's class, vertex and
/// triangle tables at compile time so the cell loop does one lookup per triangle corner.
static CASE_TRIANGLES: [CaseTriangles; 256] = {
    let mut out = [const {
        CaseTriangles {
            len: 0,
            edges: [0; 15],
        }
    }; 256];
    let mut case = 0;
    while case < 256 {
        let data = &REGULAR_CELL_DATA[REGULAR_CELL_CLASS[case] as usize];
        let mut k = 0;
        // Unused entries of `vertex_index` hold the padding value 0xFF.
        while k < 15 && data.vertex_index[k] != 0xFF {
            let (ca, cb) = edge_endpoints(REGULAR_VERTEX_DATA[case][data.vertex_index[k] as usize]);
            let axis = (ca ^ cb).trailing_zeros();
            out[case].edges[k] = ((ca & cb) << 2) as u8 | axis as u8;
            k += 1;
        }
        out[case].len = k as u8;
        case += 1;
    }
    out
};

/// The packed sign grid of one chunk (`gy` rows per layer, one bit per sample) and its shape.
pub(crate) struct Grid<'r> {
    pub(crate) rows: &'r [u64],
    pub(crate) gy: usize,
    pub(crate) stride: usize,
    /// Bits of the x positions that start a cell (and an x edge).
    pub(crate) cell_mask: u64,
    /// Bits of all samples in a row.
    pub(crate) full: u64,
}

impl Grid<'_> {
    /// Vertices on the sign-changing x and y edges of sample layer `z`.
    fn emit_xy(&self, b: &mut Builder, slots: &mut [u32], z: usize, cells_y: usize) {
        let s = self.stride;
        for y in 0..self.gy {
            let m = self.rows[z * self.gy + y];
            let mut e = (m ^ (m >> 1)) & self.cell_mask;
            while e != 0 {
                let x = e.trailing_zeros() as usize;
                e &= e - 1;
                let lower = [(x * s) as i32, (y * s) as i32, (z * s) as i32];
                slots[(y * PITCH + x) * 3] = b.defer_vertex(lower, 0, s as u32);
            }
            if y < cells_y {
                let mut e = (m ^ self.rows[z * self.gy + y + 1]) & self.full;
                while e != 0 {
                    let x = e.trailing_zeros() as usize;
                    e &= e - 1;
                    let lower = [(x * s) as i32, (y * s) as i32, (z * s) as i32];
                    slots[(y * PITCH + x) * 3 + 1] = b.defer_vertex(lower, 1, s as u32);
                }
            }
        }
    }

    /// Vertices on the sign-changing z edges from sample layer `z` to `z + 1`.
    fn emit_z(&self, b: &mut Builder, slots: &mut [u32], z: usize) {
        let s = self.stride;
        for y in 0..self.gy {
            let mut e = (self.rows[z * self.gy + y] ^ self.rows[(z + 1) * self.gy + y]) & self.full;
            while e != 0 {
                let x = e.trailing_zeros() as usize;
                e &= e - 1;
                let lower = [(x * s) as i32, (y * s) as i32, (z * s) as i32];
                slots[(y * PITCH + x) * 3 + 2] = b.defer_vertex(lower, 2, s as u32);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swar_compare_matches_scalar_for_every_byte_pair() {
        for c in 0..=255u8 {
            for base in (0..=255u8).step_by(8) {
                let bytes: [u8; 8] =
                    std::array::from_fn(|i| base.wrapping_add((i as u8).wrapping_mul(37)));
                let got = bytes_at_least(u64::from_le_bytes(bytes), u64::from_le_bytes([c; 8]));
                let want = bytes
                    .iter()
                    .enumerate()
                    .fold(0, |m, (i, &d)| m | (u64::from(d >= c) << i));
                assert_eq!(got, want, "bytes {bytes:?} vs {c}");
            }
        }
    }

    #[test]
    fn flattened_case_table_matches_lengyels_tables() {
        for case in 0..256 {
            let data = &REGULAR_CELL_DATA[REGULAR_CELL_CLASS[case] as usize];
            let tris = &CASE_TRIANGLES[case];
            assert_eq!(
                usize::from(tris.len),
                3 * data.get_triangle_count() as usize
            );
            for (k, &e) in tris.edges[..usize::from(tris.len)].iter().enumerate() {
                let entry = REGULAR_VERTEX_DATA[case][data.vertex_index[k] as usize];
                let (ca, cb) = edge_endpoints(entry);
                assert_eq!((ca ^ cb).count_ones(), 1, "case {case}: not a cube edge");
                let (corner, axis) = (usize::from(e >> 2), usize::from(e & 3));
                assert_eq!(1 << axis, ca ^ cb, "case {case} entry {k}");
                assert_eq!(corner, ca.min(cb), "case {case} entry {k}");
            }
        }
    }

    #[test]
    fn threshold_matches_the_float_rule() {
        for iso in [-3.0f32, 0.0, 0.5, 99.0, 100.0, 127.5, 254.5, 255.0, 300.0] {
            for d in 0..=255u8 {
                let want = f32::from(d) > iso;
                let got = match Threshold::new(iso) {
                    Threshold::AllSolid => true,
                    Threshold::NoneSolid => false,
                    Threshold::Above(t) => d > t,
                };
                assert_eq!(got, want, "iso {iso} density {d}");
            }
        }
    }
}
