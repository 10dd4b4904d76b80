//! Which chunks differ between two snapshots.

use std::io::Read;
use std::path::Path;

use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::hash::chunk_hash;
use strata_terrain::ChunkPos;

use super::error::SnapshotError;
use super::reader::{SnapshotChunk, SnapshotReader};

/// A chunk as one snapshot holds it: version and chunk hash. `None` in a
/// [`ChunkDiff`] side means "not stored": the generator's version 0.
pub type Side = Option<(u64, u64)>;

/// A chunk read from one side: position, then version and hash.
type Entry = (ChunkPos, (u64, u64));

/// One chunk that differs (in version or content).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkDiff {
    pub pos: ChunkPos,
    pub a: Side,
    pub b: Side,
}

/// What [`diff`] found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiffReport {
    pub seq_a: u64,
    pub seq_b: u64,
    pub same_world: bool,
    pub chunks: Vec<ChunkDiff>,
}

fn side(c: &SnapshotChunk) -> Result<(u64, u64), SnapshotError> {
    let chunk = decode_chunk(&c.payload).map_err(|e| SnapshotError::Record {
        index: c.index,
        offset: c.offset,
        pos: Some(format!("chunk ({}, {}, {})", c.pos.x, c.pos.y, c.pos.z)),
        reason: format!("chunk does not decode: {e}"),
    })?;
    Ok((c.version, chunk_hash(&chunk)))
}

fn next<R: Read>(r: &mut SnapshotReader<R>) -> Result<Option<Entry>, SnapshotError> {
    match r.next_chunk()? {
        Some(c) => Ok(Some((c.pos, side(&c)?))),
        None => Ok(None),
    }
}

/// Walks both files in chunk order (they are sorted) and lists every chunk
/// whose version or hash differs. Any corruption is an error.
pub fn diff(a: &Path, b: &Path) -> Result<DiffReport, SnapshotError> {
    let mut ra = SnapshotReader::open(a)?;
    let mut rb = SnapshotReader::open(b)?;
    let (ha, hb) = (ra.header().clone(), rb.header().clone());
    let mut out = DiffReport {
        seq_a: ha.seq,
        seq_b: hb.seq,
        same_world: ha.seed == hb.seed
            && ha.generator_version == hb.generator_version
            && ha.generator_params == hb.generator_params,
        chunks: Vec::new(),
    };
    let (mut x, mut y) = (next(&mut ra)?, next(&mut rb)?);
    loop {
        match (x, y) {
            (None, None) => break,
            (Some((pa, sa)), Some((pb, _))) if pa < pb => {
                out.chunks.push(ChunkDiff {
                    pos: pa,
                    a: Some(sa),
                    b: None,
                });
                x = next(&mut ra)?;
            }
            (Some((pa, sa)), None) => {
                out.chunks.push(ChunkDiff {
                    pos: pa,
                    a: Some(sa),
                    b: None,
                });
                x = next(&mut ra)?;
            }
            (Some((pa, _)), Some((pb, sb))) if pb < pa => {
                out.chunks.push(ChunkDiff {
                    pos: pb,
                    a: None,
                    b: Some(sb),
                });
                y = next(&mut rb)?;
            }
            (None, Some((pb, sb))) => {
                out.chunks.push(ChunkDiff {
                    pos: pb,
                    a: None,
                    b: Some(sb),
                });
                y = next(&mut rb)?;
            }
            (Some((pa, sa)), Some((_, sb))) => {
                if sa != sb {
                    out.chunks.push(ChunkDiff {
                        pos: pa,
                        a: Some(sa),
                        b: Some(sb),
                    });
                }
                x = next(&mut ra)?;
                y = next(&mut rb)?;
            }
        }
    }
    Ok(out)
}
