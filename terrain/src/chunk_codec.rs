//! Whole-chunk snapshot bytes, for storage and for sending a chunk outright.
//!
//! Used wherever a full chunk crosses a boundary: the chunk store, world
//! snapshots and the chunk snapshot message. Most chunks of a world are all
//! air or all rock, so those cost three bytes; the rest are zstd-compressed.
//!
//! # Format (version 1)
//!
//! The first byte is a tag; what follows depends on it. Nothing may follow
//! the last field.
//!
//! | tag | name | rest | total |
//! |---|---|---|---|
//! | `0x01` | [`TAG_UNIFORM`] | `density:u8 material:u8`: every voxel has this value | 3 bytes |
//! | `0x02` | [`TAG_ZSTD`] | exactly one zstd frame that decompresses to the 65536 plane bytes | varies |
//! | `0x03` | [`TAG_RAW`] | the 65536 plane bytes, uncompressed | 65537 bytes |
//!
//! The plane bytes are the 32768 density bytes followed by the 32768
//! material bytes, both in [`crate::pos::local_index`] order (x fastest, then
//! y, then z) - the same bytes [`crate::hash::chunk_hash`] hashes.
//!
//! The encoder is deterministic: a chunk whose voxels are all equal is
//! always written as `0x01`, whatever its in-memory form; any other chunk as
//! `0x02` at zstd level [`SNAPSHOT_ZSTD_LEVEL`], unless that would not be
//! smaller than the raw planes (random data), in which case `0x03`. A decoder
//! accepts a uniform chunk under `0x02` or `0x03` too and returns it compacted.
//! Decompression never produces more than 65536 bytes.

use thiserror::Error;

use crate::chunk::{Chunk, DenseChunk, Voxel};
use crate::pos::CHUNK_VOLUME;

/// Tag: a uniform chunk.
pub const TAG_UNIFORM: u8 = 0x01;
/// Tag: both planes in one zstd frame.
pub const TAG_ZSTD: u8 = 0x02;
/// Tag: both planes uncompressed.
pub const TAG_RAW: u8 = 0x03;
/// zstd level for dense chunks: level 3 is zstd's default, a good balance
/// of ratio and speed for 64 KiB inputs.
pub const SNAPSHOT_ZSTD_LEVEL: i32 = 3;
/// Bytes of both planes together.
pub const PLANES_LEN: usize = 2 * CHUNK_VOLUME;

/// Why snapshot bytes could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CodecError {
    #[error("chunk bytes are empty (no tag)")]
    Empty,
    #[error("unknown chunk tag {0:#04x}")]
    UnknownTag(u8),
    #[error("chunk bytes truncated: tag {tag:#04x} needs {needed} bytes after it, got {got}")]
    Truncated { tag: u8, needed: usize, got: usize },
    #[error("{0} unexpected trailing bytes after the chunk")]
    TrailingBytes(usize),
    #[error("chunk planes are {actual} bytes, expected {PLANES_LEN}")]
    WrongLength { actual: u64 },
    #[error("zstd frame is invalid: {0}")]
    Decompress(String),
}

/// Encodes a chunk as snapshot bytes (see the module docs).
pub fn encode_chunk(c: &Chunk) -> Vec<u8> {
    let d = match c {
        Chunk::Uniform(v) => return vec![TAG_UNIFORM, v.density, v.material],
        Chunk::Dense(d) => d,
    };
    if let Some(v) = d.uniform_value() {
        return vec![TAG_UNIFORM, v.density, v.material];
    }
    let mut planes = Vec::with_capacity(PLANES_LEN);
    planes.extend_from_slice(&d.density[..]);
    planes.extend_from_slice(&d.material[..]);
    // zstd only fails on allocation or internal errors; the raw form is a
    // correct fallback for those, so encoding never fails.
    match crate::zstd_ctx::compress(&planes, SNAPSHOT_ZSTD_LEVEL) {
        Ok(z) if z.len() < PLANES_LEN => {
            let mut out = Vec::with_capacity(1 + z.len());
            out.push(TAG_ZSTD);
            out.extend_from_slice(&z);
            out
        }
        _ => {
            let mut out = Vec::with_capacity(1 + PLANES_LEN);
            out.push(TAG_RAW);
            out.extend_from_slice(&planes);
            out
        }
    }
}

/// Decodes snapshot bytes into a compacted chunk.
pub fn decode_chunk(bytes: &[u8]) -> Result<Chunk, CodecError> {
    let (&tag, rest) = bytes.split_first().ok_or(CodecError::Empty)?;
    match tag {
        TAG_UNIFORM => {
            let (density, material) = exact::<2>(tag, rest).map(|[d, m]| (d, m))?;
            Ok(Chunk::Uniform(Voxel::new(density, material)))
        }
        TAG_RAW => {
            check_len(tag, rest, PLANES_LEN)?;
            from_planes(rest)
        }
        TAG_ZSTD => {
            let planes = decompress_frame(rest)?;
            from_planes(&planes)
        }
        other => Err(CodecError::UnknownTag(other)),
    }
}

fn check_len(tag: u8, rest: &[u8], needed: usize) -> Result<(), CodecError> {
    match rest.len() {
        got if got < needed => Err(CodecError::Truncated { tag, needed, got }),
        got if got > needed => Err(CodecError::TrailingBytes(got - needed)),
        _ => Ok(()),
    }
}

fn exact<const N: usize>(tag: u8, rest: &[u8]) -> Result<[u8; N], CodecError> {
    check_len(tag, rest, N)?;
    let mut out = [0u8; N];
    out.copy_from_slice(rest);
    Ok(out)
}

/// Decompresses exactly one zstd frame holding exactly [`PLANES_LEN`] bytes.
fn decompress_frame(data: &[u8]) -> Result<Vec<u8>, CodecError> {
    use zstd::zstd_safe;
    let zstd_err = |code| CodecError::Decompress(zstd_safe::get_error_name(code).to_string());
    let frame_len = zstd_safe::find_frame_compressed_size(data).map_err(zstd_err)?;
    if frame_len != data.len() {
        return Err(CodecError::TrailingBytes(data.len() - frame_len));
    }
    // Refuse a frame that declares the wrong size before doing any work.
    if let Ok(Some(declared)) = zstd_safe::get_frame_content_size(data) {
        if declared != PLANES_LEN as u64 {
            return Err(CodecError::WrongLength { actual: declared });
        }
    }
    // The output buffer is capped at PLANES_LEN: a frame that would write
    // more fails instead of allocating (no zip bombs).
    let planes = crate::zstd_ctx::decompress(data, PLANES_LEN)
        .map_err(|e| CodecError::Decompress(e.to_string()))?;
    if planes.len() != PLANES_LEN {
        return Err(CodecError::WrongLength {
            actual: planes.len() as u64,
        });
    }
    Ok(planes)
}

/// Builds a compacted chunk from exactly [`PLANES_LEN`] bytes.
fn from_planes(planes: &[u8]) -> Result<Chunk, CodecError> {
    let (density, material) = planes.split_at(CHUNK_VOLUME.min(planes.len()));
    let d = DenseChunk::from_planes(density, material).ok_or(CodecError::WrongLength {
        actual: planes.len() as u64,
    })?;
    let mut c = Chunk::Dense(d);
    c.compact();
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hash::chunk_hash;
    use crate::material::ids;
    use crate::pos::local_index;

    /// A layered chunk: solid stone below y = 10, a ramp, air above.
    fn layered() -> Chunk {
        let mut c = Chunk::uniform(Voxel::AIR);
        for z in 0..32 {
            for y in 0..14 {
                for x in 0..32 {
                    let density = if y < 10 {
                        255
                    } else {
                        255 - 60 * (y as u8 - 9)
                    };
                    c.set(
                        x,
                        y,
                        z,
                        Voxel::new(density, if y < 8 { ids::STONE } else { ids::DIRT }),
                    );
                }
            }
        }
        c
    }

    fn zstd_planes(planes: &[u8]) -> Vec<u8> {
        zstd::bulk::compress(planes, SNAPSHOT_ZSTD_LEVEL).unwrap()
    }

    #[test]
    fn uniform_chunks_are_three_bytes_in_either_form() {
        let v = Voxel::new(255, ids::STONE);
        assert_eq!(
            encode_chunk(&Chunk::uniform(v)),
            vec![TAG_UNIFORM, 255, ids::STONE]
        );
        assert_eq!(
            encode_chunk(&Chunk::Dense(DenseChunk::filled(v))),
            vec![TAG_UNIFORM, 255, 3]
        );
        let back = decode_chunk(&[TAG_UNIFORM, 255, 3]).unwrap();
        assert!(back.is_uniform());
        assert_eq!(back, Chunk::uniform(v));
    }

    #[test]
    fn dense_chunks_round_trip_through_zstd() {
        let c = layered();
        let bytes = encode_chunk(&c);
        assert_eq!(bytes[0], TAG_ZSTD);
        assert!(
            bytes.len() < 1000,
            "layered chunk compresses well: {}",
            bytes.len()
        );
        let back = decode_chunk(&bytes).unwrap();
        assert_eq!(back, c);
        assert_eq!(chunk_hash(&back), chunk_hash(&c));
        assert_eq!(encode_chunk(&back), bytes, "deterministic");
    }

    #[test]
    fn incompressible_chunks_are_stored_raw() {
        let mut c = Chunk::uniform(Voxel::AIR);
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        for i in 0..CHUNK_VOLUME {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            c.set_index(i, Voxel::new(s as u8, (s >> 8) as u8));
        }
        let bytes = encode_chunk(&c);
        assert_eq!(bytes[0], TAG_RAW);
        assert_eq!(bytes.len(), 1 + PLANES_LEN);
        assert_eq!(decode_chunk(&bytes).unwrap(), c);
    }

    #[test]
    fn uniform_content_under_other_tags_decodes_compacted() {
        let mut raw = vec![TAG_RAW];
        raw.extend(vec![7u8; PLANES_LEN]);
        let c = decode_chunk(&raw).unwrap();
        assert!(c.is_uniform());
        assert_eq!(c, Chunk::uniform(Voxel::new(7, 7)));
        let mut z = vec![TAG_ZSTD];
        z.extend(zstd_planes(&raw[1..]));
        assert_eq!(decode_chunk(&z).unwrap(), c);
    }

    #[test]
    fn malformed_bytes_give_typed_errors() {
        assert_eq!(decode_chunk(&[]), Err(CodecError::Empty));
        assert_eq!(decode_chunk(&[0]), Err(CodecError::UnknownTag(0)));
        assert_eq!(decode_chunk(&[9, 1, 2]), Err(CodecError::UnknownTag(9)));
        assert_eq!(
            decode_chunk(&[TAG_UNIFORM, 1]),
            Err(CodecError::Truncated {
                tag: TAG_UNIFORM,
                needed: 2,
                got: 1
            })
        );
        assert_eq!(
            decode_chunk(&[TAG_UNIFORM, 1, 2, 3]),
            Err(CodecError::TrailingBytes(1))
        );
        assert_eq!(
            decode_chunk(&[TAG_RAW, 1, 2]),
            Err(CodecError::Truncated {
                tag: TAG_RAW,
                needed: PLANES_LEN,
                got: 2
            })
        );
        assert!(matches!(
            decode_chunk(&[TAG_ZSTD]),
            Err(CodecError::Decompress(_))
        ));
        assert!(matches!(
            decode_chunk(&[TAG_ZSTD, 1, 2, 3, 4]),
            Err(CodecError::Decompress(_))
        ));
    }

    #[test]
    fn zstd_frames_of_the_wrong_size_or_with_extras_are_refused() {
        let planes = encode_planes_of(&layered());
        // Too short.
        let mut b = vec![TAG_ZSTD];
        b.extend(zstd_planes(&planes[..1000]));
        assert_eq!(
            decode_chunk(&b),
            Err(CodecError::WrongLength { actual: 1000 })
        );
        // A bomb: a frame declaring 64 MiB of zeros is refused up front.
        let mut b = vec![TAG_ZSTD];
        b.extend(zstd_planes(&vec![0u8; 64 << 20]));
        assert!(b.len() < 10_000);
        assert_eq!(
            decode_chunk(&b),
            Err(CodecError::WrongLength { actual: 64 << 20 })
        );
        // Trailing garbage after a good frame.
        let mut b = vec![TAG_ZSTD];
        b.extend(zstd_planes(&planes));
        b.push(0);
        assert_eq!(decode_chunk(&b), Err(CodecError::TrailingBytes(1)));
        // Two frames of half the planes each.
        let mut b = vec![TAG_ZSTD];
        b.extend(zstd_planes(&planes[..CHUNK_VOLUME]));
        let second = zstd_planes(&planes[CHUNK_VOLUME..]);
        b.extend(&second);
        assert_eq!(
            decode_chunk(&b),
            Err(CodecError::TrailingBytes(second.len()))
        );
    }

    #[test]
    fn frames_without_a_declared_size_are_still_bounded() {
        // A streaming frame has no content size in its header; the capped
        // output buffer still refuses more than 64 KiB.
        let mut enc = zstd::stream::Encoder::new(Vec::new(), 3).unwrap();
        std::io::Write::write_all(&mut enc, &vec![1u8; 4 * PLANES_LEN]).unwrap();
        let frame = enc.finish().unwrap();
        assert!(matches!(
            zstd::zstd_safe::get_frame_content_size(&frame),
            Ok(None)
        ));
        let mut b = vec![TAG_ZSTD];
        b.extend(frame);
        assert!(matches!(decode_chunk(&b), Err(CodecError::Decompress(_))));
    }

    fn encode_planes_of(c: &Chunk) -> Vec<u8> {
        let mut p = c.density_plane().to_vec();
        p.extend_from_slice(&c.material_plane()[..]);
        p
    }

    #[test]
    fn plane_order_is_density_then_material_in_local_index_order() {
        let mut c = layered();
        c.set(3, 20, 5, Voxel::new(77, ids::ORE));
        let bytes = encode_chunk(&c);
        let planes = zstd::bulk::decompress(&bytes[1..], PLANES_LEN).unwrap();
        let i = local_index(3, 20, 5);
        assert_eq!(planes[i], 77);
        assert_eq!(planes[CHUNK_VOLUME + i], ids::ORE);
        assert_eq!(crate::hash::hash_bytes(&planes), chunk_hash(&c));
    }
}
