//! The running server's world as the console reads it: the store's durable
//! chunks over the generator, read chunk by chunk off the engine thread.
//! What it shows is what every client has been acknowledged.

use std::path::PathBuf;
use std::sync::Arc;

use strata_terrain::gen::Generator;
use strata_terrain::{ChunkGenerator, World};

use crate::admin::world_source::{insert_raw, ChunkBox, WorldSourceError, WorldView};
use crate::store::ChunkStore;

/// How long a read waits for the commit it saw to be fsynced.
const SETTLE_WITHIN: std::time::Duration = std::time::Duration::from_secs(5);

/// Store plus generator of a running server.
#[derive(Clone)]
pub struct LiveWorld {
    store: Arc<dyn ChunkStore>,
    generator: Arc<Generator>,
}

impl std::fmt::Debug for LiveWorld {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveWorld").finish_non_exhaustive()
    }
}

impl LiveWorld {
    pub fn new(store: Arc<dyn ChunkStore>, generator: Arc<Generator>) -> Self {
        Self { store, generator }
    }

    pub fn store(&self) -> &Arc<dyn ChunkStore> {
        &self.store
    }
}

impl WorldView for LiveWorld {
    fn generator(&self) -> &Arc<Generator> {
        &self.generator
    }

    /// Point reads of the box's chunks (the box is small: a tile's columns
    /// or a bounded scene), not a scan of the whole store.
    fn world(&self, within: ChunkBox) -> Result<World, WorldSourceError> {
        let generator: Arc<dyn ChunkGenerator> = self.generator.clone();
        let mut world = World::new(generator);
        for y in within.min.y..=within.max.y {
            for z in within.min.z..=within.max.z {
                for x in within.min.x..=within.max.x {
                    let pos = strata_terrain::ChunkPos::new(x, y, z);
                    let raw =
                        self.store
                            .raw_chunk(pos)
                            .map_err(|source| WorldSourceError::Store {
                                path: PathBuf::from("world.sled"),
                                source,
                            })?;
                    if let Some(raw) = raw {
                        insert_raw(&mut world, raw)?;
                    }
                }
            }
        }
        // What the operator sees is what clients were acknowledged: never
        // an edit a power cut may still take back.
        self.store
            .settle_reads(SETTLE_WITHIN)
            .map_err(|source| WorldSourceError::Store {
                path: PathBuf::from("world.sled"),
                source,
            })?;
        Ok(world)
    }
}
