//! Turns sign-changing sample edges into mesh vertices (position, normal, material, key).
//!
//! Exactness rule (makes chunk seams bit-identical): the edge parameter
//! `t = (iso - a) / (b - a)`, measured from the lower endpoint, is computed in f64, rounded to a
//! multiple of `1 / T_ONE` and clamped to `[1 / T_ONE, 1 - 1 / T_ONE]`. A chunk-local position
//! (integer + t * len) is then exact in f32, and world = chunk origin + local is exact too.
//! Clamping away from the endpoints also means a vertex never lands on a sample, so plateau
//! data (samples equal to or next to the isovalue) cannot collapse triangles to zero area.

use super::material::vertex_material;
use super::neighborhood::{index, Neighborhood, STEP_Y, STEP_Z};
use super::normals::{edge_normal, gradient};
use super::types::{Mesh, VertexKey};

/// Fractional bits of a quantized edge parameter.
pub(crate) const T_BITS: u32 = 16;
/// Quantized value of t = 1.
pub(crate) const T_ONE: u32 = 1 << T_BITS;

/// Quantized edge parameter between samples `a` (lower end) and `b` (upper end), which lie on
/// opposite sides of `iso`.
#[inline]
pub(crate) fn quantize_t(a: u8, b: u8, iso: f64) -> u32 {
    let (a, b) = (f64::from(a), f64::from(b));
    let t = (iso - a) / (b - a);
    // t is in [0, 1] (the endpoints straddle iso), so truncation is floor here.
    let q = (t * f64::from(T_ONE) + 0.5) as u32;
    q.clamp(1, T_ONE - 1)
}

/// Accumulates one chunk's mesh.
pub(crate) struct Builder<'a> {
    nb: &'a Neighborhood,
    iso: f32,
    pub(crate) mesh: Mesh,
}

impl<'a> Builder<'a> {
    pub(crate) fn new(nb: &'a Neighborhood, iso: f32) -> Self {
        Self {
            nb,
            iso,
            mesh: Mesh::default(),
        }
    }

    /// Position, normal and material of the vertex on the edge from local sample `lower`
    /// running `len` voxels along `axis`, whose endpoints straddle the isovalue.
    #[inline(always)]
    fn vertex_data(&self, lower: [i32; 3], axis: usize, len: u32) -> ([f32; 3], [f32; 3], u8) {
        let density = self.nb.densities();
        let il = index(lower[0], lower[1], lower[2]);
        let iu = il + [1, STEP_Y, STEP_Z][axis] * len as usize;
        let (a, b) = (density[il], density[iu]);
        let q = quantize_t(a, b, f64::from(self.iso));
        let mut pos = lower.map(|c| c as f32);
        pos[axis] =
            (f64::from(lower[axis]) + f64::from(q) * f64::from(len) / f64::from(T_ONE)) as f32;
        let lower_solid = f32::from(a) > self.iso;
        let normal = edge_normal(
            gradient(density, il),
            gradient(density, iu),
            q,
            T_ONE,
            axis,
            lower_solid,
        );
        let solid_at = if lower_solid { il } else { iu };
        let material = vertex_material(density, self.nb.materials(), self.iso, solid_at, len);
        (pos, normal, material)
    }

    /// World key of an edge given by its local lower endpoint.
    fn key(&self, lower: [i32; 3], axis: usize, len: u32) -> VertexKey {
        VertexKey::from_local(self.nb.origin(), lower, axis, len)
    }

    /// Registers the vertex on an edge (endpoints straddling the isovalue) and returns its
    /// index; its data is computed by the next [`Builder::flush`]. Deferring lets that pass
    /// run as one tight loop whose divisions and square roots overlap.
    #[inline]
    pub(crate) fn defer_vertex(&mut self, lower: [i32; 3], axis: usize, len: u32) -> u32 {
        let id = self.mesh.keys.len() as u32;
        let key = self.key(lower, axis, len);
        self.mesh.keys.push(key);
        id
    }

    /// Computes the data of every deferred vertex.
    pub(crate) fn flush(&mut self) {
        let o = self.nb.origin();
        for i in self.mesh.positions.len()..self.mesh.keys.len() {
            let k = self.mesh.keys[i];
            let lower = [
                k.base.x.wrapping_sub(o.x),
                k.base.y.wrapping_sub(o.y),
                k.base.z.wrapping_sub(o.z),
            ];
            let (p, n, m) = self.vertex_data(lower, usize::from(k.axis), u32::from(k.len));
            self.mesh.positions.push(p);
            self.mesh.normals.push(n);
            self.mesh.materials.push(m);
        }
    }

    /// Adds a vertex with its data right away (deferred ones are flushed first).
    pub(crate) fn add_vertex(&mut self, lower: [i32; 3], axis: usize, len: u32) -> u32 {
        self.flush();
        let id = self.defer_vertex(lower, axis, len);
        self.flush();
        id
    }

    /// Makes room for about `vertices` more vertices and `triangles` more triangles.
    pub(crate) fn reserve(&mut self, vertices: usize, triangles: usize) {
        let m = &mut self.mesh;
        m.positions.reserve(vertices);
        m.normals.reserve(vertices);
        m.materials.reserve(vertices);
        m.keys.reserve(vertices);
        m.indices.reserve(triangles * 3);
    }

    #[inline]
    pub(crate) fn triangle(&mut self, a: u32, b: u32, c: u32) {
        self.mesh.indices.extend_from_slice(&[a, b, c]);
    }
}
