//! The ack record: one edit the server acknowledged, with the chunk
//! versions it made durable. `strata-bots --ack-log` writes one JSON line
//! per record and `strata-admin verify-acks` checks them against the store:
//!
//! ```text
//! {"seq":17,"chunks":[{"x":16,"y":1,"z":16,"version":4}]}
//! ```

use serde::{Deserialize, Serialize};
use strata_terrain::ChunkPos;

use crate::ChunkVersion;

/// One chunk an acknowledged edit changed, at the version it reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AckChunk {
    pub x: i32,
    pub y: i32,
    pub z: i32,
    pub version: u64,
}

impl AckChunk {
    pub fn pos(&self) -> ChunkPos {
        ChunkPos::new(self.x, self.y, self.z)
    }
}

/// One line of an ack log: an acknowledged edit.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AckRecord {
    pub seq: u64,
    pub chunks: Vec<AckChunk>,
}

impl AckRecord {
    /// The record of an `EditAccepted { seq, changes }`.
    pub fn new(seq: u64, changes: &[ChunkVersion]) -> Self {
        Self {
            seq,
            chunks: changes
                .iter()
                .map(|c| AckChunk {
                    x: c.pos.x,
                    y: c.pos.y,
                    z: c.pos.z,
                    version: c.version,
                })
                .collect(),
        }
    }

    /// The record as one JSON line, without the newline.
    pub fn to_line(&self) -> String {
        serde_json::to_string(self).expect("plain integers serialize")
    }

    pub fn parse_line(line: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(line)
    }
}
