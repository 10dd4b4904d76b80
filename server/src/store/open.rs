//! Opening the store the config names: sled in the data dir, or PostgreSQL.

use std::path::Path;
use std::sync::Arc;

use super::config::{StoreBackend, StoreConfig};
use super::{ChunkStore, PgStore, SledStore, StoreError};

/// Opens (creating if new) the `[store]` backend: `world_db` is sled's
/// directory; PostgreSQL records `region_chunks` as its region layout.
pub fn open_store(
    cfg: &StoreConfig,
    world_db: &Path,
    region_chunks: u32,
) -> Result<Arc<dyn ChunkStore>, StoreError> {
    Ok(match cfg.backend {
        StoreBackend::Sled => Arc::new(SledStore::open_with(world_db, cfg)?),
        StoreBackend::Postgres => Arc::new(PgStore::open(&cfg.postgres, region_chunks)?),
    })
}
