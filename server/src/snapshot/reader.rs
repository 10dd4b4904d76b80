//! Reads a snapshot file record by record, checking every checksum, and
//! [`verify`]: the whole-file check `strata-admin snapshot verify` runs.

use std::hash::Hasher;
use std::io::{BufReader, Read};
use std::path::Path;

use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::ChunkPos;
use twox_hash::XxHash3_64;

use super::error::SnapshotError;
use super::format::{
    SnapshotHeader, MAX_CHUNK_PAYLOAD, MAX_HEADER_BODY, RECORD_PREFIX, SNAPSHOT_FORMAT_VERSION,
    SNAPSHOT_MAGIC, TAG_CHUNK, TAG_FOOTER,
};

/// Issues kept by [`verify`]; past this only the count grows.
pub const MAX_VERIFY_ISSUES: usize = 1000;

/// One chunk record, checksum-verified (its payload not yet decoded).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SnapshotChunk {
    pub index: u64,
    pub offset: u64,
    pub pos: ChunkPos,
    pub version: u64,
    /// Chunk codec bytes.
    pub payload: Vec<u8>,
}

/// Reads records in order. After an error that loses the framing
/// ([`Self::stopped`]), it reads nothing more.
pub struct SnapshotReader<R: Read> {
    r: R,
    hasher: XxHash3_64,
    offset: u64,
    index: u64,
    last: Option<ChunkPos>,
    header: SnapshotHeader,
    stopped: bool,
}

impl<R: Read> std::fmt::Debug for SnapshotReader<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SnapshotReader")
            .field("offset", &self.offset)
            .field("index", &self.index)
            .finish_non_exhaustive()
    }
}

fn read_exact_or<R: Read>(r: &mut R, buf: &mut [u8]) -> Result<bool, std::io::Error> {
    match r.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

impl SnapshotReader<BufReader<std::fs::File>> {
    /// Opens a snapshot file and checks its header.
    pub fn open(path: &Path) -> Result<Self, SnapshotError> {
        Self::new(BufReader::new(std::fs::File::open(path)?))
    }
}

impl<R: Read> SnapshotReader<R> {
    /// Reads and checks the header.
    pub fn new(mut r: R) -> Result<Self, SnapshotError> {
        let mut fixed = [0u8; 16];
        if !read_exact_or(&mut r, &mut fixed)? {
            return Err(SnapshotError::Header(
                "file is shorter than a header".into(),
            ));
        }
        if fixed[..8] != SNAPSHOT_MAGIC {
            return Err(SnapshotError::Header(
                "not a Strata snapshot (bad magic)".into(),
            ));
        }
        let version = u32::from_le_bytes(fixed[8..12].try_into().expect("4 bytes"));
        if version != SNAPSHOT_FORMAT_VERSION {
            return Err(SnapshotError::Header(format!(
                "format version {version} is not supported (this build reads {SNAPSHOT_FORMAT_VERSION})"
            )));
        }
        let len = u32::from_le_bytes(fixed[12..16].try_into().expect("4 bytes")) as usize;
        if len > MAX_HEADER_BODY {
            return Err(SnapshotError::Header(format!(
                "body length {len} is over the {MAX_HEADER_BODY}-byte limit"
            )));
        }
        let mut body = vec![0u8; len + 8];
        if !read_exact_or(&mut r, &mut body)? {
            return Err(SnapshotError::Header("file ends inside the header".into()));
        }
        let stored = u64::from_le_bytes(body[len..].try_into().expect("8 bytes"));
        let mut covered = fixed.to_vec();
        covered.extend_from_slice(&body[..len]);
        let computed = XxHash3_64::oneshot(&covered);
        if stored != computed {
            return Err(SnapshotError::Header(format!(
                "checksum mismatch: stored {stored:016x}, computed {computed:016x}"
            )));
        }
        let header = SnapshotHeader::decode_body(&body[..len])?;
        let mut hasher = XxHash3_64::with_seed(0);
        hasher.write(&covered);
        hasher.write(&body[len..]);
        Ok(Self {
            r,
            hasher,
            offset: (16 + len + 8) as u64,
            index: 0,
            last: None,
            header,
            stopped: false,
        })
    }

    pub fn header(&self) -> &SnapshotHeader {
        &self.header
    }

    /// True once the reader can go no further (end of file or lost framing).
    pub fn stopped(&self) -> bool {
        self.stopped
    }

    fn fatal(&mut self, e: SnapshotError) -> SnapshotError {
        self.stopped = true;
        e
    }

    fn record_error(&self, offset: u64, pos: Option<ChunkPos>, reason: String) -> SnapshotError {
        SnapshotError::Record {
            index: self.index,
            offset,
            pos: pos.map(|p| format!("chunk ({}, {}, {})", p.x, p.y, p.z)),
            reason,
        }
    }

    /// The next chunk, or `None` after a valid footer. A record whose
    /// checksum or order is wrong is an error, and reading can go on.
    pub fn next_chunk(&mut self) -> Result<Option<SnapshotChunk>, SnapshotError> {
        if self.stopped {
            return Ok(None);
        }
        let start = self.offset;
        let mut tag = [0u8; 1];
        if !read_exact_or(&mut self.r, &mut tag)? {
            return Err(self.fatal(SnapshotError::Footer {
                offset: start,
                reason: "file ends without a footer (truncated)".into(),
            }));
        }
        match tag[0] {
            TAG_CHUNK => self.chunk(start),
            TAG_FOOTER => self.footer(start).map(|()| None),
            other => {
                let e = self.record_error(start, None, format!("unknown record tag 0x{other:02x}"));
                Err(self.fatal(e))
            }
        }
    }

    fn chunk(&mut self, start: u64) -> Result<Option<SnapshotChunk>, SnapshotError> {
        let mut prefix = [0u8; RECORD_PREFIX];
        prefix[0] = TAG_CHUNK;
        if !read_exact_or(&mut self.r, &mut prefix[1..])? {
            let e = self.record_error(start, None, "file ends inside the record".into());
            return Err(self.fatal(e));
        }
        let i32_at = |i: usize| i32::from_le_bytes(prefix[i..i + 4].try_into().expect("4 bytes"));
        let pos = ChunkPos::new(i32_at(1), i32_at(5), i32_at(9));
        let version = u64::from_le_bytes(prefix[13..21].try_into().expect("8 bytes"));
        let len = u32::from_le_bytes(prefix[21..25].try_into().expect("4 bytes")) as usize;
        if len > MAX_CHUNK_PAYLOAD {
            let e = self.record_error(
                start,
                Some(pos),
                format!("payload length {len} is over the {MAX_CHUNK_PAYLOAD}-byte limit (corrupt length or position)"),
            );
            return Err(self.fatal(e));
        }
        let mut rest = vec![0u8; len + 8];
        if !read_exact_or(&mut self.r, &mut rest)? {
            let e = self.record_error(start, Some(pos), "file ends inside the record".into());
            return Err(self.fatal(e));
        }
        self.hasher.write(&prefix);
        self.hasher.write(&rest);
        self.offset += (RECORD_PREFIX + len + 8) as u64;
        let index = self.index;
        self.index += 1;
        let stored = u64::from_le_bytes(rest[len..].try_into().expect("8 bytes"));
        let mut h = XxHash3_64::with_seed(0);
        h.write(&prefix);
        h.write(&rest[..len]);
        let computed = h.finish();
        let fail = |reason: String| SnapshotError::Record {
            index,
            offset: start,
            pos: Some(format!("chunk ({}, {}, {})", pos.x, pos.y, pos.z)),
            reason,
        };
        if stored != computed {
            return Err(fail(format!(
                "checksum mismatch: stored {stored:016x}, computed {computed:016x}"
            )));
        }
        if version == 0 {
            return Err(fail("version 0 (unmodified chunks are not stored)".into()));
        }
        if version > strata_terrain::world::MAX_CHUNK_VERSION {
            return Err(fail(format!(
                "version {version} over the highest a chunk may have"
            )));
        }
        if self.last.is_some_and(|l| l >= pos) {
            return Err(fail("out of order or repeated chunk position".into()));
        }
        self.last = Some(pos);
        if self.header.seq == 0 {
            return Err(fail(
                "a snapshot at seq 0 holds no modified chunk (its seq is wrong)".into(),
            ));
        }
        rest.truncate(len);
        Ok(Some(SnapshotChunk {
            index,
            offset: start,
            pos,
            version,
            payload: rest,
        }))
    }

    fn footer(&mut self, start: u64) -> Result<(), SnapshotError> {
        self.stopped = true;
        let mut rest = [0u8; 16];
        if !read_exact_or(&mut self.r, &mut rest)? {
            return Err(SnapshotError::Footer {
                offset: start,
                reason: "file ends inside the footer".into(),
            });
        }
        self.hasher.write(&[TAG_FOOTER]);
        self.hasher.write(&rest[..8]);
        let count = u64::from_le_bytes(rest[..8].try_into().expect("8 bytes"));
        let stored = u64::from_le_bytes(rest[8..].try_into().expect("8 bytes"));
        let computed = self.hasher.finish();
        let footer = |reason| SnapshotError::Footer {
            offset: start,
            reason,
        };
        if count != self.index {
            return Err(footer(format!(
                "says {count} records, the file holds {}",
                self.index
            )));
        }
        if stored != computed {
            return Err(footer(format!(
                "file checksum mismatch: stored {stored:016x}, computed {computed:016x}"
            )));
        }
        let mut extra = [0u8; 1];
        if read_exact_or(&mut self.r, &mut extra)? {
            return Err(footer("bytes after the footer".into()));
        }
        Ok(())
    }
}

/// What [`verify`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VerifyReport {
    pub header: Option<SnapshotHeader>,
    pub chunks: u64,
    /// Each problem, naming its record (first [`MAX_VERIFY_ISSUES`]).
    pub issues: Vec<VerifyIssue>,
    pub issues_dropped: u64,
}

/// One problem, as a sentence naming the record.
pub type VerifyIssue = String;

impl VerifyReport {
    pub fn is_ok(&self) -> bool {
        self.issues.is_empty() && self.issues_dropped == 0
    }

    fn issue(&mut self, e: impl ToString) {
        if self.issues.len() < MAX_VERIFY_ISSUES {
            self.issues.push(e.to_string());
        } else {
            self.issues_dropped += 1;
        }
    }
}

/// Checks every checksum, decodes every chunk, and checks that this build
/// can serve the header's world ([`SnapshotHeader::check_usable`]). `progress` is called
/// with the byte offset reached after each record.
pub fn verify(path: &Path, mut progress: impl FnMut(u64)) -> Result<VerifyReport, SnapshotError> {
    let mut report = VerifyReport {
        header: None,
        chunks: 0,
        issues: Vec::new(),
        issues_dropped: 0,
    };
    let mut reader = match SnapshotReader::open(path) {
        Ok(r) => r,
        Err(SnapshotError::Io(e)) => return Err(SnapshotError::Io(e)),
        Err(e) => {
            report.issue(e);
            return Ok(report);
        }
    };
    report.header = Some(reader.header().clone());
    if let Err(e) = reader.header().check_usable() {
        report.issue(SnapshotError::from(e));
    }
    loop {
        match reader.next_chunk() {
            Ok(Some(c)) => {
                report.chunks += 1;
                if let Err(e) = decode_chunk(&c.payload) {
                    report.issue(SnapshotError::Record {
                        index: c.index,
                        offset: c.offset,
                        pos: Some(format!("chunk ({}, {}, {})", c.pos.x, c.pos.y, c.pos.z)),
                        reason: format!("chunk does not decode: {e}"),
                    });
                }
                progress(reader.offset);
            }
            Ok(None) => break,
            Err(SnapshotError::Io(e)) => return Err(SnapshotError::Io(e)),
            Err(e) => {
                report.issue(e);
                if reader.stopped() {
                    break;
                }
            }
        }
    }
    Ok(report)
}
