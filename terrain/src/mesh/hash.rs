//! The specified mesh hash: server and client compare meshes with it.
//!
//! Encoding (all little-endian), hashed with [`crate::hash::hash_bytes`] (XXH3-64, seed 0):
//!
//! 1. `u32` vertex count V, then `u32` index count I;
//! 2. V positions, each three `f32` (x, y, z) as their IEEE-754 bit patterns;
//! 3. V normals, each three `f32` the same way;
//! 4. V material bytes (`u8`);
//! 5. I indices as `u32`.
//!
//! Vertex keys are not hashed: they are welding metadata, not geometry.

use std::hash::Hasher;

use twox_hash::XxHash3_64;

use super::types::Mesh;

impl Mesh {
    /// The byte string [`Mesh::hash`] digests (see the module docs for the layout).
    pub fn hash_encoding(&self) -> Vec<u8> {
        let v = self.positions.len();
        let mut out = Vec::with_capacity(8 + v * 25 + self.indices.len() * 4);
        out.extend_from_slice(&(v as u32).to_le_bytes());
        out.extend_from_slice(&(self.indices.len() as u32).to_le_bytes());
        for p in self.positions.iter().chain(self.normals.iter()) {
            for c in p {
                out.extend_from_slice(&c.to_bits().to_le_bytes());
            }
        }
        out.extend_from_slice(&self.materials);
        for i in &self.indices {
            out.extend_from_slice(&i.to_le_bytes());
        }
        out
    }

    /// Stable specified hash (XXH3-64 of [`Mesh::hash_encoding`]); keys are NOT hashed.
    /// Streams the encoding to the hasher a block at a time instead of
    /// building it.
    pub fn hash(&self) -> u64 {
        let mut w = XxHash3_64::with_seed(0);
        w.write(&(self.positions.len() as u32).to_le_bytes());
        w.write(&(self.indices.len() as u32).to_le_bytes());
        // Encoded into `b` a block at a time, then hashed.
        const BLOCK: usize = 4080;
        let mut b = [0u8; BLOCK];
        for block in [&self.positions, &self.normals]
            .into_iter()
            .flat_map(|v| v.chunks(BLOCK / 12))
        {
            for (out, p) in b.chunks_exact_mut(12).zip(block) {
                out[0..4].copy_from_slice(&p[0].to_bits().to_le_bytes());
                out[4..8].copy_from_slice(&p[1].to_bits().to_le_bytes());
                out[8..12].copy_from_slice(&p[2].to_bits().to_le_bytes());
            }
            w.write(&b[..block.len() * 12]);
        }
        w.write(&self.materials);
        for block in self.indices.chunks(BLOCK / 4) {
            for (out, i) in b.chunks_exact_mut(4).zip(block) {
                out.copy_from_slice(&i.to_le_bytes());
            }
            w.write(&b[..block.len() * 4]);
        }
        w.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mesh of `v` vertices whose every field varies.
    fn mesh(v: usize) -> Mesh {
        let f = |i: usize, k: usize| (i * 3 + k) as f32 * 0.37 - 5.0;
        Mesh {
            positions: (0..v).map(|i| [f(i, 0), f(i, 1), f(i, 2)]).collect(),
            normals: (0..v).map(|i| [-f(i, 2), f(i, 0), -f(i, 1)]).collect(),
            materials: (0..v).map(|i| (i * 7) as u8).collect(),
            indices: (0..v * 2).map(|i| (i * 5 % v.max(1)) as u32).collect(),
            keys: Vec::new(),
        }
    }

    #[test]
    fn the_streamed_hash_is_the_hash_of_the_encoding() {
        // Empty, inside one buffer, and across many buffer boundaries.
        for v in [0, 1, 3, 100, 163, 164, 1000, 5000] {
            let m = mesh(v);
            assert_eq!(
                m.hash(),
                crate::hash::hash_bytes(&m.hash_encoding()),
                "{v} vertices"
            );
        }
    }
}
