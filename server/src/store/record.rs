//! Byte encodings of the store's values (the key layout is in `keys`).
//!
//! The log uses bincode 2 through serde with the standard configuration
//! (varint integers, compact) and a size limit, so a corrupt length prefix
//! can never make a decoder allocate without bound. World metadata is JSON
//! so an operator can read it with any sled dump tool.

use serde::{Deserialize, Serialize};
use strata_terrain::chunk_codec::{decode_chunk, encode_chunk};
use strata_terrain::delta::ChunkDelta;
use strata_terrain::world::{ChunkGenerator, MAX_CHUNK_VERSION};
use strata_terrain::{Chunk, ChunkPos};

use super::error::StoreError;
use super::keys::show_pos;
use super::types::{LogEntry, WorldMeta};

/// Largest log record accepted when writing and reading: a generous bound
/// for an edit plus a few hundred chunk changes.
pub const MAX_LOG_RECORD_BYTES: usize = 1 << 20;
/// Bytes of the version prefix of a chunk value.
pub const CHUNK_VERSION_LEN: usize = 8;

type LogConfig = bincode::config::Configuration<
    bincode::config::LittleEndian,
    bincode::config::Varint,
    bincode::config::Limit<MAX_LOG_RECORD_BYTES>,
>;

fn log_config() -> LogConfig {
    bincode::config::standard().with_limit::<MAX_LOG_RECORD_BYTES>()
}

/// A chunk value: its version big-endian, then its snapshot bytes.
pub fn encode_chunk_value(version: u64, chunk: &Chunk) -> Vec<u8> {
    let snapshot = encode_chunk(chunk);
    let mut v = Vec::with_capacity(CHUNK_VERSION_LEN + snapshot.len());
    v.extend_from_slice(&version.to_be_bytes());
    v.extend_from_slice(&snapshot);
    v
}

/// Splits a chunk value into its version and snapshot bytes, undecoded.
pub fn split_chunk_value(pos: ChunkPos, value: &[u8]) -> Result<(u64, &[u8]), StoreError> {
    if value.len() <= CHUNK_VERSION_LEN {
        return Err(StoreError::corrupt(
            format!(
                "chunk value of {} bytes (needs a version and a body)",
                value.len()
            ),
            show_pos(pos),
        ));
    }
    let (v, body) = value.split_at(CHUNK_VERSION_LEN);
    let version = u64::from_be_bytes(v.try_into().expect("split at CHUNK_VERSION_LEN"));
    if version > MAX_CHUNK_VERSION {
        return Err(StoreError::corrupt(
            format!("chunk version {version} over {MAX_CHUNK_VERSION}"),
            show_pos(pos),
        ));
    }
    Ok((version, body))
}

/// The body of a "generated" chunk record: the chunk is the generator's
/// output at version 0, and its deltas follow. No snapshot starts with
/// this byte (`chunk_codec`'s tags are 1 to 3), so an older build reading
/// one reports a corrupt record rather than a wrong chunk.
pub const GENERATED_BODY: &[u8] = &[0x00];

/// The value of a "generated" record (version 0, [`GENERATED_BODY`]).
pub fn generated_chunk_value() -> Vec<u8> {
    let mut v = Vec::with_capacity(CHUNK_VERSION_LEN + GENERATED_BODY.len());
    v.extend_from_slice(&0u64.to_be_bytes());
    v.extend_from_slice(GENERATED_BODY);
    v
}

/// Whether a record's body (after its version) says "generated".
pub fn is_generated(body: &[u8]) -> bool {
    body == GENERATED_BODY
}

/// Decodes a chunk value fully: a "generated" record through `generator`,
/// which it needs ([`StoreError::NeedsGenerator`] without one).
pub fn decode_chunk_value(
    pos: ChunkPos,
    value: &[u8],
    generator: Option<&dyn ChunkGenerator>,
) -> Result<(u64, Chunk), StoreError> {
    let (version, body) = split_chunk_value(pos, value)?;
    Ok((version, decode_record(pos, version, body, generator)?))
}

/// A chunk record's state from its `version` and body (see
/// [`decode_chunk_value`]).
pub fn decode_record(
    pos: ChunkPos,
    version: u64,
    body: &[u8],
    generator: Option<&dyn ChunkGenerator>,
) -> Result<Chunk, StoreError> {
    if is_generated(body) {
        if version != 0 {
            return Err(StoreError::corrupt(
                format!("a generated record at version {version}"),
                show_pos(pos),
            ));
        }
        let g = generator.ok_or(StoreError::NeedsGenerator { pos })?;
        return Ok(g.generate(pos));
    }
    decode_chunk(body).map_err(|source| StoreError::Codec {
        key: show_pos(pos),
        source,
    })
}

pub fn encode_log_entry(e: &LogEntry) -> Result<Vec<u8>, StoreError> {
    bincode::serde::encode_to_vec(e, log_config()).map_err(|err| StoreError::Encode {
        what: "log entry",
        reason: format!("seq {}: {err}", e.seq),
    })
}

/// A log record as stored: refused past [`MAX_LOG_RECORD_BYTES`].
pub fn encode_log_record(e: &LogEntry) -> Result<Vec<u8>, StoreError> {
    let bytes = encode_log_entry(e)?;
    if bytes.len() > MAX_LOG_RECORD_BYTES {
        return Err(StoreError::Encode {
            what: "log entry",
            reason: format!(
                "seq {} is {} bytes, limit {MAX_LOG_RECORD_BYTES}",
                e.seq,
                bytes.len()
            ),
        });
    }
    Ok(bytes)
}

pub fn decode_log_entry(seq: u64, bytes: &[u8]) -> Result<LogEntry, StoreError> {
    let corrupt =
        |why: String| StoreError::corrupt(format!("log entry ({why})"), format!("seq {seq}"));
    let (e, used): (LogEntry, usize) = bincode::serde::decode_from_slice(bytes, log_config())
        .map_err(|e| corrupt(e.to_string()))?;
    if used != bytes.len() {
        return Err(corrupt(format!("{} trailing bytes", bytes.len() - used)));
    }
    if e.seq != seq {
        return Err(corrupt(format!("record says seq {}", e.seq)));
    }
    Ok(e)
}

/// A delta record (the whole [`ChunkDelta`], bincode as the log).
pub fn encode_delta(d: &ChunkDelta) -> Result<Vec<u8>, StoreError> {
    bincode::serde::encode_to_vec(d, log_config()).map_err(|err| StoreError::Encode {
        what: "chunk delta",
        reason: format!("{} to version {}: {err}", show_pos(d.pos), d.to_version),
    })
}

/// Decodes a delta record and checks it against its key.
pub fn decode_delta(
    pos: ChunkPos,
    to_version: u64,
    bytes: &[u8],
) -> Result<ChunkDelta, StoreError> {
    let corrupt = |why: String| {
        StoreError::corrupt(
            format!("chunk delta ({why})"),
            format!("{} to version {to_version}", show_pos(pos)),
        )
    };
    let (d, used): (ChunkDelta, usize) = bincode::serde::decode_from_slice(bytes, log_config())
        .map_err(|e| corrupt(e.to_string()))?;
    if used != bytes.len() {
        return Err(corrupt(format!("{} trailing bytes", bytes.len() - used)));
    }
    if d.pos != pos
        || d.to_version != to_version
        || d.from_version >= to_version
        || to_version > MAX_CHUNK_VERSION
    {
        return Err(corrupt(format!(
            "record says {} from version {} to {}",
            show_pos(d.pos),
            d.from_version,
            d.to_version
        )));
    }
    Ok(d)
}

/// The metadata record: [`WorldMeta`] without `last_seq`, which lives in
/// its own key so a commit rewrites 8 bytes, not the generator parameters.
#[derive(Debug, Serialize, Deserialize)]
struct MetaRecord {
    format_version: u32,
    seed: u64,
    generator_version: u32,
    generator_params: String,
}

pub fn encode_meta(m: &WorldMeta) -> Result<Vec<u8>, StoreError> {
    let r = MetaRecord {
        format_version: m.format_version,
        seed: m.seed,
        generator_version: m.generator_version,
        generator_params: m.generator_params.clone(),
    };
    serde_json::to_vec(&r).map_err(|e| StoreError::Encode {
        what: "world metadata",
        reason: e.to_string(),
    })
}

pub fn decode_meta(bytes: &[u8], last_seq: u64) -> Result<WorldMeta, StoreError> {
    let r: MetaRecord = serde_json::from_slice(bytes)
        .map_err(|e| StoreError::corrupt(format!("world metadata ({e})"), "meta/world"))?;
    Ok(WorldMeta {
        format_version: r.format_version,
        seed: r.seed,
        generator_version: r.generator_version,
        generator_params: r.generator_params,
        last_seq,
    })
}

pub fn decode_last_seq(bytes: &[u8]) -> Result<u64, StoreError> {
    let b: [u8; 8] = bytes.try_into().map_err(|_| {
        StoreError::corrupt(
            format!("last_seq of {} bytes", bytes.len()),
            "meta/last_seq",
        )
    })?;
    let seq = u64::from_be_bytes(b);
    if seq > MAX_SEQ {
        return Err(StoreError::corrupt(
            format!("last_seq {seq} over {MAX_SEQ}"),
            "meta/last_seq",
        ));
    }
    Ok(seq)
}

/// The highest seq a store or snapshot may hold (what PostgreSQL's
/// `bigint` holds): the sequencer hands out none past it, so no `+ 1`
/// leaves it.
pub const MAX_SEQ: u64 = i64::MAX as u64;

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::Voxel;

    #[test]
    fn a_version_no_edit_can_reach_is_corrupt() {
        let pos = ChunkPos::new(1, 2, 3);
        let chunk = Chunk::uniform(Voxel::solid(1));
        let at = |v: u64| encode_chunk_value(v, &chunk);
        assert_eq!(
            split_chunk_value(pos, &at(MAX_CHUNK_VERSION)).unwrap().0,
            MAX_CHUNK_VERSION
        );
        for v in [MAX_CHUNK_VERSION + 1, u64::MAX] {
            assert!(
                matches!(
                    split_chunk_value(pos, &at(v)),
                    Err(StoreError::Corrupt { .. })
                ),
                "{v}"
            );
        }
    }

    #[test]
    fn a_last_seq_past_what_postgresql_holds_is_corrupt() {
        let at = |s: u64| decode_last_seq(&s.to_be_bytes());
        assert_eq!(at(MAX_SEQ).unwrap(), MAX_SEQ);
        for s in [MAX_SEQ + 1, u64::MAX] {
            assert!(matches!(at(s), Err(StoreError::Corrupt { .. })), "{s}");
        }
    }
}
