//! Writes a snapshot file as chunk records arrive, hashing as it goes, so
//! memory stays bounded whatever the world's size.

use std::hash::Hasher;
use std::io::Write;

use strata_terrain::ChunkPos;
use twox_hash::XxHash3_64;

use super::error::SnapshotError;
use super::format::{encode_record, SnapshotHeader, TAG_FOOTER};

/// A snapshot being written. Call [`Self::finish`]: a file without its
/// footer fails verification.
pub struct SnapshotWriter<W: Write> {
    out: W,
    hasher: XxHash3_64,
    records: u64,
    bytes: u64,
    last: Option<ChunkPos>,
}

impl<W: Write> std::fmt::Debug for SnapshotWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SnapshotWriter")
            .field("records", &self.records)
            .field("bytes", &self.bytes)
            .finish_non_exhaustive()
    }
}

impl<W: Write> SnapshotWriter<W> {
    /// Writes the header.
    pub fn new(out: W, header: &SnapshotHeader) -> Result<Self, SnapshotError> {
        let mut w = Self {
            out,
            hasher: XxHash3_64::with_seed(0),
            records: 0,
            bytes: 0,
            last: None,
        };
        w.put(&header.encode()?)?;
        Ok(w)
    }

    fn put(&mut self, bytes: &[u8]) -> Result<(), SnapshotError> {
        self.out.write_all(bytes)?;
        self.hasher.write(bytes);
        self.bytes += bytes.len() as u64;
        Ok(())
    }

    /// Appends one chunk (chunk codec bytes). Chunks must come in ascending
    /// order, each once, at a version above 0.
    pub fn chunk(
        &mut self,
        pos: ChunkPos,
        version: u64,
        payload: &[u8],
    ) -> Result<(), SnapshotError> {
        if version == 0 {
            return Err(SnapshotError::Write(format!(
                "chunk ({}, {}, {}) at version 0 is not stored",
                pos.x, pos.y, pos.z
            )));
        }
        if self.last.is_some_and(|l| l >= pos) {
            return Err(SnapshotError::Write(format!(
                "chunk ({}, {}, {}) is out of order",
                pos.x, pos.y, pos.z
            )));
        }
        self.last = Some(pos);
        let record = encode_record(pos, version, payload)?;
        self.put(&record)?;
        self.records += 1;
        Ok(())
    }

    /// Chunk records written so far.
    pub fn records(&self) -> u64 {
        self.records
    }

    /// Writes the footer and flushes; returns the output and the file size.
    pub fn finish(mut self) -> Result<(W, u64), SnapshotError> {
        let mut footer = vec![TAG_FOOTER];
        footer.extend_from_slice(&self.records.to_le_bytes());
        self.put(&footer)?;
        let sum = self.hasher.finish();
        self.out.write_all(&sum.to_le_bytes())?;
        self.out.flush()?;
        Ok((self.out, self.bytes + 8))
    }
}
