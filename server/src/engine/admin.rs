//! Admin requests that need the engine thread: live sessions, kicks,
//! protected zones, a chunk's current state, and snapshot registration.
//! Admin sessions reach these through [`super::Command::Admin`]; player
//! sessions have no way to send one.

use std::sync::Arc;

use strata_protocol::admin::{PlayerInfo, SnapshotInfo, ZoneSpec};
use strata_protocol::ErrorCode;
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::ChunkPos;
use tokio::sync::oneshot;
use tracing::info;

use super::snapshot::PreImages;
use super::Engine;
use crate::validate::zones::Zone;

/// What the engine alone knows for `stats`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EngineStats {
    pub last_seq: u64,
    pub sessions: u32,
    pub resident_chunks: u64,
    pub modified_chunks: u64,
    pub queued_edits: u32,
}

/// A snapshot just registered: its seq, header data and pre-images.
#[derive(Debug)]
pub struct SnapshotStart {
    pub info: SnapshotInfo,
    pub preimages: Arc<PreImages>,
}

/// An admin request for the engine thread, with where to answer.
#[derive(Debug)]
pub enum AdminCommand {
    Stats(oneshot::Sender<EngineStats>),
    Players(oneshot::Sender<Vec<PlayerInfo>>),
    /// Ends every session of the player; answers how many.
    Kick {
        player: String,
        reply: oneshot::Sender<u32>,
    },
    Zones(oneshot::Sender<Vec<ZoneSpec>>),
    /// The zones as stored after a change, or as another node changed
    /// them (`net/admin_zones.rs`): they replace the engine's.
    SetZones {
        zones: Vec<Zone>,
        reply: oneshot::Sender<Vec<ZoneSpec>>,
    },
    /// The chunk's current version and chunk codec bytes.
    Chunk {
        pos: ChunkPos,
        reply: oneshot::Sender<Result<(u64, Vec<u8>), String>>,
    },
    SnapshotBegin {
        max_pending_chunks: usize,
        world_seed: u64,
        generator_version: u32,
        generator_params: String,
        reply: oneshot::Sender<Result<SnapshotStart, String>>,
    },
}

pub fn zone_spec(z: &Zone) -> ZoneSpec {
    ZoneSpec {
        name: z.name.clone(),
        min: z.min,
        max: z.max,
    }
}

impl Engine {
    pub(super) fn admin(&mut self, cmd: AdminCommand) {
        match cmd {
            AdminCommand::Stats(reply) => {
                let _ = reply.send(EngineStats {
                    // Not the sequencer's: a cluster node's runs ahead after a
                    // fenced batch (its next seq block's floor).
                    last_seq: self.durable_seq,
                    sessions: self.peers.len() as u32,
                    resident_chunks: self.seq.world().loaded() as u64,
                    modified_chunks: self.versions.len() as u64,
                    queued_edits: (self.seq.queued() + self.seq.sighting()) as u32,
                });
            }
            AdminCommand::Players(reply) => {
                let mut list: Vec<PlayerInfo> = self
                    .peers
                    .keys()
                    .filter_map(|&id| {
                        let s = self.seq.session(id)?;
                        Some(PlayerInfo {
                            session: id,
                            player: s.player.clone(),
                            role: s.role,
                            position: s.position.map(|p| p.feet),
                        })
                    })
                    .collect();
                list.sort_by_key(|p| p.session);
                let _ = reply.send(list);
            }
            AdminCommand::Kick { player, reply } => {
                let ids = self.sessions_of(&player);
                for &id in &ids {
                    self.end_session(id, ErrorCode::Kicked, "kicked by an administrator");
                }
                info!(%player, sessions = ids.len(), "kicked");
                let _ = reply.send(ids.len() as u32);
            }
            AdminCommand::Zones(reply) => {
                let _ = reply.send(self.seq.zones().iter().map(zone_spec).collect());
            }
            AdminCommand::SetZones { zones, reply } => {
                self.seq.set_zones(zones);
                let _ = reply.send(self.seq.zones().iter().map(zone_spec).collect());
            }
            AdminCommand::Chunk { pos, reply } => {
                let result = self
                    .make_resident(&[pos])
                    .map(|()| {
                        let version = self.versions.get(&pos).copied().unwrap_or(0);
                        (version, encode_chunk(&self.seq.chunk(pos)))
                    })
                    .map_err(|e| e.to_string());
                let _ = reply.send(result);
            }
            AdminCommand::SnapshotBegin {
                max_pending_chunks,
                world_seed,
                generator_version,
                generator_params,
                reply,
            } => {
                let result = self.begin_snapshot(max_pending_chunks).map(|preimages| {
                    info!(seq = preimages.seq(), "snapshot started");
                    SnapshotStart {
                        info: SnapshotInfo {
                            seq: preimages.seq(),
                            world_seed,
                            generator_version,
                            generator_params,
                            zones: self.seq.zones().iter().map(zone_spec).collect(),
                            modified_chunks: self.versions.len() as u64,
                        },
                        preimages,
                    }
                });
                let _ = reply.send(result);
            }
        }
    }
}
