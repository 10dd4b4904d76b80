//! Chunk deltas: the bytes that turn one version of a chunk into a later one.
//!
//! A delta is what the server sends when a chunk changes and what a client
//! applies to the version it already holds. Edits are local (a mined sphere
//! touches a few hundred voxels of 32768), so the payload describes only the
//! bytes that changed, and both hashes make a delta applied to the wrong base
//! fail loudly instead of silently corrupting the client's copy.
//!
//! # Payload format (version 1)
//!
//! Everything a non-Rust client needs to apply a delta is specified here.
//!
//! **XOR stream.** `X` is 65536 bytes: for `i` in `0..32768`,
//! `X[i] = base.density[i] ^ target.density[i]` and
//! `X[32768 + i] = base.material[i] ^ target.material[i]`, where `i` is
//! [`crate::pos::local_index`] order (x fastest, then y, then z). A uniform
//! chunk counts as its expanded form.
//!
//! **Varint.** Unsigned LEB128: 7 value bits per byte, least significant
//! group first, high bit set on every byte but the last. At most 3 bytes
//! ([`MAX_VARINT_BYTES`]). Inside runs a value must be at most 65536; the
//! length prefix of methods 2 and 3 at most [`MAX_RUNS_LEN`].
//!
//! **Runs.** A sequence of zero or more pairs, nothing else:
//! `varint(zero_run) varint(lit_len) lit[lit_len]`. A decoder keeps a
//! position `p`, starting at 0. For each pair, `p += zero_run` (those bytes
//! of `X` are 0), then `X[p .. p + lit_len] = lit` and `p += lit_len`.
//! `lit_len` must be at least 1 and `p + lit_len` at most 65536. Every byte
//! of `X` not covered by a literal is 0. Literals may contain zero bytes: the
//! encoder keeps zero gaps of up to [`MERGE_GAP`] bytes inside a literal,
//! because splitting would cost as many bytes as it saves.
//!
//! **Payload.** One method byte, then a body:
//!
//! | method | name | body |
//! |---|---|---|
//! | `0x01` | [`METHOD_RUNS`] | the runs, raw |
//! | `0x02` | [`METHOD_RUNS_LZ4`] | `varint(n)` then one LZ4 *block* (no frame, no size prefix) that decompresses to the `n` bytes of runs |
//! | `0x03` | [`METHOD_RUNS_ZSTD`] | `varint(n)` then exactly one zstd frame that decompresses to the `n` bytes of runs; no bytes may follow the frame |
//! | `0x04` | [`METHOD_UNIFORM`] | `density:u8 material:u8`: every voxel of the target is this value; `X` is not used |
//!
//! For methods 2 and 3, `n` is between 1 and [`MAX_RUNS_LEN`] (131072); a decoder
//! must refuse larger values before decompressing (no zip bombs). An empty
//! runs body (`[0x01]` alone) means the target equals the base.
//!
//! **Applying.** Check `xxh3_64(base) == base_hash` (see [`crate::hash`]);
//! decode `X`; `target = base XOR X`; check `xxh3_64(target) ==
//! target_hash`. Any failure rejects the delta and leaves the base as it was.
//!
//! The encoder tries runs raw, with LZ4 and with zstd (level
//! [`DELTA_ZSTD_LEVEL`]) and keeps the shortest, preferring the lower method
//! byte on a tie, so the output is deterministic. A uniform target always
//! uses method 4 unless it equals the base.

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::chunk::{Chunk, DenseChunk, Voxel};
use crate::hash::chunk_hash;
use crate::pos::{ChunkPos, CHUNK_VOLUME};

/// Length of the XOR stream: the density plane then the material plane.
pub const XOR_STREAM_LEN: usize = 2 * CHUNK_VOLUME;
/// Longest varint the format allows (65536 needs 17 bits, so 3 bytes).
pub const MAX_VARINT_BYTES: usize = 3;
/// Zero gaps up to this long stay inside a literal: a split costs two varint
/// bytes, so it only pays off for longer gaps.
pub const MERGE_GAP: usize = 2;
/// Upper bound on the decoded runs length a decoder accepts. The canonical
/// encoder never exceeds `XOR_STREAM_LEN + 8` (a pair covers at least as many
/// stream bytes as it costs, apart from a few long varints), so twice the
/// stream length leaves a wide margin while still bounding decompression.
pub const MAX_RUNS_LEN: usize = 2 * XOR_STREAM_LEN;
/// zstd level for compressing runs; inputs are small, so a fast level is enough.
pub const DELTA_ZSTD_LEVEL: i32 = 3;

/// Method byte: runs stored raw.
pub const METHOD_RUNS: u8 = 0x01;
/// Method byte: runs compressed as one LZ4 block.
pub const METHOD_RUNS_LZ4: u8 = 0x02;
/// Method byte: runs compressed as one zstd frame.
pub const METHOD_RUNS_ZSTD: u8 = 0x03;
/// Method byte: the target is a uniform chunk.
pub const METHOD_UNIFORM: u8 = 0x04;

/// The change from one version of a chunk to a later one.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChunkDelta {
    pub pos: ChunkPos,
    pub from_version: u64,
    pub to_version: u64,
    /// [`chunk_hash`] of the state this delta applies to.
    pub base_hash: u64,
    /// [`chunk_hash`] of the state it produces.
    pub target_hash: u64,
    /// Method byte and body, as specified in the module docs.
    pub payload: Vec<u8>,
}

/// Why a delta could not be built or applied. Applying never changes the base.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DeltaError {
    #[error("delta must move forward: from version {from} to version {to}")]
    VersionOrder { from: u64, to: u64 },
    #[error("delta applies to base hash {expected:#018x}, but the chunk hashes to {actual:#018x}")]
    BaseMismatch { expected: u64, actual: u64 },
    #[error("delta result hashes to {actual:#018x}, expected {expected:#018x}")]
    TargetMismatch { expected: u64, actual: u64 },
    #[error("delta payload is empty (no method byte)")]
    EmptyPayload,
    #[error("unknown delta method byte {0:#04x}")]
    UnknownMethod(u8),
    #[error("delta payload truncated: {0}")]
    Truncated(&'static str),
    #[error("delta payload has {0} unexpected trailing bytes")]
    TrailingBytes(usize),
    #[error("malformed varint: {0}")]
    BadVarint(&'static str),
    #[error("varint value {value} is above its limit {max}")]
    VarintTooLarge { value: usize, max: usize },
    #[error("run literal of length 0 at stream offset {0}")]
    EmptyLiteral(usize),
    #[error(
        "runs overrun the {XOR_STREAM_LEN}-byte stream: literal of {len} bytes at offset {offset}"
    )]
    RunOverflow { offset: usize, len: usize },
    #[error("declared runs length {declared} is outside 1..={max}")]
    DeclaredLength { declared: usize, max: usize },
    #[error("decompressed runs are {actual} bytes, header declared {expected}")]
    WrongLength { expected: usize, actual: usize },
    #[error("decompression failed: {0}")]
    Decompress(String),
}

impl ChunkDelta {
    /// Builds the delta taking `base` (at `from_version`) to `target` (at `to_version`).
    pub fn encode(
        pos: ChunkPos,
        from_version: u64,
        to_version: u64,
        base: &Chunk,
        target: &Chunk,
    ) -> Result<ChunkDelta, DeltaError> {
        if to_version <= from_version {
            return Err(DeltaError::VersionOrder {
                from: from_version,
                to: to_version,
            });
        }
        let base_hash = chunk_hash(base);
        let target_hash = chunk_hash(target);
        let payload = encode_payload(base, target, base_hash == target_hash);
        Ok(ChunkDelta {
            pos,
            from_version,
            to_version,
            base_hash,
            target_hash,
            payload,
        })
    }

    /// Applies the delta to `base`, returning the compacted target chunk.
    ///
    /// Fails, returning no chunk, if `base` is not the state the delta was
    /// built from, if the payload is malformed in any way, or if the result
    /// does not hash to `target_hash`.
    pub fn apply(&self, base: &Chunk) -> Result<Chunk, DeltaError> {
        let actual = chunk_hash(base);
        if actual != self.base_hash {
            return Err(DeltaError::BaseMismatch {
                expected: self.base_hash,
                actual,
            });
        }
        let mut target = decode_payload(&self.payload, base)?;
        target.compact();
        let actual = chunk_hash(&target);
        if actual != self.target_hash {
            return Err(DeltaError::TargetMismatch {
                expected: self.target_hash,
                actual,
            });
        }
        Ok(target)
    }
}

// ---------------------------------------------------------------- encoding

fn encode_payload(base: &Chunk, target: &Chunk, same: bool) -> Vec<u8> {
    if same {
        return vec![METHOD_RUNS];
    }
    // A uniform target (in either form) needs no stream at all.
    let uniform = match target {
        Chunk::Uniform(v) => Some(*v),
        Chunk::Dense(d) => d.uniform_value(),
    };
    if let Some(v) = uniform {
        return vec![METHOD_UNIFORM, v.density, v.material];
    }
    let runs = encode_runs(&xor_stream(base, target));
    debug_assert!(runs.len() <= MAX_RUNS_LEN);

    let mut best = Vec::with_capacity(1 + runs.len());
    best.push(METHOD_RUNS);
    best.extend_from_slice(&runs);
    // Compressed candidates; a compressor error just drops that candidate.
    let lz4 = lz4_flex::block::compress(&runs);
    let zstd = zstd::bulk::compress(&runs, DELTA_ZSTD_LEVEL).ok();
    for (method, body) in [(METHOD_RUNS_LZ4, Some(lz4)), (METHOD_RUNS_ZSTD, zstd)] {
        let Some(body) = body else { continue };
        let mut candidate = Vec::with_capacity(1 + MAX_VARINT_BYTES + body.len());
        candidate.push(method);
        write_varint(&mut candidate, runs.len());
        candidate.extend_from_slice(&body);
        // Strictly shorter only: ties keep the lower method byte.
        if candidate.len() < best.len() {
            best = candidate;
        }
    }
    best
}

/// One plane, borrowed or implied by a uniform value, so a uniform chunk is
/// never expanded just to be read.
#[derive(Clone, Copy)]
enum Plane<'a> {
    Fill(u8),
    Bytes(&'a [u8]),
}

impl Plane<'_> {
    fn xor_into(self, other: Plane<'_>, out: &mut [u8]) {
        match (self, other) {
            (Plane::Fill(a), Plane::Fill(b)) => out.fill(a ^ b),
            (Plane::Fill(a), Plane::Bytes(b)) | (Plane::Bytes(b), Plane::Fill(a)) => {
                for (o, &v) in out.iter_mut().zip(b) {
                    *o = v ^ a;
                }
            }
            (Plane::Bytes(a), Plane::Bytes(b)) => {
                for ((o, &x), &y) in out.iter_mut().zip(a).zip(b) {
                    *o = x ^ y;
                }
            }
        }
    }
}

fn planes(c: &Chunk) -> [Plane<'_>; 2] {
    match c {
        Chunk::Uniform(v) => [Plane::Fill(v.density), Plane::Fill(v.material)],
        Chunk::Dense(d) => [Plane::Bytes(&d.density[..]), Plane::Bytes(&d.material[..])],
    }
}

fn xor_stream(base: &Chunk, target: &Chunk) -> Vec<u8> {
    let mut x = vec![0u8; XOR_STREAM_LEN];
    let (lo, hi) = x.split_at_mut(CHUNK_VOLUME);
    let [bd, bm] = planes(base);
    let [td, tm] = planes(target);
    bd.xor_into(td, lo);
    bm.xor_into(tm, hi);
    x
}

/// First index at or after `from` whose byte is non-zero.
fn next_nonzero(x: &[u8], from: usize) -> Option<usize> {
    let mut i = from;
    // Skip zero words 8 bytes at a time: most of a sparse stream is zero.
    while i + 8 <= x.len() {
        let word = u64::from_ne_bytes(x[i..i + 8].try_into().ok()?);
        if word != 0 {
            break;
        }
        i += 8;
    }
    x[i..].iter().position(|&b| b != 0).map(|p| i + p)
}

/// The canonical runs encoding of an XOR stream (see module docs).
fn encode_runs(x: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut pos = 0;
    while let Some(start) = next_nonzero(x, pos) {
        let mut end = start;
        loop {
            while end < x.len() && x[end] != 0 {
                end += 1;
            }
            match next_nonzero(x, end) {
                Some(next) if next - end <= MERGE_GAP => end = next,
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

fn write_varint(out: &mut Vec<u8>, mut v: usize) {
    while v >= 0x80 {
        out.push((v as u8 & 0x7f) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

// ---------------------------------------------------------------- decoding

/// Reads a varint at `*at`, advancing it; values above `max` are refused.
fn read_varint(bytes: &[u8], at: &mut usize, max: usize) -> Result<usize, DeltaError> {
    let mut v = 0usize;
    for k in 0..MAX_VARINT_BYTES {
        let Some(&b) = bytes.get(*at) else {
            return Err(DeltaError::Truncated("varint cut short"));
        };
        *at += 1;
        v |= ((b & 0x7f) as usize) << (7 * k);
        if b & 0x80 == 0 {
            if v > max {
                return Err(DeltaError::VarintTooLarge { value: v, max });
            }
            return Ok(v);
        }
    }
    Err(DeltaError::BadVarint("longer than 3 bytes"))
}

fn decode_payload(payload: &[u8], base: &Chunk) -> Result<Chunk, DeltaError> {
    let (&method, body) = payload.split_first().ok_or(DeltaError::EmptyPayload)?;
    let decompressed;
    let runs: &[u8] = match method {
        METHOD_UNIFORM => {
            return match body {
                [density, material] => Ok(Chunk::Uniform(Voxel::new(*density, *material))),
                [] | [_] => Err(DeltaError::Truncated("uniform body needs 2 bytes")),
                _ => Err(DeltaError::TrailingBytes(body.len() - 2)),
            };
        }
        METHOD_RUNS => body,
        METHOD_RUNS_LZ4 | METHOD_RUNS_ZSTD => {
            let mut at = 0;
            let declared = read_varint(body, &mut at, MAX_RUNS_LEN)?;
            if declared == 0 || declared > MAX_RUNS_LEN {
                return Err(DeltaError::DeclaredLength {
                    declared,
                    max: MAX_RUNS_LEN,
                });
            }
            let data = &body[at..];
            decompressed = if method == METHOD_RUNS_LZ4 {
                // The output buffer is exactly `declared` bytes: a block that
                // would write more is an error, not an allocation.
                lz4_flex::block::decompress(data, declared)
                    .map_err(|e| DeltaError::Decompress(e.to_string()))?
            } else {
                zstd_one_frame(data, declared)?
            };
            if decompressed.len() != declared {
                return Err(DeltaError::WrongLength {
                    expected: declared,
                    actual: decompressed.len(),
                });
            }
            &decompressed
        }
        other => return Err(DeltaError::UnknownMethod(other)),
    };
    apply_runs(runs, base)
}

/// Decompresses exactly one zstd frame into at most `capacity` bytes.
fn zstd_one_frame(data: &[u8], capacity: usize) -> Result<Vec<u8>, DeltaError> {
    let frame_len = zstd::zstd_safe::find_frame_compressed_size(data)
        .map_err(|code| DeltaError::Decompress(zstd::zstd_safe::get_error_name(code).into()))?;
    if frame_len != data.len() {
        return Err(DeltaError::TrailingBytes(data.len() - frame_len));
    }
    zstd::bulk::decompress(data, capacity).map_err(|e| DeltaError::Decompress(e.to_string()))
}

/// `base XOR runs`, as a fresh dense chunk. The base is only read.
fn apply_runs(runs: &[u8], base: &Chunk) -> Result<Chunk, DeltaError> {
    if runs.is_empty() {
        return Ok(base.clone());
    }
    let mut out = match base {
        Chunk::Dense(d) => d.clone(),
        Chunk::Uniform(v) => DenseChunk::filled(*v),
    };
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
        xor_literal(&mut out, offset, lit);
        offset += len;
    }
    Ok(Chunk::Dense(out))
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
    use crate::material::ids;
    use crate::pos::local_index;

    const POS: ChunkPos = ChunkPos::new(1, -2, 3);

    fn stone() -> Chunk {
        Chunk::uniform(Voxel::solid(ids::STONE))
    }

    /// A delta with a hand-written payload, for decoder tests.
    fn with_payload(base: &Chunk, target: &Chunk, payload: Vec<u8>) -> ChunkDelta {
        ChunkDelta {
            pos: POS,
            from_version: 1,
            to_version: 2,
            base_hash: chunk_hash(base),
            target_hash: chunk_hash(target),
            payload,
        }
    }

    #[test]
    fn versions_must_increase() {
        let e = ChunkDelta::encode(POS, 5, 5, &stone(), &stone()).unwrap_err();
        assert_eq!(e, DeltaError::VersionOrder { from: 5, to: 5 });
        assert!(ChunkDelta::encode(POS, 5, 4, &stone(), &stone()).is_err());
    }

    #[test]
    fn golden_single_voxel_payload() {
        // Pinned bytes: the format is a wire protocol for non-Rust clients.
        let base = stone();
        let mut target = base.clone();
        target.set(5, 0, 0, Voxel::new(0xf0, ids::STONE));
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        // zero_run 5, literal of 1 byte: 0xff ^ 0xf0.
        assert_eq!(d.payload, vec![METHOD_RUNS, 5, 1, 0x0f]);
        assert_eq!(d.apply(&base).unwrap(), target);

        // A material change at voxel 200 sits at stream offset 32768 + 200 =
        // 32968 = varint [0xc8, 0x81, 0x02].
        let mut target = base.clone();
        target.set_index(200, Voxel::solid(ids::ORE));
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert_eq!(
            d.payload,
            vec![METHOD_RUNS, 0xc8, 0x81, 0x02, 1, ids::STONE ^ ids::ORE]
        );
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn short_zero_gaps_stay_inside_literals() {
        let base = Chunk::uniform(Voxel::AIR);
        let mut target = base.clone();
        for i in [0, 3, 7] {
            target.set_index(i, Voxel::new(9, 0));
        }
        // Gaps of 2 (1..3) and 3 (4..7): the first merges, the second splits.
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert_eq!(d.payload, vec![METHOD_RUNS, 0, 4, 9, 0, 0, 9, 3, 1, 9]);
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn literal_straddling_the_planes_round_trips() {
        let base = stone();
        let mut target = base.clone();
        target.set_index(CHUNK_VOLUME - 1, Voxel::new(7, ids::STONE));
        target.set_index(0, Voxel::new(255, 9));
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert_eq!(d.apply(&base).unwrap(), target);
        // The last density byte (offset 32767 = varint ff ff 01) and the
        // first material byte are adjacent in the stream: one literal.
        assert_eq!(
            d.payload,
            vec![METHOD_RUNS, 0xff, 0xff, 0x01, 2, 0xff ^ 7, ids::STONE ^ 9]
        );
    }

    #[test]
    fn unchanged_chunk_is_one_byte() {
        let d = ChunkDelta::encode(POS, 3, 9, &stone(), &stone()).unwrap();
        assert_eq!(d.payload, vec![METHOD_RUNS]);
        assert_eq!(d.base_hash, d.target_hash);
        assert_eq!(d.apply(&stone()).unwrap(), stone());
    }

    #[test]
    fn uniform_target_is_three_bytes_and_stays_uniform() {
        let mut base = stone();
        base.set(1, 2, 3, Voxel::AIR);
        let target = Chunk::uniform(Voxel::AIR);
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert_eq!(d.payload, vec![METHOD_UNIFORM, 0, ids::AIR]);
        let out = d.apply(&base).unwrap();
        assert!(out.is_uniform());
        assert_eq!(out, target);
    }

    #[test]
    fn dense_result_that_is_uniform_comes_back_compacted() {
        // A target given as a dense-but-uniform chunk still encodes and
        // applies to a compact uniform chunk.
        let base = stone();
        let mut target = Chunk::Dense(DenseChunk::filled(Voxel::AIR));
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        let out = d.apply(&base).unwrap();
        assert!(out.is_uniform());
        target.compact();
        assert_eq!(out, target);
    }

    #[test]
    fn large_change_picks_a_compressed_method() {
        let base = Chunk::uniform(Voxel::AIR);
        let mut target = base.clone();
        for i in 0..CHUNK_VOLUME / 2 {
            target.set_index(i, Voxel::new((i % 7) as u8 + 1, ids::DIRT));
        }
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert!(matches!(d.payload[0], METHOD_RUNS_LZ4 | METHOD_RUNS_ZSTD));
        assert!(
            d.payload.len() < 1000,
            "periodic data compresses: {}",
            d.payload.len()
        );
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn wrong_base_is_rejected_before_decoding() {
        let base = stone();
        let mut target = base.clone();
        target.set(4, 4, 4, Voxel::AIR);
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        let wrong = Chunk::uniform(Voxel::AIR);
        let e = d.apply(&wrong).unwrap_err();
        assert_eq!(
            e,
            DeltaError::BaseMismatch {
                expected: chunk_hash(&base),
                actual: chunk_hash(&wrong)
            }
        );
    }

    #[test]
    fn target_hash_is_checked() {
        let base = stone();
        let mut target = base.clone();
        target.set(4, 4, 4, Voxel::AIR);
        let mut d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        d.target_hash ^= 1;
        assert!(matches!(
            d.apply(&base),
            Err(DeltaError::TargetMismatch { .. })
        ));
    }

    #[test]
    fn malformed_payloads_give_typed_errors() {
        let base = stone();
        let target = Chunk::uniform(Voxel::AIR);
        let err = |payload: Vec<u8>| {
            with_payload(&base, &target, payload)
                .apply(&base)
                .unwrap_err()
        };

        assert_eq!(err(vec![]), DeltaError::EmptyPayload);
        assert_eq!(err(vec![0x00]), DeltaError::UnknownMethod(0));
        assert_eq!(err(vec![0x09, 1, 2]), DeltaError::UnknownMethod(9));
        assert!(matches!(
            err(vec![METHOD_UNIFORM, 0]),
            DeltaError::Truncated(_)
        ));
        assert_eq!(
            err(vec![METHOD_UNIFORM, 0, 0, 0]),
            DeltaError::TrailingBytes(1)
        );
        assert!(matches!(
            err(vec![METHOD_RUNS, 0x80]),
            DeltaError::Truncated(_)
        ));
        assert!(matches!(
            err(vec![METHOD_RUNS, 0x80, 0x80, 0x80, 0x01]),
            DeltaError::BadVarint(_)
        ));
        // 0x84 0x80 0x04 = 65540 > 65536.
        assert_eq!(
            err(vec![METHOD_RUNS, 0x84, 0x80, 0x04, 1, 0]),
            DeltaError::VarintTooLarge {
                value: 65540,
                max: XOR_STREAM_LEN
            }
        );
        assert_eq!(err(vec![METHOD_RUNS, 3, 0]), DeltaError::EmptyLiteral(3));
        assert!(matches!(
            err(vec![METHOD_RUNS, 0, 2, 1]),
            DeltaError::Truncated(_)
        ));
        // zero_run 65535, then a 2-byte literal: one byte past the end.
        assert_eq!(
            err(vec![METHOD_RUNS, 0xff, 0xff, 0x03, 2, 1, 1]),
            DeltaError::RunOverflow {
                offset: 65535,
                len: 2
            }
        );
        assert_eq!(
            err(vec![METHOD_RUNS_LZ4, 0]),
            DeltaError::DeclaredLength {
                declared: 0,
                max: MAX_RUNS_LEN
            }
        );
        assert!(matches!(
            err(vec![METHOD_RUNS_LZ4, 4, 0xff, 0xff]),
            DeltaError::Decompress(_)
        ));
        assert!(matches!(
            err(vec![METHOD_RUNS_ZSTD, 4, 1, 2, 3]),
            DeltaError::Decompress(_)
        ));

        // A declared length that disagrees with the compressed data.
        let runs = [0u8, 1, 7];
        let mut p = vec![METHOD_RUNS_LZ4, 5];
        p.extend(lz4_flex::block::compress(&runs));
        assert_eq!(
            err(p),
            DeltaError::WrongLength {
                expected: 5,
                actual: 3
            }
        );
        let mut p = vec![METHOD_RUNS_ZSTD, 2];
        p.extend(zstd::bulk::compress(&runs, 3).unwrap());
        assert!(
            matches!(err(p), DeltaError::Decompress(_)),
            "output larger than declared"
        );

        // Bytes after the zstd frame.
        let mut p = vec![METHOD_RUNS_ZSTD, 3];
        p.extend(zstd::bulk::compress(&runs, 3).unwrap());
        p.push(0);
        assert_eq!(err(p), DeltaError::TrailingBytes(1));
    }

    #[test]
    fn compressed_bombs_are_refused_without_expanding() {
        let base = stone();
        // A runs stream far longer than any valid one.
        let huge = vec![0x7fu8; 4 * MAX_RUNS_LEN];
        let z = zstd::bulk::compress(&huge, 3).unwrap();
        let mut p = vec![METHOD_RUNS_ZSTD];
        write_varint(&mut p, MAX_RUNS_LEN);
        p.extend(&z);
        let e = with_payload(&base, &base, p).apply(&base).unwrap_err();
        assert!(matches!(e, DeltaError::Decompress(_)), "{e}");

        let mut p = vec![METHOD_RUNS_LZ4];
        write_varint(&mut p, MAX_RUNS_LEN + 1);
        p.extend(lz4_flex::block::compress(&huge));
        let e = with_payload(&base, &base, p).apply(&base).unwrap_err();
        assert_eq!(
            e,
            DeltaError::VarintTooLarge {
                value: MAX_RUNS_LEN + 1,
                max: MAX_RUNS_LEN
            }
        );
    }

    #[test]
    fn worst_case_runs_stay_under_the_bound() {
        // Alternating patterns that defeat merging, and a full rewrite.
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
    fn varints_round_trip_at_the_limits() {
        for v in [
            0usize,
            1,
            127,
            128,
            16383,
            16384,
            65535,
            65536,
            MAX_RUNS_LEN,
        ] {
            let mut buf = Vec::new();
            write_varint(&mut buf, v);
            assert!(buf.len() <= MAX_VARINT_BYTES);
            let mut at = 0;
            assert_eq!(read_varint(&buf, &mut at, MAX_RUNS_LEN), Ok(v));
            assert_eq!(at, buf.len());
        }
    }

    #[test]
    fn uniform_base_is_read_without_expansion_errors() {
        // Base uniform, target dense: the XOR against a fill value.
        let base = Chunk::uniform(Voxel::new(200, ids::DIRT));
        let mut target = base.clone();
        target.set(31, 31, 31, Voxel::AIR);
        target.set(0, 31, 0, Voxel::new(201, ids::GRASS));
        let d = ChunkDelta::encode(POS, 0, 1, &base, &target).unwrap();
        assert_eq!(d.apply(&base).unwrap(), target);
        assert_eq!(
            d.apply(&base).unwrap().get_index(local_index(31, 31, 31)),
            Voxel::AIR
        );
    }
}
