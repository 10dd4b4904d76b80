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
        // A stored body that does not decode (a corrupt row) fails the
        // snapshot now: written, it would pass for a backup that `verify`
        // and `restore` then refuse whole.
        if let Err(e) = strata_terrain::chunk_codec::decode_chunk(payload) {
            return Err(SnapshotError::Write(format!(
                "chunk ({}, {}, {}) as stored does not decode: {e}",
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

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::chunk_codec::encode_chunk;
    use strata_terrain::{Chunk, Voxel};

    /// A stored body that does not decode fails the snapshot; nothing of
    /// it is recorded.
    #[test]
    fn a_chunk_that_does_not_decode_is_refused() {
        let header = SnapshotHeader {
            seed: 1,
            generator_version: 1,
            seq: 1,
            generator_params: String::new(),
            zones: Vec::new(),
        };
        let mut w = SnapshotWriter::new(Vec::new(), &header).unwrap();
        let good = encode_chunk(&Chunk::uniform(Voxel::AIR));
        w.chunk(ChunkPos::new(0, 0, 0), 1, &good).unwrap();
        let mut bad = good.clone();
        bad.truncate(1);
        bad.extend_from_slice(&[0xff; 7]);
        let err = w.chunk(ChunkPos::new(1, 0, 0), 1, &bad).unwrap_err();
        assert!(err.to_string().contains("does not decode"), "{err}");
        assert_eq!(w.records(), 1);
    }
}
