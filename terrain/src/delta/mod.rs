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
//! All multi-byte integers are varints; there are no fixed-width integers.
//!
//! **Planes and the XOR stream.** A chunk has a density plane and a material
//! plane of 32768 bytes each, indexed by [`crate::pos::local_index`]:
//! `i = x + 32*y + 1024*z` (x fastest, then y, then z). A uniform chunk
//! counts as its expanded form. `X` is 65536 bytes: `X[i] = base.density[i]
//! ^ target.density[i]` and `X[32768 + i] = base.material[i] ^
//! target.material[i]`.
//!
//! **Varint.** Unsigned LEB128: 7 value bits per byte, least significant
//! group first, high bit set on every byte but the last; at most
//! [`MAX_VARINT_BYTES`] (3) bytes. Each varint has a maximum value, given
//! where it is used; larger values are an error.
//!
//! **Method byte.** A payload is one method byte and a body. The high
//! nibble is the layout, the low nibble the compression:
//!
//! | method | layout | compression |
//! |---|---|---|
//! | `0x00` / `0x01` / `0x02` | runs | none / LZ4 / zstd |
//! | `0x10` / `0x11` / `0x12` | masked | none / LZ4 / zstd |
//! | `0x20` | uniform | none |
//!
//! **Compression.** With compression *none* the body is the layout body
//! itself. Otherwise the body is `varint(n)` (1 <= n <= [`MAX_BODY_LEN`] =
//! 131072) followed by the compressed layout body, which must decompress to
//! exactly `n` bytes: for LZ4, one raw LZ4 *block* (no frame, no size
//! prefix; e.g. Python `lz4.block.decompress(data, uncompressed_size=n)`);
//! for zstd, exactly one zstd frame with nothing after it. A decoder must
//! refuse `n` above the limit before decompressing, and must not produce
//! more than `n` bytes (no zip bombs).
//!
//! **Runs layout** (XOR, good for scattered or huge changes): zero or more
//! pairs `varint(zero_run) varint(lit_len) lit[lit_len]`, both varints at
//! most 65536. A decoder keeps a position `p` from 0. For each pair, `p +=
//! zero_run` (those bytes of `X` are 0), then `X[p .. p + lit_len] = lit` and
//! `p += lit_len`; `lit_len` must be at least 1 and `p + lit_len` at most
//! 65536. Bytes of `X` not covered by a literal are 0; `target = base XOR X`.
//! Literals may contain zeros: the encoder keeps zero gaps of up to
//! [`MERGE_GAP`] bytes inside a literal. An empty body means no change.
//!
//! **Masked layout** (compact shapes such as mined spheres): a section for
//! the density plane, then one for the material plane, then nothing.
//! A section is `op:u8`, and unless `op` is 0 (plane unchanged, nothing
//! follows): `x0 y0 z0 x1 y1 z1` (u8 each, `0..=31`, `x0 <= x1`, `y0 <= y1`,
//! `z0 <= z1`), the inclusive box of changed voxels; then a bitmask of
//! `ceil(V / 8)` bytes, `V` the box volume, where the `k`-th voxel of the box
//! (x fastest, then y, then z) is bit `k % 8` (1 = least significant) of mask
//! byte `k / 8`, and the unused high bits of the last byte are 0; then one
//! value byte per set bit, in the same order. For each set bit, with `old`
//! the base byte of that plane: op 1 (replace) `new = value`; op 2 (XOR)
//! `new = old ^ value`; op 3 (add) `new = (old + value) mod 256`. Bytes
//! without a set bit keep the base value. The encoder marks exactly the
//! changed bytes and picks, per plane, the op whose value sequence has the
//! fewest changes between neighbours (ties: lowest op).
//!
//! **Uniform layout**: body `density:u8 material:u8`; every voxel of the
//! target has this value, whatever the base.
//!
//! **Applying.** Check `chunk_hash(base) == base_hash` (XXH3-64 of density
//! then material plane, see [`crate::hash`]); decode; check
//! `chunk_hash(target) == target_hash`. Any failure rejects the delta and
//! leaves the base as it was.
//!
//! **Encoder choice.** An unchanged chunk is `[0x00]`; a uniform target is
//! method `0x20`. Otherwise the encoder builds the runs and the masked body,
//! tries each raw and with LZ4, and the one whose LZ4 block is shorter (runs
//! on a tie) also with zstd level [`DELTA_ZSTD_LEVEL`] when it has at least
//! [`DELTA_ZSTD_MIN_BODY`] bytes; it keeps the shortest payload, the lower
//! method byte on a tie, so its output is deterministic. Decoders accept any
//! valid payload, chosen or not.
//!
//! **Two ways to the same bytes.** [`ChunkDelta::encode`] diffs the two
//! chunks through the 64 KB XOR stream. [`ChunkDelta::encode_changed`]
//! builds the same bodies from the list of voxels an edit changed (which
//! [`crate::edit::Edit::apply`] records), without the stream or its scans;
//! the server encodes each edit's deltas this way. Tests hold the two
//! equal byte for byte, and debug builds check every such encode.

mod masked;
mod runs;
mod stream;
mod varint;

pub use masked::{MAX_MASKED_LEN, OP_ADD, OP_KEEP, OP_REPLACE, OP_XOR};
pub use runs::MERGE_GAP;
pub use stream::XOR_STREAM_LEN;
pub use varint::MAX_VARINT_BYTES;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::chunk::{Chunk, Voxel};
use crate::hash::chunk_hash;
use crate::pos::{ChunkPos, CHUNK_VOLUME};
use masked::{apply_masked, encode_masked, encode_masked_sparse};
use runs::{apply_runs, encode_runs, encode_runs_sparse};
use stream::{dense_copy, planes, xor_stream};
use varint::{read_varint, write_varint};

/// Largest decompressed layout body a decoder accepts: above both the
/// longest canonical runs body (65536 + 8) and [`MAX_MASKED_LEN`].
pub const MAX_BODY_LEN: usize = 2 * XOR_STREAM_LEN;
/// zstd level for delta bodies; they are small, so a fast level is enough.
pub const DELTA_ZSTD_LEVEL: i32 = 3;
/// Shortest body the encoder tries zstd on. Below it zstd's frame and
/// table headers cost about what it saves, and building its tables is
/// most of an edit's encoding time.
pub const DELTA_ZSTD_MIN_BODY: usize = 64;

/// Layout nibble: (zero run, literal) pairs over the XOR stream.
pub const LAYOUT_RUNS: u8 = 0x00;
/// Layout nibble: per-plane box, bitmask and values.
pub const LAYOUT_MASKED: u8 = 0x10;
/// Layout nibble: the target is one voxel value.
pub const LAYOUT_UNIFORM: u8 = 0x20;
/// Compression nibble: none.
pub const COMPRESSION_NONE: u8 = 0x00;
/// Compression nibble: one LZ4 block.
pub const COMPRESSION_LZ4: u8 = 0x01;
/// Compression nibble: one zstd frame.
pub const COMPRESSION_ZSTD: u8 = 0x02;

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
    #[error("unknown masked section op {0}")]
    UnknownOp(u8),
    #[error("masked section box {0:?} is not inside 0..=31 with min <= max")]
    BadBox([u8; 6]),
    #[error("masked section mask sets bits past the end of its box")]
    MaskPadding,
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
        Self::encode_from_hash(
            pos,
            from_version,
            to_version,
            base,
            chunk_hash(base),
            target,
        )
    }

    /// [`Self::encode`] for a caller that knows `base` hashes to
    /// `base_hash` (the previous delta's `target_hash` for that chunk):
    /// skips hashing the base again. A wrong `base_hash` makes a delta no
    /// client can apply, so only pass one computed from this very chunk.
    pub fn encode_from_hash(
        pos: ChunkPos,
        from_version: u64,
        to_version: u64,
        base: &Chunk,
        base_hash: u64,
        target: &Chunk,
    ) -> Result<ChunkDelta, DeltaError> {
        let versions = (from_version, to_version);
        Self::build(pos, versions, base, base_hash, target, None)
    }

    /// [`Self::encode_from_hash`] for an edit that knows which voxels it
    /// changed: `voxels` holds, in increasing order, the local index of
    /// every voxel where `base` and `target` may differ (a listed voxel may
    /// be equal in both; an unlisted one must be), and `target` is compact
    /// ([`Chunk::compact`], as [`crate::World`] keeps its chunks). The same
    /// delta, built from those voxels instead of from two 64 KB planes.
    pub fn encode_changed(
        pos: ChunkPos,
        from_version: u64,
        to_version: u64,
        base: &Chunk,
        base_hash: u64,
        target: &Chunk,
        voxels: &[u16],
    ) -> Result<ChunkDelta, DeltaError> {
        let versions = (from_version, to_version);
        Self::build(pos, versions, base, base_hash, target, Some(voxels))
    }

    /// The delta, its bodies from `voxels` when given, else from the XOR
    /// stream.
    fn build(
        pos: ChunkPos,
        (from_version, to_version): (u64, u64),
        base: &Chunk,
        base_hash: u64,
        target: &Chunk,
        voxels: Option<&[u16]>,
    ) -> Result<ChunkDelta, DeltaError> {
        if to_version <= from_version {
            return Err(DeltaError::VersionOrder {
                from: from_version,
                to: to_version,
            });
        }
        debug_assert_eq!(base_hash, chunk_hash(base));
        let target_hash = chunk_hash(target);
        let same = base_hash == target_hash;
        let payload = match voxels {
            None => encode_payload(base, target, same),
            Some(voxels) => {
                debug_assert!(voxels.windows(2).all(|w| w[0] < w[1]));
                // An edit's target is compact (the world keeps its chunks
                // so): uniform only in uniform form, no 64 KB check.
                let uniform = match target {
                    Chunk::Uniform(v) => Some(*v),
                    Chunk::Dense(_) => None,
                };
                let bodies = || sparse_bodies(base, target, voxels);
                let payload = payload_from(uniform, same, bodies);
                debug_assert_eq!(
                    payload,
                    encode_payload(base, target, same),
                    "`voxels` must list every changed voxel, and `target` be compact"
                );
                payload
            }
        };
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
        self.apply_to_checked_base(base)
    }

    /// [`Self::apply`] for a caller that already knows `base` hashes to
    /// `base_hash` (it checked the chunk when it took it in): skips hashing
    /// the base again. The result is still checked against `target_hash`.
    pub fn apply_to_checked_base(&self, base: &Chunk) -> Result<Chunk, DeltaError> {
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
    // A uniform target in either form.
    let uniform = match target {
        Chunk::Uniform(v) => Some(*v),
        Chunk::Dense(d) => d.uniform_value(),
    };
    payload_from(uniform, same, || {
        let x = xor_stream(base, target);
        [
            encode_runs(&x),
            encode_masked(planes(base), planes(target), &x),
        ]
    })
}

/// The runs and masked bodies from the voxels that may differ
/// ([`ChunkDelta::encode_changed`]).
fn sparse_bodies(base: &Chunk, target: &Chunk, voxels: &[u16]) -> [Vec<u8>; 2] {
    let (b, t) = (planes(base), planes(target));
    // Each plane's changed bytes: (index, base, target).
    let changes = |p: usize| -> Vec<(u16, u8, u8)> {
        let mut out = Vec::with_capacity(voxels.len());
        out.extend(
            voxels
                .iter()
                .map(|&i| (i, b[p].get(usize::from(i)), t[p].get(usize::from(i))))
                .filter(|&(_, old, new)| old != new),
        );
        out
    };
    let [density, material] = [changes(0), changes(1)];
    let xor =
        |offset: usize| move |&(i, old, new): &(u16, u8, u8)| (offset + usize::from(i), old ^ new);
    let nonzero = density
        .iter()
        .map(xor(0))
        .chain(material.iter().map(xor(CHUNK_VOLUME)));
    [
        encode_runs_sparse(nonzero),
        encode_masked_sparse([&density, &material]),
    ]
}

/// The payload for `target`: unchanged (`same`), uniform, or else the
/// shortest form of the runs and masked `bodies`.
fn payload_from(
    uniform: Option<Voxel>,
    same: bool,
    bodies: impl FnOnce() -> [Vec<u8>; 2],
) -> Vec<u8> {
    if same {
        return vec![LAYOUT_RUNS | COMPRESSION_NONE];
    }
    // A uniform target needs no stream at all.
    if let Some(v) = uniform {
        return vec![LAYOUT_UNIFORM, v.density, v.material];
    }
    let [runs, masked] = bodies();
    debug_assert!(runs.len() <= MAX_BODY_LEN && masked.len() <= MAX_BODY_LEN);

    // Every layout raw and with LZ4; zstd only for the layout LZ4 packs
    // smaller (runs on a tie): it is most of the encoding time, and the
    // other layout's zstd frame almost never wins. A compressor error just
    // drops that candidate.
    let bodies = [(LAYOUT_RUNS, &runs), (LAYOUT_MASKED, &masked)];
    let lz4 = bodies.map(|(_, body)| lz4_flex::block::compress(body));
    let zstd_for = usize::from(lz4[1].len() < lz4[0].len());
    let mut best: Option<Vec<u8>> = None;
    for (i, ((layout, body), lz4)) in bodies.into_iter().zip(lz4).enumerate() {
        let zst = (i == zstd_for && body.len() >= DELTA_ZSTD_MIN_BODY)
            .then(|| crate::zstd_ctx::compress(body, DELTA_ZSTD_LEVEL).ok())
            .flatten();
        let mut raw = Vec::with_capacity(1 + body.len());
        raw.push(layout | COMPRESSION_NONE);
        raw.extend_from_slice(body);
        consider(&mut best, raw);
        for (compression, packed) in [(COMPRESSION_LZ4, Some(lz4)), (COMPRESSION_ZSTD, zst)] {
            let Some(packed) = packed else { continue };
            let mut p = Vec::with_capacity(1 + MAX_VARINT_BYTES + packed.len());
            p.push(layout | compression);
            write_varint(&mut p, body.len());
            p.extend_from_slice(&packed);
            consider(&mut best, p);
        }
    }
    best.unwrap_or_else(|| vec![LAYOUT_RUNS | COMPRESSION_NONE])
}

/// Keeps the shorter payload. Candidates arrive in increasing method byte
/// order, so keeping the first on a tie prefers the lower method byte.
fn consider(best: &mut Option<Vec<u8>>, candidate: Vec<u8>) {
    if best.as_ref().is_none_or(|b| candidate.len() < b.len()) {
        *best = Some(candidate);
    }
}

// ---------------------------------------------------------------- decoding

fn decode_payload(payload: &[u8], base: &Chunk) -> Result<Chunk, DeltaError> {
    let (&method, body) = payload.split_first().ok_or(DeltaError::EmptyPayload)?;
    let (layout, compression) = (method & 0xf0, method & 0x0f);
    if layout == LAYOUT_UNIFORM && compression == COMPRESSION_NONE {
        return match body {
            [density, material] => Ok(Chunk::Uniform(Voxel::new(*density, *material))),
            [] | [_] => Err(DeltaError::Truncated("uniform body needs 2 bytes")),
            _ => Err(DeltaError::TrailingBytes(body.len() - 2)),
        };
    }
    if !matches!(layout, LAYOUT_RUNS | LAYOUT_MASKED)
        || !matches!(
            compression,
            COMPRESSION_NONE | COMPRESSION_LZ4 | COMPRESSION_ZSTD
        )
    {
        return Err(DeltaError::UnknownMethod(method));
    }
    let decompressed;
    let body = if compression == COMPRESSION_NONE {
        body
    } else {
        decompressed = decompress(compression, body)?;
        &decompressed[..]
    };
    if layout == LAYOUT_RUNS && body.is_empty() {
        return Ok(base.clone());
    }
    let mut out = dense_copy(base);
    if layout == LAYOUT_RUNS {
        apply_runs(body, &mut out)?;
    } else {
        apply_masked(body, &mut out)?;
    }
    Ok(Chunk::Dense(out))
}

/// `varint(n)` then a compressed block or frame of exactly `n` bytes.
fn decompress(compression: u8, body: &[u8]) -> Result<Vec<u8>, DeltaError> {
    let mut at = 0;
    let declared = read_varint(body, &mut at, MAX_BODY_LEN)?;
    if declared == 0 {
        return Err(DeltaError::DeclaredLength {
            declared,
            max: MAX_BODY_LEN,
        });
    }
    let data = &body[at..];
    let out = if compression == COMPRESSION_LZ4 {
        // The output buffer is exactly `declared` bytes: a block that would
        // write more is an error, not an allocation.
        lz4_flex::block::decompress(data, declared)
            .map_err(|e| DeltaError::Decompress(e.to_string()))?
    } else {
        zstd_one_frame(data, declared)?
    };
    if out.len() != declared {
        return Err(DeltaError::WrongLength {
            expected: declared,
            actual: out.len(),
        });
    }
    Ok(out)
}

/// Decompresses exactly one zstd frame into at most `capacity` bytes.
fn zstd_one_frame(data: &[u8], capacity: usize) -> Result<Vec<u8>, DeltaError> {
    use zstd::zstd_safe;
    let frame_len = zstd_safe::find_frame_compressed_size(data)
        .map_err(|code| DeltaError::Decompress(zstd_safe::get_error_name(code).into()))?;
    if frame_len != data.len() {
        return Err(DeltaError::TrailingBytes(data.len() - frame_len));
    }
    crate::zstd_ctx::decompress(data, capacity).map_err(|e| DeltaError::Decompress(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chunk::DenseChunk;
    use crate::material::ids;
    use crate::pos::{local_index, CHUNK_VOLUME};

    const POS: ChunkPos = ChunkPos::new(1, -2, 3);
    const RUNS: u8 = LAYOUT_RUNS | COMPRESSION_NONE;

    fn stone() -> Chunk {
        Chunk::uniform(Voxel::solid(ids::STONE))
    }

    fn encode(base: &Chunk, target: &Chunk) -> ChunkDelta {
        ChunkDelta::encode(POS, 0, 1, base, target).unwrap()
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
    fn golden_single_voxel_payloads() {
        // Pinned bytes: the format is a wire protocol for non-Rust clients.
        let base = stone();
        let mut target = base.clone();
        target.set(5, 0, 0, Voxel::new(0xf0, ids::STONE));
        let d = encode(&base, &target);
        // Runs: zero_run 5, literal of 1 byte, 0xff ^ 0xf0.
        assert_eq!(d.payload, vec![RUNS, 5, 1, 0x0f]);
        assert_eq!(d.apply(&base).unwrap(), target);

        // A material change at voxel 200 sits at stream offset 32768 + 200.
        let mut target = base.clone();
        target.set_index(200, Voxel::solid(ids::ORE));
        let d = encode(&base, &target);
        assert_eq!(
            d.payload,
            vec![RUNS, 0xc8, 0x81, 0x02, 1, ids::STONE ^ ids::ORE]
        );
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn golden_masked_payload() {
        // A 2x2x2 cube dug out of stone at (4..=5, 6..=7, 8..=9): the masked
        // layout wins over runs (4 rows of 2 voxels in each plane).
        let base = stone();
        let mut target = base.clone();
        for (x, y, z) in [(4, 6, 8), (5, 6, 8), (4, 7, 8), (5, 7, 8)] {
            for dz in 0..2 {
                target.set(x, y, z + dz, Voxel::AIR);
            }
        }
        let d = encode(&base, &target);
        let section = |v: u8| vec![OP_REPLACE, 4, 6, 8, 5, 7, 9, 0xff, v, v, v, v, v, v, v, v];
        let mut body = section(0);
        body.extend(section(ids::AIR));
        assert_eq!(d.payload[0] & 0xf0, LAYOUT_MASKED);
        let stored = match d.payload[0] & 0x0f {
            COMPRESSION_NONE => d.payload[1..].to_vec(),
            c => decompress(c, &d.payload[1..]).unwrap(),
        };
        assert_eq!(stored, body);
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn literal_straddling_the_planes_round_trips() {
        let base = stone();
        let mut target = base.clone();
        target.set_index(CHUNK_VOLUME - 1, Voxel::new(7, ids::STONE));
        target.set_index(0, Voxel::new(255, 9));
        let d = encode(&base, &target);
        assert_eq!(d.apply(&base).unwrap(), target);
        // The last density byte (offset 32767 = varint ff ff 01) and the
        // first material byte are adjacent in the stream: one literal.
        assert_eq!(
            d.payload,
            vec![RUNS, 0xff, 0xff, 0x01, 2, 0xff ^ 7, ids::STONE ^ 9]
        );
    }

    #[test]
    fn unchanged_chunk_is_one_byte() {
        let d = ChunkDelta::encode(POS, 3, 9, &stone(), &stone()).unwrap();
        assert_eq!(d.payload, vec![RUNS]);
        assert_eq!(d.base_hash, d.target_hash);
        assert_eq!(d.apply(&stone()).unwrap(), stone());
    }

    #[test]
    fn uniform_target_is_three_bytes_and_stays_uniform() {
        let mut base = stone();
        base.set(1, 2, 3, Voxel::AIR);
        for target in [
            Chunk::uniform(Voxel::AIR),
            Chunk::Dense(DenseChunk::filled(Voxel::AIR)),
        ] {
            let d = encode(&base, &target);
            assert_eq!(d.payload, vec![LAYOUT_UNIFORM, 0, ids::AIR]);
            let out = d.apply(&base).unwrap();
            assert!(out.is_uniform());
            assert_eq!(out, target);
        }
    }

    #[test]
    fn dense_result_that_becomes_uniform_is_compacted() {
        // Hand-written runs that turn a one-voxel-different chunk uniform.
        let mut base = stone();
        base.set_index(0, Voxel::AIR);
        // Density 0 -> 255 at offset 0, material AIR -> STONE at 32768.
        let d = with_payload(
            &base,
            &stone(),
            vec![RUNS, 0, 1, 0xff, 0xff, 0xff, 0x01, 1, 3],
        );
        let out = d.apply(&base).unwrap();
        assert!(out.is_uniform());
        assert_eq!(out, stone());
    }

    #[test]
    fn large_change_picks_a_compressed_method() {
        let base = Chunk::uniform(Voxel::AIR);
        let mut target = base.clone();
        for i in 0..CHUNK_VOLUME / 2 {
            target.set_index(i, Voxel::new((i % 7) as u8 + 1, ids::DIRT));
        }
        let d = encode(&base, &target);
        assert_ne!(d.payload[0] & 0x0f, COMPRESSION_NONE);
        assert!(
            d.payload.len() < 1000,
            "periodic data compresses: {}",
            d.payload.len()
        );
        assert_eq!(d.apply(&base).unwrap(), target);
    }

    #[test]
    fn every_method_decodes_the_same_change() {
        // Build each layout/compression by hand and apply it.
        let base = stone();
        let mut target = base.clone();
        for x in 0..20 {
            target.set(x, 3, 4, Voxel::new(x as u8, ids::DIRT));
        }
        let x = xor_stream(&base, &target);
        let bodies = [
            (LAYOUT_RUNS, encode_runs(&x)),
            (
                LAYOUT_MASKED,
                encode_masked(planes(&base), planes(&target), &x),
            ),
        ];
        for (layout, body) in bodies {
            let mut raw = vec![layout];
            raw.extend(&body);
            let mut lz4 = vec![layout | COMPRESSION_LZ4];
            write_varint(&mut lz4, body.len());
            lz4.extend(lz4_flex::block::compress(&body));
            let mut zst = vec![layout | COMPRESSION_ZSTD];
            write_varint(&mut zst, body.len());
            zst.extend(zstd::bulk::compress(&body, 19).unwrap());
            for p in [raw, lz4, zst] {
                let method = p[0];
                let out = with_payload(&base, &target, p).apply(&base);
                assert_eq!(out, Ok(target.clone()), "method {method:#04x}");
            }
        }
    }

    #[test]
    fn wrong_base_is_rejected_before_decoding() {
        let base = stone();
        let mut target = base.clone();
        target.set(4, 4, 4, Voxel::AIR);
        let d = encode(&base, &target);
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
        let mut d = encode(&base, &target);
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
        for m in [0x03, 0x13, 0x21, 0x22, 0x30, 0xff] {
            assert_eq!(err(vec![m, 1, 2]), DeltaError::UnknownMethod(m));
        }
        assert!(matches!(
            err(vec![LAYOUT_UNIFORM, 0]),
            DeltaError::Truncated(_)
        ));
        assert_eq!(
            err(vec![LAYOUT_UNIFORM, 0, 0, 0]),
            DeltaError::TrailingBytes(1)
        );
        assert!(matches!(err(vec![RUNS, 0x80]), DeltaError::Truncated(_)));
        assert_eq!(
            err(vec![RUNS, 0x84, 0x80, 0x04, 1, 0]),
            DeltaError::VarintTooLarge {
                value: 65540,
                max: XOR_STREAM_LEN
            }
        );
        assert_eq!(err(vec![LAYOUT_MASKED, 9]), DeltaError::UnknownOp(9));
        for c in [COMPRESSION_LZ4, COMPRESSION_ZSTD] {
            assert_eq!(
                err(vec![LAYOUT_RUNS | c, 0]),
                DeltaError::DeclaredLength {
                    declared: 0,
                    max: MAX_BODY_LEN
                }
            );
        }
        assert!(matches!(
            err(vec![LAYOUT_RUNS | COMPRESSION_LZ4, 4, 0xff, 0xff]),
            DeltaError::Decompress(_)
        ));
        assert!(matches!(
            err(vec![LAYOUT_RUNS | COMPRESSION_ZSTD, 4, 1, 2, 3]),
            DeltaError::Decompress(_)
        ));

        // A declared length that disagrees with the compressed data.
        let runs = [0u8, 1, 7];
        let mut p = vec![LAYOUT_RUNS | COMPRESSION_LZ4, 5];
        p.extend(lz4_flex::block::compress(&runs));
        assert_eq!(
            err(p),
            DeltaError::WrongLength {
                expected: 5,
                actual: 3
            }
        );
        let mut p = vec![LAYOUT_RUNS | COMPRESSION_ZSTD, 2];
        p.extend(zstd::bulk::compress(&runs, 3).unwrap());
        assert!(
            matches!(err(p), DeltaError::Decompress(_)),
            "output larger than declared"
        );

        // Bytes after the zstd frame.
        let mut p = vec![LAYOUT_RUNS | COMPRESSION_ZSTD, 3];
        p.extend(zstd::bulk::compress(&runs, 3).unwrap());
        p.push(0);
        assert_eq!(err(p), DeltaError::TrailingBytes(1));
    }

    #[test]
    fn compressed_bombs_are_refused_without_expanding() {
        let base = stone();
        // A body far longer than any valid one.
        let huge = vec![0x7fu8; 4 * MAX_BODY_LEN];
        let mut p = vec![LAYOUT_MASKED | COMPRESSION_ZSTD];
        write_varint(&mut p, MAX_BODY_LEN);
        p.extend(zstd::bulk::compress(&huge, 3).unwrap());
        let e = with_payload(&base, &base, p).apply(&base).unwrap_err();
        assert!(matches!(e, DeltaError::Decompress(_)), "{e}");

        let mut p = vec![LAYOUT_RUNS | COMPRESSION_LZ4];
        write_varint(&mut p, MAX_BODY_LEN);
        p.extend(lz4_flex::block::compress(&huge));
        let e = with_payload(&base, &base, p).apply(&base).unwrap_err();
        assert!(matches!(e, DeltaError::Decompress(_)), "{e}");

        let mut p = vec![LAYOUT_RUNS | COMPRESSION_LZ4];
        write_varint(&mut p, MAX_BODY_LEN + 1);
        let e = with_payload(&base, &base, p).apply(&base).unwrap_err();
        assert_eq!(
            e,
            DeltaError::VarintTooLarge {
                value: MAX_BODY_LEN + 1,
                max: MAX_BODY_LEN
            }
        );
    }

    #[test]
    fn uniform_base_round_trips() {
        // Base uniform, target dense: the XOR against a fill value.
        let base = Chunk::uniform(Voxel::new(200, ids::DIRT));
        let mut target = base.clone();
        target.set(31, 31, 31, Voxel::AIR);
        target.set(0, 31, 0, Voxel::new(201, ids::GRASS));
        let d = encode(&base, &target);
        let out = d.apply(&base).unwrap();
        assert_eq!(out, target);
        assert_eq!(out.get_index(local_index(31, 31, 31)), Voxel::AIR);
    }

    /// Every candidate payload, zstd of both layouts included.
    fn shortest_of_all(base: &Chunk, target: &Chunk) -> usize {
        let x = xor_stream(base, target);
        let bodies = [
            encode_runs(&x),
            encode_masked(planes(base), planes(target), &x),
        ];
        bodies
            .iter()
            .flat_map(|body| {
                let lz4 = lz4_flex::block::compress(body).len();
                let zstd = crate::zstd_ctx::compress(body, DELTA_ZSTD_LEVEL)
                    .map_or(usize::MAX, |z| z.len());
                [1 + body.len(), 1 + MAX_VARINT_BYTES + lz4.min(zstd)]
            })
            .min()
            .unwrap()
    }

    /// Calls `f` with each chunk change of 60 real edits (mined, built
    /// and exploded at the surface of the default world), and the chunk
    /// after it.
    fn for_each_real_change(mut f: impl FnMut(&crate::edit::ChunkChange, &Chunk)) {
        use crate::edit::{Edit, EditContext, StructureLibrary};
        use crate::gen::{GenParams, Generator};
        use crate::{Fixed, FixedVec3, MaterialTable, World};
        let generator = Generator::fractal(GenParams::default()).unwrap();
        let mut world = World::new(std::sync::Arc::new(generator.clone()));
        let (materials, structures) = (MaterialTable::default(), StructureLibrary::default());
        let ctx = EditContext {
            materials: &materials,
            structures: &structures,
        };
        for k in 0..60i32 {
            let (x, z) = ((k * 37) % 160 - 80, (k * 61) % 160 - 80);
            let c = FixedVec3::from_voxels(x, generator.surface_height(x, z).floor() as i32, z);
            let edit = match k % 3 {
                0 => Edit::Mine {
                    center: c,
                    radius: Fixed::from_voxels(2 + k % 4),
                    strength: 255,
                },
                1 => Edit::Build {
                    center: c,
                    radius: Fixed::from_voxels(2 + k % 3),
                    material: ids::DIRT,
                    strength: 255,
                },
                _ => Edit::Explode {
                    center: c,
                    radius: Fixed::from_voxels(4 + k % 5),
                    power: 800,
                },
            };
            for ch in edit.apply(&mut world, &ctx).unwrap().changed {
                f(&ch, &world.peek(ch.pos).unwrap().chunk);
            }
        }
    }

    #[test]
    fn zstd_on_one_layout_costs_almost_nothing_on_real_edits() {
        let (mut chosen, mut best, mut deltas) = (0, 0, 0);
        for_each_real_change(|ch, after| {
            let payload = encode_payload(&ch.before, after, false);
            if payload[0] & 0xf0 == LAYOUT_UNIFORM {
                return;
            }
            chosen += payload.len();
            // The varint of a compressed body may be shorter than the
            // bound counted for every candidate.
            best += shortest_of_all(&ch.before, after).min(payload.len());
            deltas += 1;
        });
        assert!(deltas > 100, "{deltas} deltas");
        // 3327 deltas of this mix: 634,783 bytes against 634,621.
        assert!(
            chosen * 1000 <= best * 1003,
            "{chosen} bytes against {best}"
        );
    }

    #[test]
    fn an_edits_changed_voxels_give_the_same_delta() {
        let mut deltas = 0;
        for_each_real_change(|ch, after| {
            let differ: Vec<u16> = (0..CHUNK_VOLUME)
                .filter(|&i| ch.before.get_index(i) != after.get_index(i))
                .map(|i| i as u16)
                .collect();
            assert_eq!(ch.voxels, differ, "apply lists exactly the changed voxels");
            let base_hash = chunk_hash(&ch.before);
            let (from, to) = (ch.from_version, ch.to_version);
            let full = ChunkDelta::encode_from_hash(ch.pos, from, to, &ch.before, base_hash, after);
            let listed = ChunkDelta::encode_changed(
                ch.pos, from, to, &ch.before, base_hash, after, &ch.voxels,
            );
            assert_eq!(listed.unwrap(), full.unwrap());
            deltas += 1;
        });
        assert!(deltas > 100, "{deltas} deltas");
    }
}
