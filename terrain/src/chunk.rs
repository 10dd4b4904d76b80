//! A 32³ chunk of voxels, held compactly when it is uniform.

use crate::material::{ids, MaterialId};
use crate::pos::{local_index, CHUNK_VOLUME};

/// Density at or above which a voxel is solid (surface at 127.5).
pub const SOLID_THRESHOLD: u8 = 128;

/// One voxel: density (0 air .. 255 solid) and material.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Voxel {
    pub density: u8,
    pub material: MaterialId,
}

impl Voxel {
    pub const AIR: Voxel = Voxel {
        density: 0,
        material: ids::AIR,
    };

    pub const fn new(density: u8, material: MaterialId) -> Self {
        Self { density, material }
    }

    pub const fn solid(material: MaterialId) -> Self {
        Self {
            density: 255,
            material,
        }
    }

    #[inline]
    pub const fn is_solid(self) -> bool {
        self.density >= SOLID_THRESHOLD
    }
}

/// Separate density and material planes, indexed by [`local_index`].
#[derive(Clone, PartialEq, Eq)]
pub struct DenseChunk {
    pub density: Box<[u8; CHUNK_VOLUME]>,
    pub material: Box<[u8; CHUNK_VOLUME]>,
}

impl std::fmt::Debug for DenseChunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DenseChunk").finish_non_exhaustive()
    }
}

fn filled_plane(v: u8) -> Box<[u8; CHUNK_VOLUME]> {
    vec![v; CHUNK_VOLUME]
        .into_boxed_slice()
        .try_into()
        .expect("exact length")
}

impl DenseChunk {
    pub fn filled(v: Voxel) -> Self {
        Self {
            density: filled_plane(v.density),
            material: filled_plane(v.material),
        }
    }

    /// Builds a chunk from planes; `None` if either is not exactly 32³ bytes.
    pub fn from_planes(density: &[u8], material: &[u8]) -> Option<Self> {
        Some(Self {
            density: density.to_vec().into_boxed_slice().try_into().ok()?,
            material: material.to_vec().into_boxed_slice().try_into().ok()?,
        })
    }

    #[inline]
    pub fn get(&self, i: usize) -> Voxel {
        Voxel {
            density: self.density[i],
            material: self.material[i],
        }
    }

    #[inline]
    pub fn set(&mut self, i: usize, v: Voxel) {
        self.density[i] = v.density;
        self.material[i] = v.material;
    }

    /// The single voxel value if every voxel is equal.
    pub fn uniform_value(&self) -> Option<Voxel> {
        let v = self.get(0);
        // A surface chunk is often uniform below its surface: a few probes
        // across the planes answer it without scanning half a plane.
        let probe = |i: usize| self.density[i] == v.density && self.material[i] == v.material;
        if !UNIFORM_PROBES.iter().all(|&i| probe(i)) {
            return None;
        }
        let same =
            all_equal(&self.density[..], v.density) && all_equal(&self.material[..], v.material);
        same.then_some(v)
    }
}

/// Indices [`DenseChunk::uniform_value`] looks at before scanning: the
/// last voxel and the planes' quarter points (z = 8, 16, 24 in the middle
/// of x and y).
const UNIFORM_PROBES: [usize; 4] = [
    CHUNK_VOLUME - 1,
    CHUNK_VOLUME / 2 + CHUNK_VOLUME / 64 + 16,
    CHUNK_VOLUME / 4 + CHUNK_VOLUME / 64 + 16,
    3 * CHUNK_VOLUME / 4 + CHUNK_VOLUME / 64 + 16,
];

/// Whether every byte of `bytes` is `v`. Compares 64-byte blocks at a time
/// (a loop the compiler vectorises), stopping at the first block that
/// differs: a surface chunk differs early in one plane and not at all in
/// the other, so the whole-plane case must be fast.
pub fn all_equal(bytes: &[u8], v: u8) -> bool {
    let mut blocks = bytes.chunks_exact(64);
    for block in &mut blocks {
        let differs = block.iter().fold(0u8, |acc, &b| acc | (b ^ v));
        if differs != 0 {
            return false;
        }
    }
    blocks.remainder().iter().all(|&b| b == v)
}

/// A chunk's voxels. Most of a world is all air or all rock, so a uniform
/// chunk is one voxel value and costs a few bytes.
#[derive(Debug, Clone)]
pub enum Chunk {
    Uniform(Voxel),
    Dense(DenseChunk),
}

impl PartialEq for Chunk {
    /// Compares voxel content, whatever the representation.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Chunk::Uniform(a), Chunk::Uniform(b)) => a == b,
            (Chunk::Dense(a), Chunk::Dense(b)) => a == b,
            (Chunk::Uniform(u), Chunk::Dense(d)) | (Chunk::Dense(d), Chunk::Uniform(u)) => {
                d.uniform_value() == Some(*u)
            }
        }
    }
}
impl Eq for Chunk {}

impl Default for Chunk {
    fn default() -> Self {
        Chunk::Uniform(Voxel::AIR)
    }
}

impl Chunk {
    pub fn uniform(v: Voxel) -> Self {
        Chunk::Uniform(v)
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> Voxel {
        self.get_index(local_index(x, y, z))
    }

    #[inline]
    pub fn get_index(&self, i: usize) -> Voxel {
        match self {
            Chunk::Uniform(v) => *v,
            Chunk::Dense(d) => d.get(i),
        }
    }

    /// Sets a voxel, expanding a uniform chunk when the value differs.
    pub fn set(&mut self, x: usize, y: usize, z: usize, v: Voxel) {
        self.set_index(local_index(x, y, z), v)
    }

    pub fn set_index(&mut self, i: usize, v: Voxel) {
        if let Chunk::Uniform(u) = self {
            if *u == v {
                return;
            }
            *self = Chunk::Dense(DenseChunk::filled(*u));
        }
        if let Chunk::Dense(d) = self {
            d.set(i, v);
        }
    }

    /// Mutable dense planes, expanding a uniform chunk.
    pub fn dense_mut(&mut self) -> &mut DenseChunk {
        if let Chunk::Uniform(u) = self {
            *self = Chunk::Dense(DenseChunk::filled(*u));
        }
        match self {
            Chunk::Dense(d) => d,
            Chunk::Uniform(_) => unreachable!("expanded above"),
        }
    }

    /// Collapses to [`Chunk::Uniform`] when every voxel is equal.
    pub fn compact(&mut self) {
        if let Chunk::Dense(d) = self {
            if let Some(v) = d.uniform_value() {
                *self = Chunk::Uniform(v);
            }
        }
    }

    pub fn is_uniform(&self) -> bool {
        matches!(self, Chunk::Uniform(_))
    }

    /// Density plane, materialised (64 KiB total with materials).
    pub fn density_plane(&self) -> Box<[u8; CHUNK_VOLUME]> {
        match self {
            Chunk::Uniform(v) => filled_plane(v.density),
            Chunk::Dense(d) => d.density.clone(),
        }
    }

    /// Material plane, materialised.
    pub fn material_plane(&self) -> Box<[u8; CHUNK_VOLUME]> {
        match self {
            Chunk::Uniform(v) => filled_plane(v.material),
            Chunk::Dense(d) => d.material.clone(),
        }
    }

    /// Voxel count per material id among solid voxels.
    pub fn solid_histogram(&self) -> [u32; 256] {
        let mut h = [0u32; 256];
        match self {
            Chunk::Uniform(v) => {
                if v.is_solid() {
                    h[v.material as usize] = CHUNK_VOLUME as u32;
                }
            }
            Chunk::Dense(d) => {
                for (dn, m) in d.density.iter().zip(d.material.iter()) {
                    if *dn >= SOLID_THRESHOLD {
                        h[*m as usize] += 1;
                    }
                }
            }
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_expands_and_compacts() {
        let mut c = Chunk::uniform(Voxel::AIR);
        c.set(1, 2, 3, Voxel::AIR);
        assert!(c.is_uniform(), "setting the same value keeps it uniform");
        c.set(1, 2, 3, Voxel::solid(ids::STONE));
        assert!(!c.is_uniform());
        assert_eq!(c.get(1, 2, 3), Voxel::solid(ids::STONE));
        assert_eq!(c.get(0, 0, 0), Voxel::AIR);
        c.set(1, 2, 3, Voxel::AIR);
        assert_ne!(c, Chunk::uniform(Voxel::solid(1)));
        assert_eq!(c, Chunk::uniform(Voxel::AIR));
        c.compact();
        assert!(c.is_uniform());
    }

    #[test]
    fn solid_threshold_is_128() {
        assert!(!Voxel::new(127, 3).is_solid());
        assert!(Voxel::new(128, 3).is_solid());
        let mut c = Chunk::uniform(Voxel::new(200, ids::DIRT));
        c.set(0, 0, 0, Voxel::new(100, ids::DIRT));
        let h = c.solid_histogram();
        assert_eq!(h[ids::DIRT as usize], CHUNK_VOLUME as u32 - 1);
    }

    #[test]
    fn all_equal_sees_one_differing_byte_anywhere() {
        // Lengths around the 64-byte blocks, and every position in them.
        for len in [0, 1, 63, 64, 65, 127, 128, 200] {
            let mut bytes = vec![7u8; len];
            assert!(all_equal(&bytes, 7), "len {len}");
            for i in 0..len {
                bytes[i] = 8;
                assert!(!all_equal(&bytes, 7), "len {len}, byte {i}");
                bytes[i] = 7;
            }
        }
        let mut d = DenseChunk::filled(Voxel::new(3, ids::DIRT));
        assert_eq!(d.uniform_value(), Some(Voxel::new(3, ids::DIRT)));
        d.material[CHUNK_VOLUME - 1] = ids::STONE;
        assert_eq!(d.uniform_value(), None);
        // Every probe agreeing is not enough: the scan finds the rest.
        let mut d = DenseChunk::filled(Voxel::new(3, ids::DIRT));
        for i in [1, 4095, CHUNK_VOLUME - 2] {
            d.density[i] = 4;
            assert_eq!(d.uniform_value(), None, "density at {i}");
            d.density[i] = 3;
            d.material[i] = ids::STONE;
            assert_eq!(d.uniform_value(), None, "material at {i}");
            d.material[i] = ids::DIRT;
        }
        assert_eq!(d.uniform_value(), Some(Voxel::new(3, ids::DIRT)));
    }
}
