//! `strata-admin verify-acks`: proves that every edit a client saw
//! acknowledged is in the stored world.
//!
//! The ack log is written by `strata-bots --ack-log FILE`: one JSON object
//! per line, an [`AckRecord`]:
//!
//! ```text
//! {"seq":17,"chunks":[{"x":16,"y":1,"z":16,"version":4}]}
//! ```
//!
//! `seq` is the edit's global sequence number and `chunks` every chunk it
//! changed with the version it moved that chunk to (from `EditAccepted`).
//! The check passes when, for every record, the store's edit log reaches
//! `seq` and holds that entry with the same chunk versions, and every chunk
//! is stored at that version or later; and no seq is acknowledged twice in
//! the ack log (a seq handed out again, say after a crash lost the first
//! edit: the second ack may name the very same chunk versions) or appears
//! twice in the store's log over the acknowledged seqs. Run it while the
//! server is stopped.
//!
//! The records carry no player or client edit id, so the stored entry's
//! player is not compared with the acknowledging client.

use std::collections::HashSet;
use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};

use clap::Args;
use serde::Serialize;
pub use strata_protocol::ack::{AckChunk, AckRecord};
use strata_terrain::ChunkPos;
use thiserror::Error;

use super::remote::open_offline_store;
use crate::datadir::DataDir;
use crate::store::{ChunkStore, StoreError};

/// Failures listed in a report; the count covers all of them.
pub const MAX_REPORTED_FAILURES: usize = 32;
/// Longest ack-log line accepted, in bytes.
pub const MAX_ACK_LINE_BYTES: usize = 64 * 1024;

#[derive(Debug, Args)]
pub struct VerifyAcksArgs {
    /// The server's data directory (stop the server first).
    #[arg(long)]
    pub data_dir: PathBuf,
    /// The ack log written by `strata-bots --ack-log`.
    pub file: PathBuf,
}

/// Why verification could not run (as opposed to finding lost edits).
#[derive(Debug, Error)]
pub enum VerifyError {
    #[error("cannot read ack log {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("ack log line {line}: {reason}")]
    Parse { line: usize, reason: String },
    #[error("opening data dir: {0}")]
    DataDir(String),
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The data dir's store (the backend its `strata.toml` names) did not open.
    #[error("opening the store: {0}")]
    Open(String),
}

/// An acknowledged edit the store does not hold.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum AckFailure {
    /// The store's log ends before the edit.
    SeqNotLogged { seq: u64, last_seq: u64 },
    /// The log entry exists but names other chunk versions (or another seq).
    LogDiffers { seq: u64 },
    /// The ack log holds the seq again: the server acknowledged two edits
    /// with one seq.
    AckedTwice { seq: u64 },
    /// The store's log holds the seq more than once.
    LoggedTwice { seq: u64 },
    /// A chunk is stored at an older version than acknowledged.
    ChunkBehind {
        seq: u64,
        x: i32,
        y: i32,
        z: i32,
        acked: u64,
        stored: u64,
    },
}

/// What verification found.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct VerifyReport {
    pub records: u64,
    pub chunks: u64,
    pub last_seq: u64,
    /// Records whose log entries are gone (pruned by `[store]
    /// log_retention`, or from before the snapshot the world was restored
    /// from): their chunks are checked.
    pub pruned: u64,
    /// Every failure counted; the first [`MAX_REPORTED_FAILURES`] listed.
    pub failure_count: u64,
    pub failures: Vec<AckFailure>,
}

impl VerifyReport {
    pub fn ok(&self) -> bool {
        self.failure_count == 0
    }

    fn fail(&mut self, f: AckFailure) {
        self.failure_count += 1;
        if self.failures.len() < MAX_REPORTED_FAILURES {
            self.failures.push(f);
        }
    }
}

/// Reads an ack log; blank lines are skipped.
pub fn read_ack_log(path: &Path) -> Result<Vec<AckRecord>, VerifyError> {
    let io = |source| VerifyError::Io {
        path: path.display().to_string(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let mut reader = BufReader::new(file);
    let mut out = Vec::new();
    let mut bytes = Vec::new();
    for i in 0.. {
        // Never more than a line's bound in memory, whatever the file holds.
        bytes.clear();
        let limit = MAX_ACK_LINE_BYTES as u64 + 2;
        if (&mut reader)
            .take(limit)
            .read_until(b'\n', &mut bytes)
            .map_err(io)?
            == 0
        {
            break;
        }
        let body = bytes.strip_suffix(b"\n").unwrap_or(&bytes);
        let body = body.strip_suffix(b"\r").unwrap_or(body);
        if body.len() > MAX_ACK_LINE_BYTES {
            return Err(VerifyError::Parse {
                line: i + 1,
                reason: format!("longer than {MAX_ACK_LINE_BYTES} bytes"),
            });
        }
        let line = std::str::from_utf8(body).map_err(|e| VerifyError::Parse {
            line: i + 1,
            reason: format!("not UTF-8: {e}"),
        })?;
        if line.trim().is_empty() {
            continue;
        }
        let rec = AckRecord::parse_line(line).map_err(|e| VerifyError::Parse {
            line: i + 1,
            reason: e.to_string(),
        })?;
        out.push(rec);
    }
    Ok(out)
}

/// Checks every record against a store.
pub fn verify(store: &dyn ChunkStore, records: &[AckRecord]) -> Result<VerifyReport, StoreError> {
    let last_seq = store.last_seq()?;
    let mut report = VerifyReport {
        last_seq,
        ..Default::default()
    };
    let mut acked = HashSet::with_capacity(records.len());
    for rec in records {
        report.records += 1;
        report.chunks += rec.chunks.len() as u64;
        if !acked.insert(rec.seq) {
            report.fail(AckFailure::AckedTwice { seq: rec.seq });
        }
        if rec.seq <= last_seq && store.log_pruned_at(rec.seq)? {
            report.pruned += 1;
        } else {
            let Some(entry) = store.log_entry(rec.seq)?.filter(|_| rec.seq <= last_seq) else {
                report.fail(AckFailure::SeqNotLogged {
                    seq: rec.seq,
                    last_seq,
                });
                continue;
            };
            let mut logged = entry.changes.clone();
            let mut acked: Vec<(ChunkPos, u64)> =
                rec.chunks.iter().map(|c| (c.pos(), c.version)).collect();
            logged.sort();
            acked.sort();
            if logged != acked || entry.seq != rec.seq {
                report.fail(AckFailure::LogDiffers { seq: rec.seq });
            }
        }
        for c in &rec.chunks {
            let stored = store.load_chunk(c.pos())?.map_or(0, |s| s.version);
            if stored < c.version {
                report.fail(AckFailure::ChunkBehind {
                    seq: rec.seq,
                    x: c.x,
                    y: c.y,
                    z: c.z,
                    acked: c.version,
                    stored,
                });
            }
        }
    }
    // The store's log over the acknowledged seqs: each seq once.
    if let (Some(&lo), Some(&hi)) = (acked.iter().min(), acked.iter().max()) {
        for seq in logged_twice(store.edit_log(lo..=hi).map(|e| e.map(|e| e.seq)))? {
            report.fail(AckFailure::LoggedTwice { seq });
        }
    }
    Ok(report)
}

/// Seqs a log yields more than once (each named once), in order.
fn logged_twice(
    seqs: impl Iterator<Item = Result<u64, StoreError>>,
) -> Result<Vec<u64>, StoreError> {
    let (mut seen, mut named) = (HashSet::new(), HashSet::new());
    let mut twice = Vec::new();
    for seq in seqs {
        let seq = seq?;
        if !seen.insert(seq) && named.insert(seq) {
            twice.push(seq);
        }
    }
    Ok(twice)
}

/// Opens the data dir's store and verifies the ack log against it.
pub fn run(args: &VerifyAcksArgs) -> Result<VerifyReport, VerifyError> {
    let records = read_ack_log(&args.file)?;
    let dir =
        DataDir::open_existing(&args.data_dir).map_err(|e| VerifyError::DataDir(e.to_string()))?;
    let store = open_offline_store(dir.root()).map_err(|e| VerifyError::Open(format!("{e:#}")))?;
    Ok(verify(&*store, &records)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::SledStore;
    use strata_protocol::ChunkVersion;

    #[test]
    fn lines_round_trip_and_refuse_junk() {
        let rec = AckRecord::new(
            17,
            &[ChunkVersion {
                pos: ChunkPos::new(16, -1, 2),
                version: 4,
            }],
        );
        let line = rec.to_line();
        assert_eq!(
            line,
            r#"{"seq":17,"chunks":[{"x":16,"y":-1,"z":2,"version":4}]}"#
        );
        assert_eq!(AckRecord::parse_line(&line).unwrap(), rec);
        assert!(AckRecord::parse_line(r#"{"seq":1}"#).is_err());
        assert!(AckRecord::parse_line(r#"{"seq":1,"chunks":[],"extra":2}"#).is_err());
    }

    #[test]
    fn an_ack_log_reads_line_by_line_and_refuses_an_overlong_line() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("acks.jsonl");
        let line = AckRecord::new(3, &[]).to_line();
        std::fs::write(&path, format!("{line}\r\n\n{line}")).unwrap();
        assert_eq!(read_ack_log(&path).unwrap().len(), 2);
        // One line far past the bound, no newline: refused by its length.
        let mut long = format!("{line}\n").into_bytes();
        long.resize(long.len() + 4 * MAX_ACK_LINE_BYTES, b'x');
        std::fs::write(&path, &long).unwrap();
        match read_ack_log(&path) {
            Err(VerifyError::Parse { line: 2, reason }) => {
                assert!(reason.contains("longer than"), "{reason}")
            }
            other => panic!("{other:?}"),
        }
        std::fs::write(&path, b"\xff\n").unwrap();
        assert!(matches!(
            read_ack_log(&path),
            Err(VerifyError::Parse { line: 1, .. })
        ));
    }

    #[test]
    fn a_real_store_passes_what_it_holds_and_fails_what_it_lost() {
        use crate::store::{CommitBatch, LogEntry};
        use strata_terrain::{Chunk, Edit, FixedVec3, Voxel};
        let tmp = tempfile::tempdir().unwrap();
        let store = SledStore::open(tmp.path()).unwrap();
        store
            .init_meta(&crate::store::WorldMeta::new(1, 1, "seed = 1\n"))
            .unwrap();
        let pos = ChunkPos::new(3, 0, -2);
        let entry = |seq, version| LogEntry {
            seq,
            player: "bot-0".into(),
            time_ms: 1,
            edit: Edit::Mine {
                center: FixedVec3::from_voxels(100, 5, -60),
                radius: strata_terrain::Fixed::from_voxels(2),
                strength: 255,
            },
            changes: vec![(pos, version)],
        };
        store
            .commit_batch(&CommitBatch {
                entries: vec![entry(1, 1), entry(2, 2)],
                chunks: vec![(pos, 2, Chunk::uniform(Voxel::AIR).into())],
                deltas: Vec::new(),
                generated: Vec::new(),
                last_seq: 2,
                epochs: None,
            })
            .unwrap();
        let ack = |seq, version| AckRecord::new(seq, &[ChunkVersion { pos, version }]);
        let good = verify(&store, &[ack(1, 1), ack(2, 2)]).unwrap();
        assert!(good.ok(), "{good:?}");
        assert_eq!((good.records, good.chunks, good.last_seq), (2, 2, 2));
        let bad = verify(&store, &[ack(2, 3), ack(3, 3)]).unwrap();
        assert_eq!(bad.failure_count, 3);
        assert_eq!(
            bad.failures,
            vec![
                AckFailure::LogDiffers { seq: 2 },
                AckFailure::ChunkBehind {
                    seq: 2,
                    x: 3,
                    y: 0,
                    z: -2,
                    acked: 3,
                    stored: 2
                },
                AckFailure::SeqNotLogged {
                    seq: 3,
                    last_seq: 2
                },
            ]
        );
        // A seq acknowledged twice: the second ack names the same chunk
        // version (an edit lost in a crash, its seq and version reused),
        // so only the repeat gives it away.
        let twice = verify(&store, &[ack(1, 1), ack(2, 2), ack(2, 2)]).unwrap();
        assert_eq!(twice.failures, vec![AckFailure::AckedTwice { seq: 2 }]);
        assert_eq!(twice.failure_count, 1);
        // Pruned from the log: counted so, its chunks still checked.
        assert_eq!(store.prune_log(2, 10).unwrap(), 2);
        let pruned = verify(&store, &[ack(1, 1), ack(2, 2)]).unwrap();
        assert!(pruned.ok(), "{pruned:?}");
        assert_eq!(pruned.pruned, 2);
        let behind = verify(&store, &[ack(2, 3)]).unwrap();
        assert!(matches!(
            behind.failures[..],
            [AckFailure::ChunkBehind { seq: 2, .. }]
        ));
    }

    #[test]
    fn a_seq_the_log_holds_twice_is_named_once() {
        let log = |seqs: &[u64]| logged_twice(seqs.iter().map(|&s| Ok(s))).unwrap();
        assert_eq!(log(&[1, 2, 3]), Vec::<u64>::new());
        assert_eq!(log(&[1, 2, 2, 3, 2, 3]), vec![2, 3]);
        let failed = vec![Ok(1), Err(StoreError::Io(std::io::ErrorKind::Other.into()))];
        assert!(logged_twice(failed.into_iter()).is_err());
    }
}
