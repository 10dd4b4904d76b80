//! The XOR stream of two chunks, and plane access that never expands a
//! uniform chunk just to read it.

use crate::chunk::{Chunk, DenseChunk};
use crate::pos::CHUNK_VOLUME;

/// Length of the XOR stream: the density plane then the material plane.
pub const XOR_STREAM_LEN: usize = 2 * CHUNK_VOLUME;

/// One plane, borrowed or implied by a uniform value.
#[derive(Clone, Copy)]
pub(super) enum Plane<'a> {
    Fill(u8),
    Bytes(&'a [u8]),
}

impl Plane<'_> {
    #[inline]
    pub(super) fn get(self, i: usize) -> u8 {
        match self {
            Plane::Fill(v) => v,
            Plane::Bytes(b) => b[i],
        }
    }

    /// Appends `self XOR other` (one plane) to `out`.
    fn xor_onto(self, other: Plane<'_>, out: &mut Vec<u8>) {
        match (self, other) {
            (Plane::Fill(a), Plane::Fill(b)) => out.resize(out.len() + CHUNK_VOLUME, a ^ b),
            (Plane::Fill(a), Plane::Bytes(b)) | (Plane::Bytes(b), Plane::Fill(a)) => {
                out.extend(b.iter().map(|&v| v ^ a));
            }
            (Plane::Bytes(a), Plane::Bytes(b)) => {
                out.extend(a.iter().zip(b).map(|(&x, &y)| x ^ y));
            }
        }
    }
}

/// Density and material planes of a chunk.
pub(super) fn planes(c: &Chunk) -> [Plane<'_>; 2] {
    match c {
        Chunk::Uniform(v) => [Plane::Fill(v.density), Plane::Fill(v.material)],
        Chunk::Dense(d) => [Plane::Bytes(&d.density[..]), Plane::Bytes(&d.material[..])],
    }
}

/// `base XOR target`, density plane then material plane.
pub(super) fn xor_stream(base: &Chunk, target: &Chunk) -> Vec<u8> {
    // Written once, never zeroed first.
    let mut x = Vec::with_capacity(XOR_STREAM_LEN);
    let [bd, bm] = planes(base);
    let [td, tm] = planes(target);
    bd.xor_onto(td, &mut x);
    bm.xor_onto(tm, &mut x);
    debug_assert_eq!(x.len(), XOR_STREAM_LEN);
    x
}

/// First index at or after `from` whose byte is non-zero.
pub(super) fn next_nonzero(x: &[u8], from: usize) -> Option<usize> {
    let mut i = from;
    // Skip zero blocks 32 bytes at a time (a vectorised OR), then zero
    // words: most of a sparse stream is zero.
    while let Some(block) = x.get(i..i + 32) {
        if block.iter().fold(0u8, |acc, &b| acc | b) != 0 {
            break;
        }
        i += 32;
    }
    while let Some(word) = x.get(i..i + 8) {
        let w = u64::from_le_bytes(word.try_into().expect("8 bytes"));
        if w != 0 {
            return Some(i + (w.trailing_zeros() / 8) as usize);
        }
        i += 8;
    }
    x.get(i..)?.iter().position(|&b| b != 0).map(|p| i + p)
}

/// A writable copy of the base to decode into.
pub(super) fn dense_copy(base: &Chunk) -> DenseChunk {
    match base {
        Chunk::Dense(d) => d.clone(),
        Chunk::Uniform(v) => DenseChunk::filled(*v),
    }
}

/// Mutable plane `p` (0 density, 1 material).
pub(super) fn plane_mut(d: &mut DenseChunk, p: usize) -> &mut [u8; CHUNK_VOLUME] {
    if p == 0 {
        &mut d.density
    } else {
        &mut d.material
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chunk::Voxel;

    #[test]
    fn next_nonzero_finds_every_position() {
        let mut x = vec![0u8; 100];
        assert_eq!(next_nonzero(&x, 0), None);
        for i in [0, 7, 8, 63, 99] {
            x[i] = 1;
            assert_eq!(next_nonzero(&x, 0), Some(i));
            assert_eq!(next_nonzero(&x, i + 1), None);
            x[i] = 0;
        }
        assert_eq!(next_nonzero(&x, 100), None);
        assert_eq!(next_nonzero(&x, 200), None);
    }

    #[test]
    fn xor_of_uniform_and_dense() {
        let a = Chunk::uniform(Voxel::new(0xf0, 3));
        let mut b = a.clone();
        b.set_index(5, Voxel::new(0x0f, 3));
        let x = xor_stream(&a, &b);
        assert_eq!(x[5], 0xff);
        assert_eq!(x.iter().filter(|&&v| v != 0).count(), 1);
        assert_eq!(xor_stream(&b, &a), x);
    }
}
