//! `strata-admin stats`: world size, modified chunks, sequence, store size,
//! and (online) live sessions.

use std::fmt;

use anyhow::bail;
use clap::Args;
use strata_protocol::admin::{AdminRequest, AdminResponse, ServerStats};
use strata_terrain::ChunkPos;

use super::remote::{open_offline_store, request_once, Target, TargetArgs};
use crate::net::admin_session::store_figures;
use crate::store::ChunkStore;

#[derive(Debug, Args)]
pub struct StatsArgs {
    #[command(flatten)]
    pub target: TargetArgs,
}

/// What `stats` prints.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stats {
    pub last_seq: u64,
    pub modified_chunks: u64,
    pub modified_extent: Option<(ChunkPos, ChunkPos)>,
    pub store_bytes: u64,
    pub world_seed: u64,
    pub generator_version: u32,
    /// Online only.
    pub sessions: Option<u32>,
    pub resident_chunks: Option<u64>,
}

impl From<ServerStats> for Stats {
    fn from(s: ServerStats) -> Self {
        Self {
            last_seq: s.last_seq,
            modified_chunks: s.modified_chunks,
            modified_extent: s.modified_extent,
            store_bytes: s.store_bytes,
            world_seed: s.world_seed,
            generator_version: s.generator_version,
            sessions: Some(s.sessions),
            resident_chunks: Some(s.resident_chunks),
        }
    }
}

impl fmt::Display for Stats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "seq: {}", self.last_seq)?;
        writeln!(f, "modified_chunks: {}", self.modified_chunks)?;
        match self.modified_extent {
            Some((lo, hi)) => writeln!(
                f,
                "world_size: chunks ({}, {}, {}) to ({}, {}, {}), {} x {} x {} chunks",
                lo.x,
                lo.y,
                lo.z,
                hi.x,
                hi.y,
                hi.z,
                i64::from(hi.x) - i64::from(lo.x) + 1,
                i64::from(hi.y) - i64::from(lo.y) + 1,
                i64::from(hi.z) - i64::from(lo.z) + 1
            )?,
            None => writeln!(f, "world_size: unmodified (generated only)")?,
        }
        writeln!(f, "store_bytes: {}", self.store_bytes)?;
        writeln!(f, "world_seed: {}", self.world_seed)?;
        writeln!(f, "generator_version: {}", self.generator_version)?;
        if let Some(s) = self.sessions {
            writeln!(f, "sessions: {s}")?;
        }
        if let Some(r) = self.resident_chunks {
            writeln!(f, "resident_chunks: {r}")?;
        }
        Ok(())
    }
}

/// Statistics of a store (offline).
pub fn offline(store: &dyn ChunkStore) -> anyhow::Result<Stats> {
    let Some(meta) = store.load_meta()? else {
        bail!("the store has no world yet (start the server once)");
    };
    let (extent, store_bytes) = store_figures(store)?;
    Ok(Stats {
        last_seq: meta.last_seq,
        modified_chunks: store.chunk_count()?,
        modified_extent: extent,
        store_bytes,
        world_seed: meta.seed,
        generator_version: meta.generator_version,
        sessions: None,
        resident_chunks: None,
    })
}

pub fn run(args: &StatsArgs) -> anyhow::Result<Stats> {
    match args.target.target()? {
        Target::Offline(dir) => offline(&*open_offline_store(&dir)?),
        Target::Online {
            server,
            cert,
            token,
        } => match request_once(server, &cert, &token, &AdminRequest::Stats)? {
            AdminResponse::Stats(s) => Ok(s.into()),
            other => bail!("unexpected answer {other:?}"),
        },
    }
}
