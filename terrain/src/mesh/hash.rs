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
    pub fn hash(&self) -> u64 {
        crate::hash::hash_bytes(&self.hash_encoding())
    }
}
