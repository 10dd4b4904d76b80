//! One-thread path of [`super::mesh_volume`]: the same chunks in the same order, meshed
//! straight from the volume into the welded output with the same arithmetic, so the bytes
//! equal the parallel path's. No neighbourhood copy, no chunk meshes, no weld map.
//!
//! * Sign bits: at LOD 0 each slab of chunks (same z) is classified once, whole slices at a
//!   time (long streaming reads); a chunk's rows and its emptiness are cut from those bits.
//!   Coarser levels use the min/max pre-scan and strided rows per chunk.
//! * Vertex data is computed in batches, as `builder.rs` does, from the volume itself:
//!   central differences past the volume's faces repeat the face sample, like the apron.
//! * Welding: a vertex on a chunk's low face belongs to the earlier chunk across it, which
//!   left the ids on its high faces: the top face's as a list per chunk column, in the order
//!   the chunk above visits its first layer (which then takes all of them from it); the x
//!   and y faces' in one plane buffer each. Where those two meet (a chunk edge), the x face
//!   is read: a later chunk of the same band may already have reused the y buffer's entry.

use super::{chunk_is_empty, ChunkJob, VolumeError, VolumeGrid, VolumeMeshOptions};
use super::{CELLS, MAX_VOLUME_VERTICES, ROW};
use crate::mesh::builder::{EdgeParam, BATCH, T_ONE};
use crate::mesh::normals::{fallback_normal, normalise};
use crate::mesh::regular::{
    cell_layer, row_bits, CellScratch, Grid, Threshold, LAYER, PITCH, SLOTS,
};
use crate::mesh::{Mesh, VertexKey};
use crate::VoxelPos;

/// Meshes `jobs` in order on this thread; returns the mesh and how many chunks had none.
pub(super) fn mesh_direct(
    grid: &VolumeGrid<'_>,
    opts: &VolumeMeshOptions,
    jobs: &[ChunkJob],
    progress: &(dyn Fn() + Sync),
) -> Result<(Mesh, u64), VolumeError> {
    let mut s = Sweep::new(grid, opts);
    let mut empty = 0;
    for slab in jobs.chunk_by(|a, b| a.origin[2] == b.origin[2]) {
        if let (Some(t), 0) = (s.t, opts.lod) {
            s.classify(&slab[0], t);
        }
        for job in slab {
            if !s.chunk(job) {
                empty += 1;
            }
            if s.count > MAX_VOLUME_VERTICES {
                return Err(VolumeError::TooManyVertices {
                    count: MAX_VOLUME_VERTICES + 1,
                    max: MAX_VOLUME_VERTICES,
                });
            }
            progress();
        }
    }
    Ok((s.out, empty))
}

/// Vertex ids on the high faces of recently meshed chunks.
struct Faces {
    /// Plane x = chunk end: y and z edges at `(z * gy + y) * 2 + k` (chunk-local samples).
    x: Vec<u32>,
    /// Plane y = chunk end: x and z edges at `(z * nx + x) * 2 + k` (local z, volume x).
    y: Vec<u32>,
    /// Plane z = chunk end, per chunk column (x fastest): ids of its sign-changing x and y
    /// edges in [`plane_edges`] order.
    z: Vec<Vec<u32>>,
    /// Strided samples along the volume's x.
    nx: usize,
}

/// Samples per band of chunks along y at LOD 0.
const BAND: usize = CELLS as usize;

/// Sign bits of one slab of chunks at LOD 0: every sample row it spans, whole.
#[derive(Default)]
struct Slab {
    /// `words` per row, rows y fastest.
    bits: Vec<u64>,
    words: usize,
    /// Per band of chunks (same y), `words` each: OR and AND of its rows. A chunk is empty
    /// where they agree.
    any: Vec<u64>,
    all: Vec<u64>,
}

/// A vertex waiting for its data: volume index and chunk-local voxel of its edge's lower end.
#[derive(Clone, Copy, Default)]
struct Pending {
    at: usize,
    lower: [u8; 3],
    axis: u8,
}

/// Vertex data of one batch, computed in place (kept between batches: no zeroing).
struct Batch {
    pos: [[f32; 3]; BATCH],
    /// Unnormalised normals, `[axis][vertex]`.
    raw: [[f64; BATCH]; 3],
    /// Edge axis and whether its lower end is solid (`axis << 1 | solid`), for flat normals.
    flat: [u8; BATCH],
    normals: [[f32; 3]; BATCH],
}

/// The chunk being meshed.
#[derive(Default)]
struct Chunk {
    /// Origin in voxels and in strided samples.
    origin: [usize; 3],
    first: [usize; 3],
    /// Earlier chunk across the low face on each axis (its vertices are reused).
    below: [bool; 3],
    /// Later chunk across the high face on each axis (it reuses this one's).
    above: [bool; 3],
    /// Central differences of every vertex stay inside the volume.
    interior: bool,
    /// Index of the chunk's column (same x and y) in [`Faces::z`].
    column: usize,
    gx: usize,
    gy: usize,
    cells_x: usize,
}

struct Sweep<'a> {
    grid: VolumeGrid<'a>,
    density: &'a [u8],
    dims: [usize; 3],
    /// Index steps of the volume along x, y, z.
    steps: [usize; 3],
    /// Cells meshed per axis, in voxels.
    span: [usize; 3],
    opts: VolumeMeshOptions,
    t: Option<u8>,
    stride: usize,
    param: EdgeParam,
    faces: Faces,
    slab: Slab,
    c: Chunk,
    rows: Vec<u64>,
    slots: Box<[u32; SLOTS]>,
    cells: CellScratch,
    /// Vertices so far, pending included.
    count: u64,
    pending: [Pending; BATCH],
    npending: usize,
    batch: Batch,
    out: Mesh,
}

impl<'a> Sweep<'a> {
    fn new(grid: &VolumeGrid<'a>, opts: &VolumeMeshOptions) -> Self {
        let dims = grid.dims.map(|d| d as usize);
        let stride = 1usize << opts.lod;
        let nx = (dims[0] - 1) / stride + 1;
        let span = dims.map(|d| (d - 1) & !(stride - 1));
        let columns = span[0].div_ceil(BAND) * span[1].div_ceil(BAND);
        let t = match Threshold::new(opts.iso) {
            Threshold::Above(t) => Some(t),
            Threshold::AllSolid | Threshold::NoneSolid => None,
        };
        Self {
            grid: *grid,
            density: grid.density,
            dims,
            steps: [1, dims[0], dims[0] * dims[1]],
            span,
            opts: *opts,
            t,
            stride,
            param: EdgeParam::new(opts.iso),
            faces: Faces {
                x: vec![0; ROW * ROW * 2],
                y: vec![0; nx * ROW * 2],
                z: vec![Vec::new(); columns],
                nx,
            },
            slab: Slab::default(),
            c: Chunk::default(),
            rows: Vec::new(),
            slots: Box::new([0; SLOTS]),
            cells: CellScratch::default(),
            count: 0,
            pending: [Pending::default(); BATCH],
            npending: 0,
            batch: Batch {
                pos: [[0.0; 3]; BATCH],
                raw: [[0.0; BATCH]; 3],
                flat: [0; BATCH],
                normals: [[0.0; 3]; BATCH],
            },
            out: Mesh::default(),
        }
    }

    /// Sign bits of every sample row of the slab of `job` (slices `z..=z + ez`), 64 samples
    /// per word: whole slices are contiguous, so this reads long streams.
    fn classify(&mut self, job: &ChunkJob, t: u8) {
        let (oz, ez) = (job.origin[2] as usize, job.extent[2] as usize);
        let ([dx, dy, _], sz) = (self.dims, self.steps[2]);
        let b = &mut self.slab;
        let (words, bands) = (dx.div_ceil(64), (dy - 1).div_ceil(BAND));
        b.words = words;
        b.bits.resize((ez + 1) * dy * words, 0);
        b.any.clear();
        b.any.resize(bands * words, 0);
        b.all.clear();
        b.all.resize(bands * words, !0);
        let rows = (oz..=oz + ez).flat_map(|z| (0..dy).map(move |y| (y, z * sz + y * dx)));
        for ((y, at), bits) in rows.zip(b.bits.chunks_exact_mut(words)) {
            for (m, samples) in bits.iter_mut().zip(self.density[at..at + dx].chunks(64)) {
                *m = solid_bits(samples, t);
            }
            // Row y belongs to band y / 32 and, on a band boundary, to the one below too.
            let band = y / BAND;
            let first = band - usize::from(y % BAND == 0 && y > 0);
            for b_at in first..=band.min(bands - 1) {
                let (any, all) = (&mut b.any[b_at * words..], &mut b.all[b_at * words..]);
                for ((a, l), &m) in any.iter_mut().zip(all.iter_mut()).zip(bits.iter()) {
                    *a |= m;
                    *l &= m;
                }
            }
        }
    }

    /// Meshes one chunk; false when it has no triangles.
    fn chunk(&mut self, job: &ChunkJob) -> bool {
        let Some(t) = self.t else { return false };
        let s = self.stride;
        let origin = job.origin.map(|o| o as usize);
        let extent = job.extent.map(|e| e as usize);
        let cells = extent.map(|e| e / s);
        let [gx, gy, gz] = cells.map(|c| c + 1);
        let full = (1u64 << gx) - 1;
        self.rows.clear();
        if self.opts.lod == 0 {
            let (b, w, dy) = (&self.slab, self.slab.words, self.dims[1]);
            let cut = |words: &[u64]| bits_at(words, origin[0], gx);
            let band = origin[1] / BAND * w;
            if cut(&b.any[band..band + w]) == 0 || cut(&b.all[band..band + w]) == full {
                return false;
            }
            // This chunk's rows: rows y..=y + ey of every slice of the slab.
            self.rows.resize(gz * gy, 0);
            for (z, rows) in self.rows.chunks_exact_mut(gy).enumerate() {
                let at = (z * dy + origin[1]) * w;
                for (row, words) in rows.iter_mut().zip(b.bits[at..at + gy * w].chunks_exact(w)) {
                    *row = cut(words);
                }
            }
        } else {
            if chunk_is_empty(&self.grid, self.opts.iso, job) {
                return false;
            }
            for z in 0..gz {
                for y in 0..gy {
                    let at = self.index(origin, [0, y * s, z * s]);
                    self.rows.push(row_bits(self.density, at, s, gx, t));
                }
            }
            let any = self.rows.iter().fold(0, |a, &m| a | m);
            let all = self.rows.iter().fold(full, |a, &m| a & m);
            if any == 0 || all == full {
                return false;
            }
        }
        self.c = Chunk {
            origin,
            first: origin.map(|o| o / s),
            below: origin.map(|o| o > 0),
            above: [0, 1, 2].map(|a| origin[a] + extent[a] < self.span[a]),
            interior: (0..3).all(|a| origin[a] > 0 && origin[a] + extent[a] + 1 < self.dims[a]),
            column: origin[1] / BAND * self.span[0].div_ceil(BAND) + origin[0] / BAND,
            gx,
            gy,
            cells_x: cells[0],
        };
        let rows = std::mem::take(&mut self.rows);
        let grid = Grid {
            rows: &rows,
            gy,
            stride: s,
            cell_mask: (1u64 << cells[0]) - 1,
            full,
        };
        let start = self.out.indices.len();
        // The chunk mesher's order (`regular.rs`): vertices of layer 0, then per layer the z
        // edges above it and the x and y edges of the next, then that layer's cells.
        self.emit_xy(&grid, 0);
        for z in 0..cells[2] {
            self.emit_z(&grid, z, (z & 1) * LAYER);
            self.emit_xy(&grid, z + 1);
            let out = &mut self.out.indices;
            cell_layer(&grid, z, &self.slots, &mut self.cells.0, out);
            self.keep_faces(z, (z & 1) * LAYER);
        }
        self.keep_faces(cells[2], (cells[2] & 1) * LAYER);
        if self.c.above[2] {
            let (list, slots) = (&mut self.faces.z[self.c.column], &self.slots);
            let part = (cells[2] & 1) * LAYER;
            list.clear();
            plane_edges(&grid, cells[2], |at| {
                list.push(slots[(part + at) & (SLOTS - 1)])
            });
        }
        self.flush();
        self.rows = rows;
        self.out.indices.len() > start
    }

    #[inline]
    fn index(&self, origin: [usize; 3], local: [usize; 3]) -> usize {
        let [x, y, z] = [
            origin[0] + local[0],
            origin[1] + local[1],
            origin[2] + local[2],
        ];
        x + y * self.steps[1] + z * self.steps[2]
    }

    /// Volume index of local sample `(0, y, z)`.
    #[inline]
    fn row_at(&self, y: usize, z: usize) -> usize {
        let s = self.stride;
        self.index(self.c.origin, [0, y * s, z * s])
    }

    /// Id of a new vertex on the edge from local sample `(x, y, z)` along `axis`; `row` is
    /// [`Self::row_at`] of its row.
    #[inline]
    fn vertex(&mut self, row: usize, x: usize, y: usize, z: usize, axis: u8) -> u32 {
        if self.npending == BATCH {
            self.flush();
        }
        let id = self.count as u32;
        self.count += 1;
        let s = self.stride;
        self.pending[self.npending % BATCH] = Pending {
            at: row + x * s,
            lower: [(x * s) as u8, (y * s) as u8, (z * s) as u8],
            axis,
        };
        self.npending += 1;
        id
    }

    /// Vertices on the sign-changing x and y edges of sample layer `z`.
    fn emit_xy(&mut self, g: &Grid, z: usize) {
        let (nx, first, below) = (self.faces.nx, self.c.first, self.c.below);
        if z == 0 && below[2] {
            // All from the chunk below, in the order it listed them.
            let (list, slots) = (&self.faces.z[self.c.column], &mut self.slots);
            let mut ids = list.iter();
            plane_edges(g, 0, |at| {
                slots[at & (SLOTS - 1)] = *ids.next().expect("listed")
            });
            return;
        }
        let part = (z & 1) * LAYER;
        for y in 0..g.gy {
            let m = g.rows[z * g.gy + y];
            let row = part + y * PITCH * 3;
            let at = self.row_at(y, z);
            let mut e = (m ^ (m >> 1)) & g.cell_mask;
            while e != 0 {
                let x = e.trailing_zeros() as usize;
                e &= e - 1;
                self.slots[(row + x * 3) & (SLOTS - 1)] = if y == 0 && below[1] {
                    self.faces.y[(z * nx + first[0] + x) * 2]
                } else {
                    self.vertex(at, x, y, z, 0)
                };
            }
            if y + 1 == g.gy {
                break;
            }
            let mut e = (m ^ g.rows[z * g.gy + y + 1]) & g.full;
            if below[0] && e & 1 != 0 {
                self.slots[(row + 1) & (SLOTS - 1)] = self.faces.x[(z * g.gy + y) * 2];
                e &= !1;
            }
            while e != 0 {
                let x = e.trailing_zeros() as usize;
                e &= e - 1;
                self.slots[(row + x * 3 + 1) & (SLOTS - 1)] = self.vertex(at, x, y, z, 1);
            }
        }
    }

    /// Vertices on the sign-changing z edges from sample layer `z` (slots from `part`).
    fn emit_z(&mut self, g: &Grid, z: usize, part: usize) {
        let (nx, first, below) = (self.faces.nx, self.c.first, self.c.below);
        for y in 0..g.gy {
            let row = part + y * PITCH * 3 + 2;
            let at = self.row_at(y, z);
            let mut e = (g.rows[z * g.gy + y] ^ g.rows[(z + 1) * g.gy + y]) & g.full;
            if below[0] && e & 1 != 0 {
                self.slots[row & (SLOTS - 1)] = self.faces.x[(z * g.gy + y) * 2 + 1];
                e &= !1;
            }
            while e != 0 {
                let x = e.trailing_zeros() as usize;
                e &= e - 1;
                self.slots[(row + x * 3) & (SLOTS - 1)] = if y == 0 && below[1] {
                    self.faces.y[(z * nx + first[0] + x) * 2 + 1]
                } else {
                    self.vertex(at, x, y, z, 2)
                };
            }
        }
    }

    /// Copies the ids on this chunk's x and y high faces from the finished sample layer `z`
    /// (slots from `part`) for the later chunks across them. Only edges that start inside
    /// the chunk are written (see the module docs). Ids of edges without a sign change are
    /// stale, but nothing reads them.
    fn keep_faces(&mut self, z: usize, part: usize) {
        let c = &self.c;
        let (gx, gy, nx) = (c.gx, c.gy, self.faces.nx);
        let slot = |x: usize, y: usize, k: usize| {
            self.slots[(part + (y * PITCH + x) * 3 + k) & (SLOTS - 1)]
        };
        if c.above[0] {
            for y in 0..gy {
                self.faces.x[(z * gy + y) * 2] = slot(gx - 1, y, 1);
                self.faces.x[(z * gy + y) * 2 + 1] = slot(gx - 1, y, 2);
            }
        }
        if c.above[1] {
            let to = (z * nx + c.first[0]) * 2;
            for x in 0..c.cells_x {
                self.faces.y[to + x * 2] = slot(x, gy - 1, 0);
            }
            for x in 0..gx {
                self.faces.y[to + x * 2 + 1] = slot(x, gy - 1, 2);
            }
        }
    }

    fn flush(&mut self) {
        if self.c.interior {
            self.flush_as::<false>();
        } else {
            self.flush_as::<true>();
        }
    }

    /// Computes position, normal and material of the pending vertices as `builder.rs` and
    /// the welder do (local position in f32, then plus the chunk origin in f32). `CLAMP`:
    /// the chunk touches the volume's faces, where samples past them repeat the face sample
    /// (the chunk path's apron).
    fn flush_as<const CLAMP: bool>(&mut self) {
        let n = self.npending.min(BATCH);
        if n == 0 {
            return;
        }
        let (d, s, iso, param) = (self.density, self.stride, self.opts.iso, self.param);
        let vol = Samples {
            density: d,
            dims: self.dims,
            steps: self.steps,
        };
        let len = s as f64;
        let o = self.c.origin;
        let fo = [o[0] as f32, o[1] as f32, o[2] as f32];
        let b = &mut self.batch;
        for (j, p) in self.pending[..n].iter().enumerate() {
            let axis = usize::from(p.axis);
            let lower = [0, 1, 2].map(|k| i32::from(p.lower[k]));
            let upper_at = p.at + self.steps[axis] * s;
            let (a, c) = (d[p.at], d[upper_at]);
            let q = param.quantize(a, c);
            let along = (f64::from(lower[axis]) + f64::from(q) * len / f64::from(T_ONE)) as f32;
            // Selects, not a store at index `axis` (see `builder.rs`).
            let local = |k: usize| if k == axis { along } else { lower[k] as f32 };
            b.pos[j] = [local(0) + fo[0], local(1) + fo[1], local(2) + fo[2]];
            let inside = |k: usize| {
                let v = o[k] + usize::from(p.lower[k]);
                v > 0 && v + 1 + if k == axis { s } else { 0 } < self.dims[k]
            };
            let (g0, g1) = if !CLAMP || (inside(0) && inside(1) && inside(2)) {
                (vol.gradient(p.at), vol.gradient(upper_at))
            } else {
                let at = |k: usize| o[k] + usize::from(p.lower[k]);
                let mut v = [at(0), at(1), at(2)];
                let g0 = vol.clamped_gradient(p.at, v);
                v[axis] += s;
                (g0, vol.clamped_gradient(upper_at, v))
            };
            // `normals::raw_normal` regrouped: -(g0 (1 - t) + g1 t) = -(g0 + (g1 - g0) t),
            // exact in integers, so the same values.
            let (one, q) = (i64::from(T_ONE), i64::from(q));
            let r = |k: usize| -(i64::from(g0[k]) * one + i64::from(g1[k] - g0[k]) * q) as f64;
            b.raw[0][j] = r(0);
            b.raw[1][j] = r(1);
            b.raw[2][j] = r(2);
            b.flat[j] = p.axis << 1 | u8::from(f32::from(a) > iso);
        }
        let flat = |j: usize| fallback_normal(usize::from(b.flat[j] >> 1), b.flat[j] & 1 != 0);
        normalise(&b.raw, flat, &mut b.normals, n);
        let m = &mut self.out;
        m.positions.extend_from_slice(&b.pos[..n]);
        m.normals.extend_from_slice(&b.normals[..n]);
        m.materials
            .extend_from_slice(&[self.opts.material; BATCH][..n]);
        if self.opts.keys {
            let [x, y, z] = o.map(|v| v as i32);
            let origin = VoxelPos::new(x, y, z);
            for p in &self.pending[..n] {
                let lower = p.lower.map(i32::from);
                let axis = usize::from(p.axis);
                m.keys
                    .push(VertexKey::from_local(origin, lower, axis, s as u32));
            }
        }
        self.npending = 0;
    }
}

/// The volume's samples and shape.
#[derive(Clone, Copy)]
struct Samples<'a> {
    density: &'a [u8],
    dims: [usize; 3],
    /// Index steps along x, y, z.
    steps: [usize; 3],
}

impl Samples<'_> {
    /// Central-difference gradient at the volume sample with index `i`, inside the volume.
    #[inline(always)]
    fn gradient(&self, i: usize) -> [i32; 3] {
        let d = |j: usize| i32::from(self.density[j]);
        let [_, sy, sz] = self.steps;
        [
            d(i + 1) - d(i - 1),
            d(i + sy) - d(i - sy),
            d(i + sz) - d(i - sz),
        ]
    }

    /// [`Self::gradient`] at sample `p` (index `i`) anywhere in the volume.
    #[inline(always)]
    fn clamped_gradient(&self, i: usize, p: [usize; 3]) -> [i32; 3] {
        let g = |a: usize| {
            let step = self.steps[a];
            let up = if p[a] + 1 < self.dims[a] { i + step } else { i };
            let down = if p[a] > 0 { i - step } else { i };
            i32::from(self.density[up]) - i32::from(self.density[down])
        };
        [g(0), g(1), g(2)]
    }
}

/// Calls `f` with the slot offset (within its layer) of every sign-changing x and y edge of
/// sample layer `z`, in the order `emit_xy` visits them.
#[inline]
fn plane_edges(g: &Grid, z: usize, mut f: impl FnMut(usize)) {
    let mut each = |mut e: u64, at: usize| {
        while e != 0 {
            f(at + e.trailing_zeros() as usize * 3);
            e &= e - 1;
        }
    };
    for y in 0..g.gy {
        let m = g.rows[z * g.gy + y];
        each((m ^ (m >> 1)) & g.cell_mask, y * PITCH * 3);
        if y + 1 < g.gy {
            each((m ^ g.rows[z * g.gy + y + 1]) & g.full, y * PITCH * 3 + 1);
        }
    }
}

/// Bits `start..start + n` of a row of words (`n <= 64`).
#[inline]
fn bits_at(words: &[u64], start: usize, n: usize) -> u64 {
    let (w, shift) = (start / 64, start % 64);
    let mut m = words[w] >> shift;
    if shift != 0 {
        m |= words.get(w + 1).map_or(0, |&h| h << (64 - shift));
    }
    m & (u64::MAX >> (64 - n))
}

/// Solid bits (`density > t`) of up to 64 samples.
#[inline]
fn solid_bits(samples: &[u8], t: u8) -> u64 {
    /// Gathers bit 0 of each byte into the top byte (byte i lands on bit 56 + i).
    const GATHER: u64 = 0x0102_0408_1020_4080;
    let Ok(block) = <&[u8; 64]>::try_from(samples) else {
        return (samples.iter().enumerate()).fold(0, |m, (i, &d)| m | (u64::from(d > t) << i));
    };
    // One flag byte per sample (vectorises), then eight bytes to eight bits by a multiply.
    let mut flags = [0u8; 64];
    for (f, &d) in flags.iter_mut().zip(block) {
        *f = u8::from(d > t);
    }
    (flags.chunks_exact(8).enumerate()).fold(0, |m, (k, w)| {
        let w = u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]);
        m | (w.wrapping_mul(GATHER) >> 56) << (8 * k)
    })
}
