//! Regular cells: Marching Cubes with Lengyel's crack-free tables, at any stride.
//!
//! Corner signs are computed once per sample into a grid, so each cell's case is eight byte
//! loads. Vertices are welded through two z-layers of per-sample slots (one per axis): a vertex
//! is made the first time any cell touches its edge and reused by the up to three other cells
//! sharing that edge, so each sign-changing edge yields exactly one vertex and no hash map sits
//! in the hot loop.

use super::builder::Builder;
use super::neighborhood::{index, Neighborhood};
use super::tables::{edge_endpoints, REGULAR_CELL_CLASS, REGULAR_CELL_DATA, REGULAR_VERTEX_DATA};

/// Marker of an empty vertex slot.
const NO_VERTEX: u32 = u32::MAX;

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
    let [gx, gy, gz] = cells.map(|c| c + 1);
    let density = nb.densities();
    // Corner signs of the strided sample grid.
    let mut solid = vec![0u8; gx * gy * gz];
    let mut solid_count = 0usize;
    let s = stride as usize;
    for z in 0..gz {
        for y in 0..gy {
            let src = index(0, (y * s) as i32, (z * s) as i32);
            let row = &mut solid[(z * gy + y) * gx..][..gx];
            for (x, out) in row.iter_mut().enumerate() {
                let d = density[src + x * s];
                let v = u8::from(f32::from(d) > iso);
                *out = v;
                solid_count += usize::from(v);
            }
        }
    }
    if solid_count == 0 || solid_count == solid.len() {
        return; // no sign change anywhere: no surface
    }

    let layer = gx * gy * 3;
    let mut slots = [vec![NO_VERTEX; layer], vec![NO_VERTEX; layer]];
    let (sx, sy, sz) = (1usize, gx, gx * gy);
    let mut verts = [0u32; 12];
    for z in 0..cells[2] {
        if z > 0 {
            // Layer z+1 reuses the buffer of layer z-1.
            slots[(z + 1) & 1].fill(NO_VERTEX);
        }
        for y in 0..cells[1] {
            let r = z * sz + y * sy;
            for x in 0..cells[0] {
                let c = r + x * sx;
                let case = solid[c]
                    | solid[c + sx] << 1
                    | solid[c + sy] << 2
                    | solid[c + sx + sy] << 3
                    | solid[c + sz] << 4
                    | solid[c + sx + sz] << 5
                    | solid[c + sy + sz] << 6
                    | solid[c + sx + sy + sz] << 7;
                if case == 0 || case == 255 {
                    continue;
                }
                let data = &REGULAR_CELL_DATA[REGULAR_CELL_CLASS[case as usize] as usize];
                let entries = &REGULAR_VERTEX_DATA[case as usize];
                let n = data.get_vertex_count() as usize;
                for (v, &entry) in verts.iter_mut().zip(entries.iter()).take(n) {
                    let (ca, cb) = edge_endpoints(entry);
                    let axis = (ca ^ cb).trailing_zeros() as usize;
                    let (ox, oy, oz) = (x + (ca & 1), y + ((ca >> 1) & 1), z + ((ca >> 2) & 1));
                    let slot = &mut slots[oz & 1][(oy * gx + ox) * 3 + axis];
                    if *slot == NO_VERTEX {
                        let lower = [(ox * s) as i32, (oy * s) as i32, (oz * s) as i32];
                        *slot = b.add_vertex(lower, axis, s as u32);
                    }
                    *v = *slot;
                }
                let tris = data.get_triangle_count() as usize;
                for t in data.vertex_index[..tris * 3].chunks_exact(3) {
                    b.triangle(
                        verts[t[0] as usize],
                        verts[t[1] as usize],
                        verts[t[2] as usize],
                    );
                }
            }
        }
    }
}
