//! Turns sign-changing sample edges into mesh vertices (position, normal, material, key).
//!
//! Exactness rule (makes chunk seams bit-identical): the edge parameter
//! `t = (iso - a) / (b - a)`, measured from the lower endpoint, is computed in f64, rounded to a
//! multiple of `1 / T_ONE` and clamped to `[1 / T_ONE, 1 - 1 / T_ONE]`. A chunk-local position
//! (integer + t * len) is then exact in f32, and world = chunk origin + local is exact too.
//! Clamping away from the endpoints also means a vertex never lands on a sample, so plateau
//! data (samples equal to or next to the isovalue) cannot collapse triangles to zero area.
//!
//! Speed: when `2 * iso` is an integer (the default 127.5 and every half-integer isovalue) the
//! same rounded value is computed in exact integer arithmetic with a reciprocal table instead
//! of an f64 division (the rational `t * T_ONE` is never within rounding distance of a tie, so
//! both give the same bits; a test checks every pair). Vertices are finished in batches so the
//! square roots and divisions of many vertices overlap (see [`Builder::flush`]).

use super::material::vertex_material;
use super::neighborhood::{index, Neighborhood, STEP_Y, STEP_Z};
use super::normals::{fallback_normal, gradient, normalise, raw_normal};
use super::types::{Mesh, VertexKey};

/// Fractional bits of a quantized edge parameter.
pub(crate) const T_BITS: u32 = 16;
/// Quantized value of t = 1.
pub(crate) const T_ONE: u32 = 1 << T_BITS;

/// Quantized edge parameter between samples `a` (lower end) and `b` (upper end), which lie on
/// opposite sides of `iso`. The reference definition; [`EdgeParam`] computes the same value.
#[inline]
pub(crate) fn quantize_t(a: u8, b: u8, iso: f64) -> u32 {
    let (a, b) = (f64::from(a), f64::from(b));
    let t = (iso - a) / (b - a);
    // t is in [0, 1] (the endpoints straddle iso), so truncation is floor here.
    let q = (t * f64::from(T_ONE) + 0.5) as u32;
    q.clamp(1, T_ONE - 1)
}

/// Shift of the fixed-point reciprocals in [`RECIPROCAL`].
const RECIP_SHIFT: u32 = 37;

/// `RECIPROCAL[e] = ceil(2^37 / e)`: for every `x < 2^26` and `e <= 1020`,
/// `x * RECIPROCAL[e] >> 37 == x / e` (the error term `x * (RECIPROCAL[e] * e - 2^37)` stays
/// below `x * e < 2^37`). Index 0 is unused.
static RECIPROCAL: [u64; 1021] = {
    let mut t = [0u64; 1021];
    let mut e = 1;
    while e < t.len() {
        t[e] = (1u64 << RECIP_SHIFT).div_ceil(e as u64);
        e += 1;
    }
    t
};

/// How one call computes [`quantize_t`] for its isovalue.
#[derive(Clone, Copy, Debug)]
pub(crate) enum EdgeParam {
    /// `iso = h / 2` with `h` in `0..=510`: exact integer arithmetic.
    Half(i32),
    /// Any other isovalue: the f64 reference.
    General(f64),
}

impl EdgeParam {
    pub(crate) fn new(iso: f32) -> Self {
        let h = f64::from(iso) * 2.0;
        if h.fract() == 0.0 && (0.0..=510.0).contains(&h) {
            EdgeParam::Half(h as i32)
        } else {
            EdgeParam::General(f64::from(iso))
        }
    }

    /// [`quantize_t`] for samples `a` (lower end) and `b` (upper end) straddling the isovalue.
    #[inline(always)]
    pub(crate) fn quantize(self, a: u8, b: u8) -> u32 {
        match self {
            EdgeParam::Half(h) => {
                // t = (h - 2a) / (2b - 2a); both have the same sign and |num| < |den| <= 510.
                let num = (h - 2 * i32::from(a)).unsigned_abs();
                let den = (2 * (i32::from(b) - i32::from(a))).unsigned_abs();
                // round(num * T_ONE / den) = floor((2 * num * T_ONE + den) / (2 * den)).
                let x = u64::from(num) * u64::from(2 * T_ONE) + u64::from(den);
                let e = (2 * den).min(1020) as usize;
                let q = ((x * RECIPROCAL[e]) >> RECIP_SHIFT) as u32;
                q.clamp(1, T_ONE - 1)
            }
            EdgeParam::General(iso) => quantize_t(a, b, iso),
        }
    }
}

/// Vertices finished together by [`Builder::flush`]: enough for the normalisation loop to run
/// on full vectors and for independent square roots and divisions to overlap.
pub(crate) const BATCH: usize = 32;

/// Accumulates one chunk's mesh.
pub(crate) struct Builder<'a> {
    nb: &'a Neighborhood,
    iso: f32,
    param: EdgeParam,
    pub(crate) mesh: Mesh,
}

impl<'a> Builder<'a> {
    pub(crate) fn new(nb: &'a Neighborhood, iso: f32) -> Self {
        Self {
            nb,
            iso,
            param: EdgeParam::new(iso),
            mesh: Mesh::default(),
        }
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

    /// Computes the data of every deferred vertex, [`BATCH`] at a time.
    pub(crate) fn flush(&mut self) {
        let end = self.mesh.keys.len();
        let mut start = self.mesh.positions.len();
        while start < end {
            let n = (end - start).min(BATCH);
            self.flush_batch(start, n);
            start += n;
        }
    }

    /// Position, normal and material of deferred vertices `start..start + n` (`n <= BATCH`).
    ///
    /// Each vertex is a function of its edge's samples only: `t` from its two endpoints, the
    /// normal from their gradients (see `normals.rs`), the material from its solid endpoint.
    fn flush_batch(&mut self, start: usize, n: usize) {
        let density = self.nb.densities();
        let materials = self.nb.materials();
        let o = self.nb.origin();
        let mut pos = [[0.0f32; 3]; BATCH];
        let mut mat = [0u8; BATCH];
        let mut raw = [[0.0f64; BATCH]; 3];
        let mut flat = [[0.0f32; 3]; BATCH];
        for (j, k) in self.mesh.keys[start..start + n].iter().enumerate() {
            let lower = [
                k.base.x.wrapping_sub(o.x),
                k.base.y.wrapping_sub(o.y),
                k.base.z.wrapping_sub(o.z),
            ];
            let (axis, len) = (usize::from(k.axis), u32::from(k.len));
            let il = index(lower[0], lower[1], lower[2]);
            let iu = il + [1, STEP_Y, STEP_Z][axis] * len as usize;
            let (a, b) = (density[il], density[iu]);
            let q = self.param.quantize(a, b);
            // Exact: q * len has at most 19 significant bits.
            let along =
                (f64::from(lower[axis]) + f64::from(q) * f64::from(len) / f64::from(T_ONE)) as f32;
            // Selects, not a store at index `axis`: a narrow store then a wide copy of the
            // same bytes would stall store forwarding.
            pos[j] = [0, 1, 2].map(|c| if c == axis { along } else { lower[c] as f32 });
            let lower_solid = f32::from(a) > self.iso;
            let r = raw_normal(gradient(density, il), gradient(density, iu), q, T_ONE);
            for (c, v) in raw.iter_mut().zip(r) {
                c[j] = v;
            }
            flat[j] = fallback_normal(axis, lower_solid);
            let solid_at = if lower_solid { il } else { iu };
            mat[j] = vertex_material(density, materials, self.iso, solid_at, len);
        }
        let mut normals = [[0.0f32; 3]; BATCH];
        normalise(&raw, |j| flat[j], &mut normals, n);
        let m = &mut self.mesh;
        m.positions.extend_from_slice(&pos[..n]);
        m.normals.extend_from_slice(&normals[..n]);
        m.materials.extend_from_slice(&mat[..n]);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_edge_parameter_equals_the_f64_reference_for_every_half_integer_iso() {
        for h in 0..=510i32 {
            let iso = f64::from(h) / 2.0;
            let param = EdgeParam::new(iso as f32);
            assert!(matches!(param, EdgeParam::Half(x) if x == h));
            for a in 0..=255u8 {
                for b in 0..=255u8 {
                    if (f64::from(a) > iso) != (f64::from(b) > iso) {
                        assert_eq!(
                            param.quantize(a, b),
                            quantize_t(a, b, iso),
                            "iso {iso} a {a} b {b}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn other_isovalues_use_the_f64_reference() {
        for iso in [100.25f32, 0.1, -1.0, 255.5, 1e9] {
            assert!(
                matches!(EdgeParam::new(iso), EdgeParam::General(_)),
                "{iso}"
            );
        }
        assert_eq!(
            EdgeParam::new(100.25).quantize(90, 110),
            quantize_t(90, 110, 100.25)
        );
    }
}
