//! Opening the store the config names: sled in the data dir, or PostgreSQL.

use std::path::Path;
use std::sync::Arc;

use crate::cluster::ClusterConfig;

use super::config::{StoreBackend, StoreConfig};
use super::{ChunkStore, PgStore, SledStore, StoreError, WorldLock};

/// Opens (creating if new) the `[store]` backend: `world_db` is sled's
/// directory, held by its [`WorldLock`] while the store is open; PostgreSQL records `region_chunks` as its region layout, and
/// with `cluster` this node's commits are fenced by its region leases.
pub fn open_store(
    cfg: &StoreConfig,
    world_db: &Path,
    region_chunks: u32,
    cluster: Option<&ClusterConfig>,
) -> Result<Arc<dyn ChunkStore>, StoreError> {
    Ok(match (cfg.backend, cluster) {
        (StoreBackend::Sled, None) => {
            let lock = WorldLock::take_whole(world_db)?;
            Arc::new(SledStore::open_with(world_db, cfg)?.holding(lock))
        }
        (StoreBackend::Sled, Some(_)) => {
            return Err(StoreError::PgSetup {
                reason: "[cluster] needs [store] backend = \"postgres\"".into(),
            })
        }
        (StoreBackend::Postgres, None) => Arc::new(PgStore::open(&cfg.postgres, region_chunks)?),
        (StoreBackend::Postgres, Some(c)) => {
            Arc::new(PgStore::open_node(&cfg.postgres, region_chunks, c)?)
        }
    })
}
