//! Why a snapshot could not be read or written.

use thiserror::Error;

#[derive(Debug, Error)]
pub enum SnapshotError {
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// The header is unreadable: nothing after it can be trusted.
    #[error("header: {0}")]
    Header(String),
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
