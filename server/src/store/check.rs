//! Offline consistency check of a store: what `strata-admin check` runs.
//!
//! The [`Checker`] is fed every record of the log and chunk trees (in key
//! order) and reports each one that breaks an invariant:
//! - every log record decodes, its key equals its seq, seqs run 1, 2, 3, ...
//!   without gaps, and the meta `last_seq` is the last of them;
//! - a chunk's `to_version`s rise with seq;
//! - every chunk record decodes; its deltas (those past its version)
//!   decode and chain from it, version by version, hash by hash; and the
//!   newest of the two is the highest `to_version` the log gives the chunk
//!   (no chunk without a log entry, no log entry whose chunk is missing,
//!   no delta without its chunk record);
//! - nothing else is stored: no meta key besides the world record and
//!   `last_seq`, and no tree besides meta, chunks, log and blobs (records
//!   there are orphans no code reads).

use std::collections::BTreeMap;
use std::fmt;

use strata_terrain::chunk_codec::decode_chunk;
use strata_terrain::ChunkPos;

use super::keys::{chunk_pos_from_key, delta_from_key, seq_from_key, show_pos, show_raw};
use super::record::{decode_delta, decode_log_entry, is_generated, split_chunk_value};

/// Issues kept in a report; past this only the count grows, so checking a
/// badly broken store cannot exhaust memory.
pub const MAX_REPORTED_ISSUES: usize = 1000;

/// One record that breaks an invariant.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CheckIssue {
    /// The store has log or chunk records but no world metadata.
    MissingMeta,
    /// Metadata or `last_seq` does not decode.
    BadMeta {
        reason: String,
    },
    BadLogKey {
        key: String,
    },
    BadLogRecord {
        seq: u64,
        reason: String,
    },
    /// Seqs must run 1, 2, 3, ... with nothing missing.
    LogGap {
        expected: u64,
        found: u64,
    },
    /// A chunk's version did not rise at this seq.
    VersionNotIncreasing {
        seq: u64,
        pos: ChunkPos,
        to_version: u64,
        previous: u64,
    },
    LastSeqMismatch {
        meta: u64,
        log: u64,
    },
    BadChunkKey {
        key: String,
    },
    BadChunkRecord {
        pos: ChunkPos,
        reason: String,
    },
    /// A stored chunk that no log entry changed.
    OrphanChunk {
        pos: ChunkPos,
        version: u64,
    },
    /// The log changed this chunk but the store does not hold it.
    MissingChunk {
        pos: ChunkPos,
        logged_version: u64,
        seq: u64,
    },
    VersionMismatch {
        pos: ChunkPos,
        stored: u64,
        logged: u64,
        seq: u64,
    },
    BadDeltaKey {
        key: String,
    },
    /// A delta that does not decode or does not continue its chunk's chain.
    BadDelta {
        pos: ChunkPos,
        to_version: u64,
        reason: String,
    },
    /// A meta record this version does not write.
    UnknownMetaKey {
        key: String,
    },
    /// A tree this version does not use, with its record count.
    UnknownTree {
        name: String,
        records: u64,
    },
}

impl fmt::Display for CheckIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use CheckIssue::*;
        match self {
            MissingMeta => write!(f, "meta: no world metadata, but the store holds records"),
            BadMeta { reason } => write!(f, "meta: {reason}"),
            BadLogKey { key } => write!(f, "log key {key}: not an 8-byte seq"),
            BadLogRecord { seq, reason } => write!(f, "log seq {seq}: {reason}"),
            LogGap { expected, found } => {
                write!(f, "log seq {found}: expected seq {expected} next (gap)")
            }
            VersionNotIncreasing {
                seq,
                pos,
                to_version,
                previous,
            } => write!(
                f,
                "log seq {seq}: {} moved to version {to_version}, not above {previous}",
                show_pos(*pos)
            ),
            LastSeqMismatch { meta, log } => {
                write!(f, "meta: last_seq is {meta} but the last log seq is {log}")
            }
            BadChunkKey { key } => write!(f, "chunk key {key}: not a 12-byte position"),
            BadChunkRecord { pos, reason } => write!(f, "{}: {reason}", show_pos(*pos)),
            OrphanChunk { pos, version } => write!(
                f,
                "{} (version {version}): stored but no log entry changed it",
                show_pos(*pos)
            ),
            MissingChunk {
                pos,
                logged_version,
                seq,
            } => write!(
                f,
                "{}: log seq {seq} moved it to version {logged_version} but it is not stored",
                show_pos(*pos)
            ),
            VersionMismatch {
                pos,
                stored,
                logged,
                seq,
            } => write!(
                f,
                "{}: stored at version {stored} but log seq {seq} moved it to {logged}",
                show_pos(*pos)
            ),
            BadDeltaKey { key } => write!(f, "delta key {key}: not a position and a version"),
            BadDelta {
                pos,
                to_version,
                reason,
            } => write!(
                f,
                "{} delta to version {to_version}: {reason}",
                show_pos(*pos)
            ),
            UnknownMetaKey { key } => {
                write!(
                    f,
                    "meta key {key}: orphaned record (not written by this version)"
                )
            }
            UnknownTree { name, records } => write!(
                f,
                "tree {name}: {records} orphaned records in a tree this version does not use"
            ),
        }
    }
}

/// What `check` found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CheckReport {
    pub log_entries: u64,
    pub chunks: u64,
    /// The first [`MAX_REPORTED_ISSUES`] issues, in the order found.
    pub issues: Vec<CheckIssue>,
    /// Issues beyond those kept in `issues`.
    pub issues_dropped: u64,
}

impl CheckReport {
    pub fn is_ok(&self) -> bool {
        self.issues.is_empty() && self.issues_dropped == 0
    }
}

/// Accumulates a [`CheckReport`]; feed all log records, then all chunk
/// records, then call [`Checker::finish`].
#[derive(Debug, Default)]
pub struct Checker {
    report: CheckReport,
    last_log_seq: u64,
    /// Highest to_version per chunk, and the seq that set it.
    logged: BTreeMap<ChunkPos, (u64, u64)>,
    /// Per stored chunk: its newest version so far (record, then deltas)
    /// and the target hash of its last delta.
    stored: BTreeMap<ChunkPos, (u64, Option<u64>)>,
    /// Seq of the snapshot the store was restored from (0: none).
    log_base: u64,
    /// Seqs the log may jump forward to: the first seqs of cluster nodes'
    /// seq blocks (`store/pg/seqs.rs`), and where a block's log was
    /// pruned to.
    block_starts: std::collections::BTreeSet<u64>,
    /// Entries were pruned from the log (`[store] log_retention`): a
    /// chunk need not have one.
    pruned: bool,
    /// The highest seq a block's log was pruned to: the store's last seq
    /// may be that, with no entry left above it.
    pruned_to: u64,
}

impl Checker {
    pub fn new() -> Self {
        Self::default()
    }

    /// A checker for a store restored from a snapshot at seq `base`: its
    /// log starts at `base + 1`, and chunks stored at restore have no entry.
    pub fn with_log_base(base: u64) -> Self {
        Self {
            last_log_seq: base,
            log_base: base,
            ..Self::default()
        }
    }

    /// Lets the log skip forward to any of `starts` (a node numbering from
    /// a new block leaves the rest of its old one unused).
    pub fn allow_jumps_to(&mut self, starts: std::collections::BTreeSet<u64>) {
        self.block_starts = starts;
    }

    /// The log was pruned inside seq blocks too, to the seqs before
    /// `starts` (a chunk last changed there has no entry left).
    pub fn allow_pruned(&mut self, starts: std::collections::BTreeSet<u64>) {
        self.pruned |= !starts.is_empty();
        if let Some(&last) = starts.last() {
            self.pruned_to = self.pruned_to.max(last - 1);
        }
        self.block_starts.extend(starts);
    }

    fn issue(&mut self, i: CheckIssue) {
        if self.report.issues.len() < MAX_REPORTED_ISSUES {
            self.report.issues.push(i);
        } else {
            self.report.issues_dropped += 1;
        }
    }

    pub fn meta_issue(&mut self, reason: String) {
        self.issue(CheckIssue::BadMeta { reason });
    }

    /// A meta key other than the world record, `last_seq` and `log_base`.
    pub fn unknown_meta_key(&mut self, key: &[u8]) {
        self.issue(CheckIssue::UnknownMetaKey { key: show_raw(key) });
    }

    /// A tree other than the store's own, holding `records` records.
    pub fn unknown_tree(&mut self, name: &[u8], records: u64) {
        self.issue(CheckIssue::UnknownTree {
            name: show_raw(name),
            records,
        });
    }

    /// A log page that does not split into the entries its key names.
    pub fn bad_log_page(&mut self, first: u64, reason: String) {
        self.report.log_entries += 1;
        self.issue(CheckIssue::BadLogRecord {
            seq: first,
            reason: format!("page: {reason}"),
        });
    }

    /// One log entry's record, in seq order.
    pub fn log_record(&mut self, key: &[u8], value: &[u8]) {
        self.report.log_entries += 1;
        let Some(seq) = seq_from_key(key) else {
            return self.issue(CheckIssue::BadLogKey { key: show_raw(key) });
        };
        // Saturating: a damaged key or base may hold the largest seq.
        let expected = self.last_log_seq.saturating_add(1);
        if seq != expected && !(seq > expected && self.block_starts.contains(&seq)) {
            self.issue(CheckIssue::LogGap {
                expected,
                found: seq,
            });
        }
        self.last_log_seq = seq;
        let entry = match decode_log_entry(seq, value) {
            Ok(e) => e,
            Err(e) => {
                return self.issue(CheckIssue::BadLogRecord {
                    seq,
                    reason: e.to_string(),
                })
            }
        };
        for (pos, v) in entry.changes {
            match self.logged.insert(pos, (v, seq)) {
                Some((previous, _)) if previous >= v => {
                    // Keep the highest version as the one the chunk must have.
                    self.logged.insert(pos, (previous, seq));
                    self.issue(CheckIssue::VersionNotIncreasing {
                        seq,
                        pos,
                        to_version: v,
                        previous,
                    });
                }
                _ => {}
            }
        }
    }

    /// One chunk record, after all log records.
    pub fn chunk_record(&mut self, key: &[u8], value: &[u8]) {
        self.report.chunks += 1;
        let Some(pos) = chunk_pos_from_key(key) else {
            return self.issue(CheckIssue::BadChunkKey { key: show_raw(key) });
        };
        let (version, body) = match split_chunk_value(pos, value) {
            Ok(x) => x,
            Err(e) => {
                self.logged.remove(&pos);
                return self.issue(CheckIssue::BadChunkRecord {
                    pos,
                    reason: e.to_string(),
                });
            }
        };
        if is_generated(body) {
            // The generator's output, which its deltas must follow.
            if version != 0 {
                self.issue(CheckIssue::BadChunkRecord {
                    pos,
                    reason: format!("a generated record at version {version}"),
                });
            }
        } else if let Err(e) = decode_chunk(body) {
            self.issue(CheckIssue::BadChunkRecord {
                pos,
                reason: format!("snapshot does not decode: {e}"),
            });
        }
        self.stored.insert(pos, (version, None));
    }

    /// One delta record, after all chunk records, in key order.
    pub fn delta_record(&mut self, key: &[u8], value: &[u8]) {
        let Some((pos, to_version)) = delta_from_key(key) else {
            return self.issue(CheckIssue::BadDeltaKey { key: show_raw(key) });
        };
        let bad = |reason: String| CheckIssue::BadDelta {
            pos,
            to_version,
            reason,
        };
        let d = match decode_delta(pos, to_version, value) {
            Ok(d) => d,
            Err(e) => return self.issue(bad(e.to_string())),
        };
        let Some((head, last_hash)) = self.stored.get(&pos).copied() else {
            return self.issue(bad("no chunk record to apply to".into()));
        };
        if to_version <= head && last_hash.is_none() {
            return; // already in the record: a fold will remove it
        }
        if d.from_version != head || last_hash.is_some_and(|h| h != d.base_hash) {
            return self.issue(bad(format!(
                "the chain is at version {head}, this delta starts at {}",
                d.from_version
            )));
        }
        self.stored.insert(pos, (to_version, Some(d.target_hash)));
    }

    /// Closes the check. `meta_last_seq` is `None` when the store has no
    /// world metadata.
    pub fn finish(mut self, meta_last_seq: Option<u64>) -> CheckReport {
        for (pos, (version, _)) in std::mem::take(&mut self.stored) {
            match self.logged.remove(&pos) {
                None if self.log_base > 0 || self.pruned => {}
                None => self.issue(CheckIssue::OrphanChunk { pos, version }),
                Some((logged, seq)) if logged != version => {
                    self.issue(CheckIssue::VersionMismatch {
                        pos,
                        stored: version,
                        logged,
                        seq,
                    })
                }
                Some(_) => {}
            }
        }
        for (pos, (logged_version, seq)) in std::mem::take(&mut self.logged) {
            self.issue(CheckIssue::MissingChunk {
                pos,
                logged_version,
                seq,
            });
        }
        match meta_last_seq {
            // A block pruned to its end leaves the last seq above the log.
            Some(meta) if meta != self.last_log_seq.max(self.pruned_to) => {
                self.issue(CheckIssue::LastSeqMismatch {
                    meta,
                    log: self.last_log_seq,
                })
            }
            Some(_) => {}
            None if self.report.log_entries > 0 || self.report.chunks > 0 => {
                self.issue(CheckIssue::MissingMeta)
            }
            None => {}
        }
        self.report
    }
}
