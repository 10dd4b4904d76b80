//! `strata-admin zones add|remove|list`. Online changes persist in the
//! store, then take effect in the running sequencer (and on a cluster's
//! other nodes within `ZONES_RELOAD_PERIOD`); offline ones edit the stored
//! zones of a stopped server.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand};
use strata_protocol::admin::{AdminRequest, AdminResponse, ZoneSpec};
use strata_terrain::VoxelPos;

use super::remote::{open_offline_store, Target, TargetArgs};
use crate::config::ServerConfig;
use crate::engine::admin::zone_spec;
use crate::sequencer::Sequencer;
use crate::store::ChunkStore;
use crate::stored_zones::{self, ZoneChange};
use crate::validate::zones::Zone;

#[derive(Debug, Subcommand)]
pub enum ZonesCommand {
    /// List the protected zones.
    List(ZonesListArgs),
    /// Add a protected box (inclusive voxel corners) where players may not edit.
    Add(ZoneAddArgs),
    /// Remove a protected zone by name.
    Remove(ZoneRemoveArgs),
}

#[derive(Debug, Args)]
pub struct ZonesListArgs {
    #[command(flatten)]
    pub target: TargetArgs,
    /// Offline: server config whose spawn protection applies when no zones are stored.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ZoneAddArgs {
    /// Zone name (1 to 64 bytes).
    pub name: String,
    /// Minimum corner: X Y Z (voxels).
    #[arg(long, num_args = 3, value_names = ["X", "Y", "Z"], allow_negative_numbers = true)]
    pub min: Vec<i32>,
    /// Maximum corner: X Y Z (voxels, inclusive).
    #[arg(long, num_args = 3, value_names = ["X", "Y", "Z"], allow_negative_numbers = true)]
    pub max: Vec<i32>,
    #[command(flatten)]
    pub target: TargetArgs,
    /// Offline: server config whose spawn protection applies when no zones are stored.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ZoneRemoveArgs {
    pub name: String,
    #[command(flatten)]
    pub target: TargetArgs,
    /// Offline: server config whose spawn protection applies when no zones are stored.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

fn voxel(v: &[i32]) -> anyhow::Result<VoxelPos> {
    match v {
        [x, y, z] => Ok(VoxelPos::new(*x, *y, *z)),
        _ => bail!("a corner needs three coordinates"),
    }
}

/// One line per zone.
pub fn render(zones: &[ZoneSpec]) -> String {
    let mut out = String::new();
    for z in zones {
        let _ = writeln!(
            out,
            "{} ({}, {}, {}) to ({}, {}, {})",
            z.name, z.min.x, z.min.y, z.min.z, z.max.x, z.max.y, z.max.z
        );
    }
    out
}

/// The zones a stopped server starts with when none are stored.
fn defaults(config: Option<&std::path::Path>) -> anyhow::Result<Vec<Zone>> {
    Ok(Sequencer::default_zones(
        &ServerConfig::load(config)?.validation,
    ))
}

/// Makes `change` to the stored zones (a cluster's running nodes may
/// change them meanwhile, on a shared database: written only over what
/// was read).
fn save(
    store: &dyn ChunkStore,
    config: Option<&std::path::Path>,
    change: &ZoneChange,
) -> anyhow::Result<Vec<ZoneSpec>> {
    let zones = stored_zones::change(store, &defaults(config)?, change)?;
    Ok(zones.iter().map(zone_spec).collect())
}

fn online(target: &TargetArgs, req: AdminRequest) -> anyhow::Result<Option<Vec<ZoneSpec>>> {
    match target.request_if_online(&req)? {
        None => Ok(None),
        Some(AdminResponse::Zones(z)) => Ok(Some(z)),
        Some(other) => bail!("unexpected answer {other:?}"),
    }
}

fn offline_store(
    target: &TargetArgs,
) -> anyhow::Result<std::sync::Arc<dyn crate::store::ChunkStore>> {
    match target.target()? {
        Target::Offline(dir) => open_offline_store(&dir),
        Target::Online { .. } => unreachable!("online handled first"),
    }
}

/// Runs a zones command; returns the zones after it.
pub fn run(cmd: &ZonesCommand) -> anyhow::Result<Vec<ZoneSpec>> {
    match cmd {
        ZonesCommand::List(a) => {
            if let Some(z) = online(&a.target, AdminRequest::Zones)? {
                return Ok(z);
            }
            let store = offline_store(&a.target)?;
            let zones = match stored_zones::stored(&*store)? {
                Some(z) => z,
                None => defaults(a.config.as_deref())?,
            };
            Ok(zones.iter().map(zone_spec).collect())
        }
        ZonesCommand::Add(a) => {
            let zone = Zone {
                name: a.name.clone(),
                min: voxel(&a.min)?,
                max: voxel(&a.max)?,
            };
            if let Some(z) = online(&a.target, AdminRequest::ZoneAdd(zone_spec(&zone)))? {
                return Ok(z);
            }
            let store = offline_store(&a.target)?;
            save(&*store, a.config.as_deref(), &ZoneChange::Add(zone))
        }
        ZonesCommand::Remove(a) => {
            let req = AdminRequest::ZoneRemove {
                name: a.name.clone(),
            };
            if let Some(z) = online(&a.target, req)? {
                return Ok(z);
            }
            let store = offline_store(&a.target)?;
            save(
                &*store,
                a.config.as_deref(),
                &ZoneChange::Remove(a.name.clone()),
            )
        }
    }
}
