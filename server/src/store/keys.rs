//! Key layout of the store's trees.
//!
//! All keys are big-endian so sled's byte order is the numeric order and
//! range scans work:
//!
//! | tree | key | value |
//! |---|---|---|
//! | `meta` | `b"world"` | JSON of the world metadata without `last_seq` |
//! | `meta` | `b"last_seq"` | `u64` big-endian: seq of the last committed edit |
//! | `chunks` | [`chunk_key`]: 12 bytes | `version: u64 BE` then [`encode_chunk`] bytes, or version 0 then `0x00`: "generated", the generator's output, which the chunk's deltas follow |
//! | `log` | [`seq_key`]: 8 bytes, `u64` BE | bincode 2 (serde, standard config) of a `LogEntry` |
//! | `deltas` | [`delta_key`]: chunk key then `to_version: u64 BE` (20 bytes) | bincode 2 (as the log) of the `ChunkDelta` |
//! | `blobs` | the blob name, UTF-8 | the blob bytes |
//! | `players` | the player name, UTF-8 | feet x, y, z: fixed-point i32, big-endian (12 bytes) |
//!
//! A chunk key is `x, y, z`, each an `i32` with its sign bit flipped and
//! written big-endian: flipping the sign bit maps `i32::MIN..=i32::MAX`
//! monotonically onto `0..=u32::MAX`, so byte order equals [`ChunkPos`]'s
//! derived order (x, then y, then z) including negative coordinates. All
//! chunks of one x-slab, or one (x, y) column of z, are a contiguous range.
//!
//! [`encode_chunk`]: strata_terrain::chunk_codec::encode_chunk

use strata_terrain::ChunkPos;

/// Bytes of a chunk key.
pub const CHUNK_KEY_LEN: usize = 12;
/// Bytes of a log (seq) key.
pub const SEQ_KEY_LEN: usize = 8;
/// Bytes of a delta key: a chunk key and a version.
pub const DELTA_KEY_LEN: usize = CHUNK_KEY_LEN + 8;

const SIGN_BIT: u32 = 0x8000_0000;

fn ordered(v: i32) -> [u8; 4] {
    ((v as u32) ^ SIGN_BIT).to_be_bytes()
}

fn unordered(b: [u8; 4]) -> i32 {
    (u32::from_be_bytes(b) ^ SIGN_BIT) as i32
}

/// The order-preserving key of a chunk position.
pub fn chunk_key(pos: ChunkPos) -> [u8; CHUNK_KEY_LEN] {
    let mut k = [0u8; CHUNK_KEY_LEN];
    k[0..4].copy_from_slice(&ordered(pos.x));
    k[4..8].copy_from_slice(&ordered(pos.y));
    k[8..12].copy_from_slice(&ordered(pos.z));
    k
}

/// Inverse of [`chunk_key`]; `None` if the key has the wrong length.
pub fn chunk_pos_from_key(key: &[u8]) -> Option<ChunkPos> {
    let k: [u8; CHUNK_KEY_LEN] = key.try_into().ok()?;
    let part = |i: usize| unordered([k[i], k[i + 1], k[i + 2], k[i + 3]]);
    Some(ChunkPos::new(part(0), part(4), part(8)))
}

/// The key of a chunk's delta to `to_version`: all of one chunk's deltas
/// are one contiguous range (prefix [`chunk_key`]), in version order.
pub fn delta_key(pos: ChunkPos, to_version: u64) -> [u8; DELTA_KEY_LEN] {
    let mut k = [0u8; DELTA_KEY_LEN];
    k[..CHUNK_KEY_LEN].copy_from_slice(&chunk_key(pos));
    k[CHUNK_KEY_LEN..].copy_from_slice(&to_version.to_be_bytes());
    k
}

/// Inverse of [`delta_key`]; `None` if the key has the wrong length.
pub fn delta_from_key(key: &[u8]) -> Option<(ChunkPos, u64)> {
    if key.len() != DELTA_KEY_LEN {
        return None;
    }
    let pos = chunk_pos_from_key(&key[..CHUNK_KEY_LEN])?;
    let v = u64::from_be_bytes(key[CHUNK_KEY_LEN..].try_into().ok()?);
    Some((pos, v))
}

/// The key of a log entry: its seq, big-endian.
pub fn seq_key(seq: u64) -> [u8; SEQ_KEY_LEN] {
    seq.to_be_bytes()
}

/// Inverse of [`seq_key`]; `None` if the key has the wrong length.
pub fn seq_from_key(key: &[u8]) -> Option<u64> {
    Some(u64::from_be_bytes(key.try_into().ok()?))
}

/// Printable form of a key that did not parse: UTF-8 if it is, else hex.
pub fn show_raw(key: &[u8]) -> String {
    match std::str::from_utf8(key) {
        Ok(s) => format!("{s:?}"),
        Err(_) => format!(
            "0x{}",
            key.iter().map(|b| format!("{b:02x}")).collect::<String>()
        ),
    }
}

/// Printable form of a chunk position, for error messages.
pub fn show_pos(p: ChunkPos) -> String {
    format!("chunk ({}, {}, {})", p.x, p.y, p.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunk_keys_round_trip_extremes() {
        for v in [i32::MIN, -1, 0, 1, i32::MAX] {
            let p = ChunkPos::new(v, v.wrapping_neg().wrapping_add(1), v / 2);
            assert_eq!(chunk_pos_from_key(&chunk_key(p)), Some(p));
        }
        assert_eq!(chunk_pos_from_key(&[0u8; 11]), None);
        assert_eq!(seq_from_key(&seq_key(u64::MAX)), Some(u64::MAX));
        assert_eq!(seq_from_key(&[1, 2, 3]), None);
    }
}
