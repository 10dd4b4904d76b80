//! Stable 64-bit hashes, specified so any process or language can recompute them.
//!
//! * Byte hash: XXH3-64 with seed 0 (the reference xxHash algorithm).
//! * Chunk hash: XXH3-64 of the 32768 density bytes followed by the 32768
//!   material bytes, both in [`crate::pos::local_index`] order (x fastest,
//!   then y, then z). A uniform chunk hashes as its expanded form.

use crate::chunk::Chunk;
use crate::pos::CHUNK_VOLUME;
use std::hash::Hasher;
use std::sync::atomic::{AtomicU64, Ordering};

use twox_hash::XxHash3_64;

/// XXH3-64 (seed 0) of a byte string.
pub fn hash_bytes(bytes: &[u8]) -> u64 {
    XxHash3_64::oneshot(bytes)
}

/// The specified hash of a chunk's voxel state.
pub fn chunk_hash(chunk: &Chunk) -> u64 {
    match chunk {
        Chunk::Dense(d) => {
            let mut h = XxHash3_64::with_seed(0);
            h.write(&d.density[..]);
            h.write(&d.material[..]);
            h.finish()
        }
        Chunk::Uniform(v) => uniform_hash(v.density, v.material),
    }
}

/// [`chunk_hash`] of uniform chunks already hashed, by `density << 8 | material`; 0 stands
/// for "not yet" (a value whose hash is 0 is just hashed each time). An edit that empties
/// a chunk hashes 64 KiB of air otherwise.
static UNIFORM_HASHES: [AtomicU64; 1 << 16] = [const { AtomicU64::new(0) }; 1 << 16];

fn uniform_hash(density: u8, material: u8) -> u64 {
    let slot = &UNIFORM_HASHES[usize::from(density) << 8 | usize::from(material)];
    match slot.load(Ordering::Relaxed) {
        0 => {
            let h = expanded_uniform_hash(density, material);
            slot.store(h, Ordering::Relaxed);
            h
        }
        h => h,
    }
}

fn expanded_uniform_hash(density: u8, material: u8) -> u64 {
    const BLOCK: usize = 4096;
    let mut h = XxHash3_64::with_seed(0);
    for value in [density, material] {
        let block = [value; BLOCK];
        for _ in 0..CHUNK_VOLUME / BLOCK {
            h.write(&block);
        }
    }
    h.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chunk::{DenseChunk, Voxel};

    #[test]
    fn uniform_and_dense_hash_alike() {
        let v = Voxel::new(255, 3);
        let dense = Chunk::Dense(DenseChunk::filled(v));
        assert_eq!(chunk_hash(&Chunk::uniform(v)), chunk_hash(&dense));
        let mut concat = vec![255u8; CHUNK_VOLUME];
        concat.extend(std::iter::repeat_n(3u8, CHUNK_VOLUME));
        assert_eq!(chunk_hash(&dense), hash_bytes(&concat));
    }

    #[test]
    fn remembered_uniform_hashes_equal_hashing_the_expanded_chunk() {
        for (d, m) in [(0, 0), (255, 3), (127, 9), (0, 0), (255, 3)] {
            let dense = Chunk::Dense(DenseChunk::filled(Voxel::new(d, m)));
            assert_eq!(
                chunk_hash(&Chunk::uniform(Voxel::new(d, m))),
                chunk_hash(&dense)
            );
            assert_eq!(uniform_hash(d, m), expanded_uniform_hash(d, m));
        }
    }

    #[test]
    fn golden_values() {
        // Pinned: the hash is part of the wire protocol.
        assert_eq!(hash_bytes(b""), 0x2d06800538d394c2);
        assert_eq!(
            chunk_hash(&Chunk::uniform(Voxel::AIR)),
            chunk_hash(&Chunk::default())
        );
        let a = chunk_hash(&Chunk::uniform(Voxel::AIR));
        let mut c = Chunk::uniform(Voxel::AIR);
        c.set(31, 31, 31, Voxel::new(1, 0));
        assert_ne!(a, chunk_hash(&c));
    }
}
