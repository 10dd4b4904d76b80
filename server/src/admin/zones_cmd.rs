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

use super::remote::{offline_config, open_offline_store_as, Target, TargetArgs};
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
    /// Offline: the server's config: its [store], and its spawn protection when no
    /// zones are stored [default: the data dir's strata.toml, else the defaults].
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
    /// Offline: the server's config: its [store], and its spawn protection when no
    /// zones are stored [default: the data dir's strata.toml, else the defaults].
    #[arg(long)]
    pub config: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct ZoneRemoveArgs {
    pub name: String,
    #[command(flatten)]
    pub target: TargetArgs,
    /// Offline: the server's config: its [store], and its spawn protection when no
    /// zones are stored [default: the data dir's strata.toml, else the defaults].
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

/// Makes `change` to the stored zones (a cluster's running nodes may
/// change them meanwhile, on a shared database: written only over what
/// was read); `defaults` are those a server starts with when none are.
fn save(
    (store, defaults): (&dyn ChunkStore, Vec<Zone>),
    change: &ZoneChange,
) -> anyhow::Result<Vec<ZoneSpec>> {
    let zones = stored_zones::change(store, &defaults, change)?;
    Ok(zones.iter().map(zone_spec).collect())
}

fn online(target: &TargetArgs, req: AdminRequest) -> anyhow::Result<Option<Vec<ZoneSpec>>> {
    match target.request_if_online(&req)? {
        None => Ok(None),
        Some(AdminResponse::Zones(z)) => Ok(Some(z)),
        Some(other) => bail!("unexpected answer {other:?}"),
    }
}

/// A stopped server's store and the zones it starts with when none are
/// stored: both from `config` when given, else from the data dir's own
/// `strata.toml` (else the defaults), as the server would.
fn offline_store(
    target: &TargetArgs,
    config: Option<&std::path::Path>,
) -> anyhow::Result<(std::sync::Arc<dyn crate::store::ChunkStore>, Vec<Zone>)> {
    match target.target()? {
        Target::Offline(dir) => {
            let cfg = offline_config(&dir, config)?;
            let store = open_offline_store_as(&dir, config)?;
            Ok((store, Sequencer::default_zones(&cfg.validation)))
        }
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
            let (store, defaults) = offline_store(&a.target, a.config.as_deref())?;
            let zones = match stored_zones::stored(&*store)? {
                Some(z) => z,
                None => defaults,
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
            let (store, defaults) = offline_store(&a.target, a.config.as_deref())?;
            save((&*store, defaults), &ZoneChange::Add(zone))
        }
        ZonesCommand::Remove(a) => {
            let req = AdminRequest::ZoneRemove {
                name: a.name.clone(),
            };
            if let Some(z) = online(&a.target, req)? {
                return Ok(z);
            }
            let (store, defaults) = offline_store(&a.target, a.config.as_deref())?;
            save((&*store, defaults), &ZoneChange::Remove(a.name.clone()))
        }
    }
}
