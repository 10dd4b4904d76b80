//! Why a snapshot could not be read or written.

use thiserror::Error;

use crate::store::MAX_GENERATOR_PARAMS_BYTES;
use crate::validate::zones::ZoneError;

#[derive(Debug, Error)]
pub enum SnapshotError {
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// The header is unreadable: nothing after it can be trusted.
    #[error("header: {0}")]
    Header(String),
    /// The header reads, but names a world this build cannot restore.
    #[error("header: {0}")]
    Unusable(#[from] HeaderProblem),
    /// A record is corrupt; `index` counts chunk records from 0.
    #[error("record {index} at byte {offset}{}: {reason}", pos.as_ref().map(|p| format!(" ({p})")).unwrap_or_default())]
    Record {
        index: u64,
        offset: u64,
        pos: Option<String>,
        reason: String,
    },
    /// The footer (record count, whole-file checksum) is wrong or missing.
    #[error("footer at byte {offset}: {reason}")]
    Footer { offset: u64, reason: String },
    /// A chunk to be written breaks the format's rules.
    #[error("cannot write: {0}")]
    Write(String),
}

/// Why a readable header's world cannot be restored by this build
/// ([`super::SnapshotHeader::check_usable`]).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum HeaderProblem {
    #[error("generator version {found} is not the one this build runs ({supported})")]
    GeneratorVersion { found: u32, supported: u32 },
    #[error("generator params are {len} bytes, limit {MAX_GENERATOR_PARAMS_BYTES}")]
    ParamsTooLong { len: usize },
    #[error("generator params are not valid: {0}")]
    Params(String),
    #[error(
        "seq {seq} is over the highest a world may hold ({})",
        crate::store::MAX_SEQ
    )]
    Seq { seq: u64 },
    #[error("zone {index} ({name:?}): {source}")]
    Zone {
        index: usize,
        name: String,
        #[source]
        source: ZoneError,
    },
}
