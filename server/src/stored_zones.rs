//! Protected zones as the store holds them (the blob [`ZONES_BLOB`], JSON).
//! A cluster's nodes share it: a change starts from the stored zones, not
//! from a node's copy, and is written only over the bytes it read
//! ([`ChunkStore::swap_blob`]), so two nodes' changes never erase each
//! other. Nodes read it again every [`ZONES_RELOAD_PERIOD`]
//! (`net/admin_zones.rs`).

use std::time::Duration;

use thiserror::Error;

use crate::store::{ChunkStore, StoreError};
use crate::validate::zones::{check_new, Zone, ZoneError};

/// Blob name under which protected zones are stored.
pub const ZONES_BLOB: &str = "zones";

/// How often a running server reads the stored zones again, taking up
/// changes made elsewhere (another node, or `strata-admin zones` offline
/// on a shared database).
pub const ZONES_RELOAD_PERIOD: Duration = Duration::from_secs(5);

/// Reads and swaps one zone change tries while other writers keep
/// changing the stored zones under it.
pub const ZONE_WRITE_ATTEMPTS: usize = 8;

#[derive(Debug, Error)]
pub enum ZonesError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("stored protected zones do not parse: {0}")]
    Parse(#[from] serde_json::Error),
    #[error(transparent)]
    Zone(#[from] ZoneError),
    #[error("no zone named {0:?}")]
    NoSuchZone(String),
    #[error("the stored zones changed under this change {ZONE_WRITE_ATTEMPTS} times; nothing was written, try again")]
    Contended,
}

/// What a change does to the zones.
#[derive(Debug, Clone)]
pub enum ZoneChange {
    Add(Zone),
    Remove(String),
}

impl ZoneChange {
    fn apply(&self, zones: &mut Vec<Zone>) -> Result<(), ZonesError> {
        match self {
            ZoneChange::Add(z) => {
                check_new(zones, z)?;
                zones.push(z.clone());
            }
            ZoneChange::Remove(name) => {
                let Some(i) = zones.iter().position(|z| &z.name == name) else {
                    return Err(ZonesError::NoSuchZone(name.clone()));
                };
                zones.remove(i);
            }
        }
        Ok(())
    }
}

/// The stored zones, `None` when none are stored (a server then uses its
/// configured defaults).
pub fn stored(store: &dyn ChunkStore) -> Result<Option<Vec<Zone>>, ZonesError> {
    match store.get_blob(ZONES_BLOB)? {
        Some(bytes) => Ok(Some(serde_json::from_slice(&bytes)?)),
        None => Ok(None),
    }
}

/// Applies `change` to the stored zones (`defaults` when none are stored)
/// and writes them, durably, only over what was read; returns the zones
/// written. A refused change writes nothing.
pub fn change(
    store: &dyn ChunkStore,
    defaults: &[Zone],
    change: &ZoneChange,
) -> Result<Vec<Zone>, ZonesError> {
    for _ in 0..ZONE_WRITE_ATTEMPTS {
        let raw = store.get_blob(ZONES_BLOB)?;
        let mut zones = match &raw {
            Some(bytes) => serde_json::from_slice(bytes)?,
            None => defaults.to_vec(),
        };
        change.apply(&mut zones)?;
        let bytes = serde_json::to_vec(&zones)?;
        if store.swap_blob(ZONES_BLOB, raw.as_deref(), &bytes)? {
            return Ok(zones);
        }
    }
    Err(ZonesError::Contended)
}
