//! Snapshot files: a consistent copy of a world at one sequence number.
//! The byte format is specified in SNAPSHOT.md and in [`format`].
//!
//! [`writer`] writes one as chunk records arrive (online from the admin
//! protocol, offline from a store); [`reader`] checks every checksum and
//! decodes every chunk; [`diff`] compares two; [`restore`] turns one into a
//! fresh data dir.

pub mod diff;
pub mod error;
pub mod format;
pub mod reader;
pub mod restore;
pub mod writer;

pub use error::{HeaderProblem, SnapshotError};
pub use format::{SnapshotHeader, SNAPSHOT_FORMAT_VERSION, SNAPSHOT_MAGIC};
pub use reader::{verify, SnapshotChunk, SnapshotReader, VerifyIssue, VerifyReport};
pub use writer::SnapshotWriter;
