//! Transvoxel transition cells: crack-free seams between this chunk (LOD k) and finer
//! (LOD k-1) face neighbours.
//!
//! For each face bit in [`MeshOptions::transition_faces`](super::MeshOptions):
//!
//! 1. Regular vertices within one cell of the face are pushed inward by up to
//!    [`TRANSITION_WIDTH`] of a cell (Lengyel's shrink, along the face normal, falling off
//!    linearly to zero one cell in). That opens a thin slab along the face.
//! 2. One transition cell per face cell fills the slab: its full-resolution side samples the
//!    face at half stride, exactly like the finer neighbour's cells do, so its vertices there
//!    are the neighbour's vertices (same key, same bits); its low-resolution side reuses this
//!    chunk's own (pushed) regular vertices on the face's coarse edges.
//!
//! Edges and corners where 2 or 3 transition faces meet need nothing special: the pushes add
//! per axis, and neighbouring transition slabs share their slanted side faces vertex for vertex.
//! Where a transition face meets a face that is NOT a transition face, the push is tapered to
//! zero on that face (multiplied by the distance to it in cells, capped at 1), so vertices on a
//! same-LOD neighbour's face stay where that neighbour puts them. Displacement only ever moves
//! a coordinate along a transition axis by a monotone function of that coordinate, so no
//! triangle folds over.

use std::collections::HashMap;

use super::builder::Builder;
use super::neighborhood::{index, Neighborhood};
use super::tables::{
    edge_endpoints, TRANSITION_CASE_SAMPLES, TRANSITION_CELL_CLASS, TRANSITION_CELL_DATA,
    TRANSITION_REVERSE_FLAG, TRANSITION_SAMPLE_SOURCE, TRANSITION_VERTEX_DATA,
};
use super::types::VertexKey;
use crate::pos::CHUNK_SIZE;

/// Width of the transition slab, as a fraction of the cell size (Lengyel's transition width).
pub const TRANSITION_WIDTH: f64 = 0.5;

/// The six faces, bit order -X,+X,-Y,+Y,-Z,+Z: (u, v, w axes, max side?). (u, v, inward w) is
/// right-handed, so the tables' winding holds unchanged on every face.
const FACE_FRAMES: [([usize; 3], bool); 6] = [
    ([1, 2, 0], false),
    ([2, 1, 0], true),
    ([2, 0, 1], false),
    ([0, 2, 1], true),
    ([0, 1, 2], false),
    ([1, 0, 2], true),
];

/// Distance (voxels) from local coordinate `c` on a face's axis to that face.
#[inline]
fn face_distance(c: f64, max_side: bool) -> f64 {
    if max_side {
        f64::from(CHUNK_SIZE) - c
    } else {
        c
    }
}

/// Lengyel's inward push of a regular vertex at local `p` for the faces in `faces`.
pub(crate) fn displaced(p: [f32; 3], faces: u8, stride: f64) -> [f32; 3] {
    let p64 = p.map(f64::from);
    let mut taper = 1.0f64;
    for (f, &(frame, max_side)) in FACE_FRAMES.iter().enumerate() {
        if faces & (1 << f) == 0 {
            let d = face_distance(p64[frame[2]], max_side) / stride;
            taper *= d.min(1.0);
        }
    }
    if taper == 0.0 {
        return p;
    }
    let mut out = p64;
    for (f, &(frame, max_side)) in FACE_FRAMES.iter().enumerate() {
        if faces & (1 << f) != 0 {
            let a = frame[2];
            let d = face_distance(p64[a], max_side) / stride;
            if d < 1.0 {
                let push = (1.0 - d) * TRANSITION_WIDTH * stride * taper;
                out[a] += if max_side { -push } else { push };
            }
        }
    }
    out.map(|c| c as f32)
}

/// Adds transition cells on every face in `faces` (regular cells must already be meshed).
pub(crate) fn mesh_transitions(
    b: &mut Builder,
    nb: &Neighborhood,
    iso: f32,
    stride: i32,
    faces: u8,
) {
    let s = f64::from(stride);
    for p in b.mesh.positions.iter_mut() {
        *p = displaced(*p, faces, s);
    }
    // Transition cells reuse regular vertices only on the coarse edges lying in their face
    // plane; index just those (keys of edges on a transition face plane).
    let o = nb.origin();
    let on_face = |k: &VertexKey| {
        let lower = [
            k.base.x.wrapping_sub(o.x),
            k.base.y.wrapping_sub(o.y),
            k.base.z.wrapping_sub(o.z),
        ];
        FACE_FRAMES
            .iter()
            .enumerate()
            .any(|(f, &(frame, max_side))| {
                let plane = if max_side { CHUNK_SIZE } else { 0 };
                faces & (1 << f) != 0 && usize::from(k.axis) != frame[2] && lower[frame[2]] == plane
            })
    };
    let mut ids: HashMap<VertexKey, u32> = b
        .mesh
        .keys
        .iter()
        .enumerate()
        .filter(|(_, k)| on_face(k))
        .map(|(i, k)| (*k, i as u32))
        .collect();
    let density = nb.densities();
    let half = stride / 2;
    let cells = CHUNK_SIZE / stride;
    let mut verts = [0u32; 12];
    for (f, &(frame, max_side)) in FACE_FRAMES.iter().enumerate() {
        if faces & (1 << f) == 0 {
            continue;
        }
        let [au, av, aw] = frame;
        let plane = if max_side { CHUNK_SIZE } else { 0 };
        for j in 0..cells {
            for i in 0..cells {
                // The nine full-resolution samples of this face cell.
                let mut pos = [[0i32; 3]; 9];
                let mut solid = [false; 9];
                for (k, (p, sld)) in pos.iter_mut().zip(solid.iter_mut()).enumerate() {
                    p[aw] = plane;
                    p[au] = i * stride + (k as i32 % 3) * half;
                    p[av] = j * stride + (k as i32 / 3) * half;
                    *sld = f32::from(density[index(p[0], p[1], p[2])]) > iso;
                }
                let case = TRANSITION_CASE_SAMPLES
                    .iter()
                    .enumerate()
                    .fold(0usize, |c, (bit, &k)| c | (usize::from(solid[k]) << bit));
                if case == 0 || case == 0x1FF {
                    continue;
                }
                let class = TRANSITION_CELL_CLASS[case];
                let data = &TRANSITION_CELL_DATA[(class & !TRANSITION_REVERSE_FLAG) as usize];
                let n = data.get_vertex_count() as usize;
                for (v, &entry) in verts
                    .iter_mut()
                    .zip(TRANSITION_VERTEX_DATA[case].iter())
                    .take(n)
                {
                    let (ea, eb) = edge_endpoints(entry);
                    let pa = pos[TRANSITION_SAMPLE_SOURCE[ea]];
                    let pb = pos[TRANSITION_SAMPLE_SOURCE[eb]];
                    let axis = if pa[au] != pb[au] { au } else { av };
                    let lower = if pa[axis] < pb[axis] { pa } else { pb };
                    let len = (pa[axis] - pb[axis]).unsigned_abs();
                    let key = VertexKey::from_local(nb.origin(), lower, axis, len);
                    *v = *ids.entry(key).or_insert_with(|| {
                        let id = b.add_vertex(lower, axis, len);
                        if len == stride as u32 {
                            // A coarse edge no regular cell produced: push it like one.
                            let p = &mut b.mesh.positions[id as usize];
                            *p = displaced(*p, faces, s);
                        }
                        id
                    });
                }
                let reverse = class & TRANSITION_REVERSE_FLAG != 0;
                let tris = data.get_triangle_count() as usize;
                for t in data.vertex_index[..tris * 3].chunks_exact(3) {
                    let (a, bb, c) = (
                        verts[t[0] as usize],
                        verts[t[1] as usize],
                        verts[t[2] as usize],
                    );
                    if reverse {
                        b.triangle(a, c, bb);
                    } else {
                        b.triangle(a, bb, c);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_is_full_on_the_face_zero_one_cell_in_and_tapered_at_other_faces() {
        let s = 4.0;
        // -X transition: a vertex on the face moves in by the full width, one cell in not at all.
        assert_eq!(displaced([0.0, 10.0, 10.0], 0b1, s), [2.0, 10.0, 10.0]);
        assert_eq!(displaced([4.0, 10.0, 10.0], 0b1, s), [4.0, 10.0, 10.0]);
        assert_eq!(displaced([2.0, 10.0, 10.0], 0b1, s), [3.0, 10.0, 10.0]);
        // +X transition pushes towards -x.
        assert_eq!(displaced([32.0, 10.0, 10.0], 0b10, s), [30.0, 10.0, 10.0]);
        // On a non-transition face (+Y here) nothing moves; halfway into its cell, half the push.
        assert_eq!(displaced([0.0, 32.0, 10.0], 0b1, s), [0.0, 32.0, 10.0]);
        assert_eq!(displaced([0.0, 30.0, 10.0], 0b1, s), [1.0, 30.0, 10.0]);
        // Two transition faces meeting at an edge: both pushes apply.
        assert_eq!(displaced([0.0, 0.0, 10.0], 0b101, s), [2.0, 2.0, 10.0]);
        // Order along the pushed axis is kept (no fold-over).
        let xs: Vec<f32> = (0..=8)
            .map(|i| displaced([i as f32 * 0.5, 9.0, 9.0], 0b1, s)[0])
            .collect();
        assert!(xs.windows(2).all(|w| w[0] < w[1]), "{xs:?}");
    }
}
