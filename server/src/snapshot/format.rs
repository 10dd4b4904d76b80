//! The snapshot byte format (normative text in SNAPSHOT.md). All integers
//! are little-endian; checksums are XXH3-64 with seed 0.
//!
//! ```text
//! header  = magic "STRATASN" | format_version u32 | body_len u32 | body | checksum u64
//!   body  = seed u64 | generator_version u32 | seq u64
//!         | params_len u32 | params (UTF-8 TOML) | zones_len u32 | zones (UTF-8 JSON)
//!   checksum covers magic .. body
//! record  = tag 0x01 | x i32 | y i32 | z i32 | version u64 | len u32 | payload | checksum u64
//!   payload is the chunk codec's bytes; checksum covers tag .. payload
//! footer  = tag 0xFF | record_count u64 | file_checksum u64
//!   file_checksum covers every byte of the file before itself
//! ```
//!
//! Records are in ascending chunk order (x, then y, then z), each chunk at
//! most once, every version above 0.

use strata_protocol::admin::ZoneSpec;
use strata_terrain::gen::{GenParams, GENERATOR_VERSION};

use super::error::{HeaderProblem, SnapshotError};
use crate::store::MAX_GENERATOR_PARAMS_BYTES;
use crate::validate::zones::{check_new, Zone};

/// First bytes of every snapshot file.
pub const SNAPSHOT_MAGIC: [u8; 8] = *b"STRATASN";
/// Version of the layout this build writes and reads.
pub const SNAPSHOT_FORMAT_VERSION: u32 = 1;
/// Tag of a chunk record.
pub const TAG_CHUNK: u8 = 0x01;
/// Tag of the footer.
pub const TAG_FOOTER: u8 = 0xFF;
/// Largest header body (generator parameters plus zones JSON).
pub const MAX_HEADER_BODY: usize = 1 << 20;
/// Largest chunk payload: the chunk codec's raw form is 65537 bytes.
pub const MAX_CHUNK_PAYLOAD: usize = 128 * 1024;
/// Bytes of a chunk record before its payload (tag, position, version, length).
pub const RECORD_PREFIX: usize = 1 + 12 + 8 + 4;

/// What a snapshot is a snapshot of.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SnapshotHeader {
    pub seed: u64,
    pub generator_version: u32,
    /// Every edit up to and including this seq is in; none after.
    pub seq: u64,
    /// Generator parameters exactly as the store's metadata holds them.
    pub generator_params: String,
    /// Protected zones at `seq`.
    pub zones: Vec<ZoneSpec>,
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

impl SnapshotHeader {
    /// The header's bytes, checksum included.
    pub fn encode(&self) -> Result<Vec<u8>, SnapshotError> {
        let zones = serde_json::to_string(&self.zones)
            .map_err(|e| SnapshotError::Write(format!("zones: {e}")))?;
        let mut body = Vec::new();
        body.extend_from_slice(&self.seed.to_le_bytes());
        body.extend_from_slice(&self.generator_version.to_le_bytes());
        body.extend_from_slice(&self.seq.to_le_bytes());
        put_str(&mut body, &self.generator_params);
        put_str(&mut body, &zones);
        if body.len() > MAX_HEADER_BODY {
            return Err(SnapshotError::Write(format!(
                "header body is {} bytes, limit {MAX_HEADER_BODY}",
                body.len()
            )));
        }
        let mut out = Vec::with_capacity(body.len() + 24);
        out.extend_from_slice(&SNAPSHOT_MAGIC);
        out.extend_from_slice(&SNAPSHOT_FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(body.len() as u32).to_le_bytes());
        out.extend_from_slice(&body);
        let sum = twox_hash::XxHash3_64::oneshot(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        Ok(out)
    }

    /// Refuses a world this build cannot serve: another generator version,
    /// parameters too long or invalid, or zones `ZoneAdd` would refuse.
    pub fn check_usable(&self) -> Result<(), HeaderProblem> {
        if self.generator_version != GENERATOR_VERSION {
            return Err(HeaderProblem::GeneratorVersion {
                found: self.generator_version,
                supported: GENERATOR_VERSION,
            });
        }
        let len = self.generator_params.len();
        if len > MAX_GENERATOR_PARAMS_BYTES {
            return Err(HeaderProblem::ParamsTooLong { len });
        }
        // A heightmap world's params end in a TOML comment: they parse too.
        let params: GenParams = toml::from_str(&self.generator_params)
            .map_err(|e| HeaderProblem::Params(e.message().to_string()))?;
        params
            .validate()
            .map_err(|e| HeaderProblem::Params(e.to_string()))?;
        self.zones()?;
        if self.seq > crate::store::MAX_SEQ {
            return Err(HeaderProblem::Seq { seq: self.seq });
        }
        Ok(())
    }

    /// The zones, each checked as `ZoneAdd` checks a new one.
    pub fn zones(&self) -> Result<Vec<Zone>, HeaderProblem> {
        let mut zones = Vec::with_capacity(self.zones.len());
        for (index, z) in self.zones.iter().enumerate() {
            let zone = Zone {
                name: z.name.clone(),
                min: z.min,
                max: z.max,
            };
            check_new(&zones, &zone).map_err(|source| HeaderProblem::Zone {
                index,
                name: z.name.clone(),
                source,
            })?;
            zones.push(zone);
        }
        Ok(zones)
    }

    /// Parses a header body (after its checksum was checked).
    pub fn decode_body(body: &[u8]) -> Result<Self, SnapshotError> {
        let mut c = Cursor { b: body, at: 0 };
        let seed = c.u64()?;
        let generator_version = c.u32()?;
        let seq = c.u64()?;
        let generator_params = c.string("generator params")?;
        let zones_json = c.string("zones")?;
        if c.at != body.len() {
            return Err(SnapshotError::Header(format!(
                "{} unexpected bytes after the zones",
                body.len() - c.at
            )));
        }
        let zones = serde_json::from_str(&zones_json)
            .map_err(|e| SnapshotError::Header(format!("zones do not parse: {e}")))?;
        Ok(Self {
            seed,
            generator_version,
            seq,
            generator_params,
            zones,
        })
    }
}

/// Reads fixed fields from a header body.
struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], SnapshotError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len());
        let end = end.ok_or_else(|| {
            SnapshotError::Header(format!("body ends at byte {} of {n} wanted", self.at))
        })?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn u32(&mut self) -> Result<u32, SnapshotError> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }

    fn u64(&mut self) -> Result<u64, SnapshotError> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }

    fn string(&mut self, what: &str) -> Result<String, SnapshotError> {
        let n = self.u32()? as usize;
        let bytes = self.take(n)?;
        String::from_utf8(bytes.to_vec())
            .map_err(|_| SnapshotError::Header(format!("{what} are not UTF-8")))
    }
}

/// A chunk record's bytes, checksum included.
pub fn encode_record(
    pos: strata_terrain::ChunkPos,
    version: u64,
    payload: &[u8],
) -> Result<Vec<u8>, SnapshotError> {
    if payload.len() > MAX_CHUNK_PAYLOAD {
        return Err(SnapshotError::Write(format!(
            "chunk ({}, {}, {}) payload is {} bytes, limit {MAX_CHUNK_PAYLOAD}",
            pos.x,
            pos.y,
            pos.z,
            payload.len()
        )));
    }
    let mut out = Vec::with_capacity(RECORD_PREFIX + payload.len() + 8);
    out.push(TAG_CHUNK);
    for v in [pos.x, pos.y, pos.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let sum = twox_hash::XxHash3_64::oneshot(&out);
    out.extend_from_slice(&sum.to_le_bytes());
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seq_past_what_a_store_holds_is_not_usable() {
        let at = |seq: u64| SnapshotHeader {
            seed: 1,
            generator_version: GENERATOR_VERSION,
            seq,
            generator_params: String::new(),
            zones: Vec::new(),
        };
        let max = crate::store::MAX_SEQ;
        assert_eq!(at(max).check_usable(), Ok(()));
        assert!(matches!(
            at(max + 1).check_usable(),
            Err(HeaderProblem::Seq { seq }) if seq == max + 1
        ));
    }
}
