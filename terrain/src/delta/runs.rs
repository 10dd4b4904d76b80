//! The runs layout: (zero run, literal run) pairs over the XOR stream.
//! Good for scattered or very large changes; see the module docs of
//! [`crate::delta`] for the exact bytes.

use super::stream::{next_nonzero, XOR_STREAM_LEN};
use super::varint::{read_varint, write_varint, MAX_VARINT_BYTES};
use super::DeltaError;
use crate::chunk::DenseChunk;
use crate::pos::CHUNK_VOLUME;

/// Zero gaps up to this long stay inside a literal: a split costs two varint
/// bytes, so it only pays off for longer gaps.
pub const MERGE_GAP: usize = 2;

/// The canonical runs encoding of an XOR stream.
pub(super) fn encode_runs(x: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut pos = 0;
    // Each zero gap is scanned once: the search that ends a literal finds
    // the next one's start.
    let mut next = next_nonzero(x, 0);
    while let Some(start) = next {
        let mut end = start;
        loop {
            while end < x.len() && x[end] != 0 {
                end += 1;
            }
            next = next_nonzero(x, end);
            match next {
                Some(n) if n - end <= MERGE_GAP => end = n,
                _ => break,
            }
        }
        write_varint(&mut out, start - pos);
        write_varint(&mut out, end - start);
        out.extend_from_slice(&x[start..end]);
        pos = end;
    }
    out
}

/// [`encode_runs`] of a stream given by its non-zero bytes: `(index,
/// byte)` in increasing index order. The same bytes, without the stream.
pub(super) fn encode_runs_sparse(nonzero: impl Iterator<Item = (usize, u8)>) -> Vec<u8> {
    // Sized for the bytes listed (gaps merged into literals may add more).
    let listed = nonzero.size_hint().0;
    let mut out = Vec::with_capacity(listed + 2 * MAX_VARINT_BYTES);
    let mut pos = 0;
    // The open literal: it starts at `start`, its last byte is `end - 1`.
    let (mut start, mut end) = (0, 0);
    let mut literal: Vec<u8> = Vec::with_capacity(listed);
    for (i, byte) in nonzero {
        if !literal.is_empty() && i - end <= MERGE_GAP {
            literal.resize(literal.len() + (i - end), 0);
        } else {
            write_literal(&mut out, &mut pos, start, &literal);
            literal.clear();
            start = i;
        }
        literal.push(byte);
        end = i + 1;
    }
    write_literal(&mut out, &mut pos, start, &literal);
    out
}

/// Appends one (zero run, literal) pair unless `literal` is empty.
fn write_literal(out: &mut Vec<u8>, pos: &mut usize, start: usize, literal: &[u8]) {
    if literal.is_empty() {
        return;
    }
    write_varint(out, start - *pos);
    write_varint(out, literal.len());
    out.extend_from_slice(literal);
    *pos = start + literal.len();
}

/// XORs the runs into `out` (a copy of the base). On error `out` is
/// partly written; callers discard it.
pub(super) fn apply_runs(runs: &[u8], out: &mut DenseChunk) -> Result<(), DeltaError> {
    let mut at = 0;
    let mut offset = 0usize;
    while at < runs.len() {
        offset += read_varint(runs, &mut at, XOR_STREAM_LEN)?;
        let len = read_varint(runs, &mut at, XOR_STREAM_LEN)?;
        if len == 0 {
            return Err(DeltaError::EmptyLiteral(offset));
        }
        if offset + len > XOR_STREAM_LEN {
            return Err(DeltaError::RunOverflow { offset, len });
        }
        let lit = runs
            .get(at..at + len)
            .ok_or(DeltaError::Truncated("literal shorter than its length"))?;
        at += len;
        xor_literal(out, offset, lit);
        offset += len;
    }
    Ok(())
}

/// XORs `lit` into the stream at `offset`, which may straddle the planes.
/// The caller has checked `offset + lit.len() <= XOR_STREAM_LEN`.
fn xor_literal(d: &mut DenseChunk, offset: usize, lit: &[u8]) {
    let (to_density, to_material) =
        lit.split_at(CHUNK_VOLUME.saturating_sub(offset).min(lit.len()));
    if !to_density.is_empty() {
        xor_slice(
            &mut d.density[offset..offset + to_density.len()],
            to_density,
        );
    }
    if !to_material.is_empty() {
        let start = offset + to_density.len() - CHUNK_VOLUME;
        xor_slice(
            &mut d.material[start..start + to_material.len()],
            to_material,
        );
    }
}

fn xor_slice(out: &mut [u8], bytes: &[u8]) {
    for (o, &b) in out.iter_mut().zip(bytes) {
        *o ^= b;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chunk::Voxel;

    #[test]
    fn short_zero_gaps_stay_inside_literals() {
        let mut x = vec![0u8; XOR_STREAM_LEN];
        for i in [0, 3, 7] {
            x[i] = 9;
        }
        // Gaps of 2 (1..3) and 3 (4..7): the first merges, the second splits.
        assert_eq!(encode_runs(&x), vec![0, 4, 9, 0, 0, 9, 3, 1, 9]);
    }

    #[test]
    fn worst_case_runs_stay_under_the_stream_length_plus_8() {
        // Patterns that defeat merging, and a full rewrite.
        for period in [1usize, 2, 3, 4, 5, 200, 16385] {
            let x: Vec<u8> = (0..XOR_STREAM_LEN)
                .map(|i| u8::from(i % period == 0))
                .collect();
            let runs = encode_runs(&x);
            assert!(
                runs.len() <= XOR_STREAM_LEN + 8,
                "period {period}: {}",
                runs.len()
            );
        }
        let full = vec![0xa5u8; XOR_STREAM_LEN];
        assert_eq!(encode_runs(&full).len(), XOR_STREAM_LEN + 4);
    }

    #[test]
    fn runs_round_trip_across_the_plane_boundary() {
        let mut x = vec![0u8; XOR_STREAM_LEN];
        x[CHUNK_VOLUME - 2..CHUNK_VOLUME + 3].copy_from_slice(&[1, 2, 3, 4, 5]);
        x[XOR_STREAM_LEN - 1] = 6;
        let runs = encode_runs(&x);
        let mut d = DenseChunk::filled(Voxel::AIR);
        apply_runs(&runs, &mut d).unwrap();
        assert_eq!(&d.density[CHUNK_VOLUME - 2..], &[1, 2]);
        assert_eq!(&d.material[..4], &[3, 4, 5, 0]);
        assert_eq!(d.material[CHUNK_VOLUME - 1], 6);
    }

    #[test]
    fn malformed_runs_give_typed_errors() {
        let mut d = DenseChunk::filled(Voxel::AIR);
        assert_eq!(
            apply_runs(&[3, 0], &mut d),
            Err(DeltaError::EmptyLiteral(3))
        );
        assert!(matches!(
            apply_runs(&[0, 2, 1], &mut d),
            Err(DeltaError::Truncated(_))
        ));
        assert!(matches!(
            apply_runs(&[0x80], &mut d),
            Err(DeltaError::Truncated(_))
        ));
        // zero_run 65535, then a 2-byte literal: one byte past the end.
        assert_eq!(
            apply_runs(&[0xff, 0xff, 0x03, 2, 1, 1], &mut d),
            Err(DeltaError::RunOverflow {
                offset: 65535,
                len: 2
            })
        );
        // Two zero runs of 65536 add up past the end.
        assert!(matches!(
            apply_runs(&[0x80, 0x80, 0x04, 1, 1, 0x80, 0x80, 0x04, 1, 1], &mut d),
            Err(DeltaError::RunOverflow { .. })
        ));
    }
}
