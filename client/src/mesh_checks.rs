//! A tick's mesh checks, taken out of the replica so the meshing runs
//! without its lock ([`Replica::take_mesh_checks`], [`MeshChecks::run`],
//! [`Replica::finish_mesh_checks`]): a game thread reading chunks or
//! meshing them never waits for the connection's checks.
//!
//! [`Replica::take_mesh_checks`]: crate::replica::Replica::take_mesh_checks
//! [`Replica::finish_mesh_checks`]: crate::replica::Replica::finish_mesh_checks

use std::sync::Arc;

use strata_terrain::mesh::{mesh_chunk, MeshOptions, Neighborhood};
use strata_terrain::{Chunk, ChunkPos};

use crate::pool::{ChunkPool, MeshKey};

/// One chunk's check: the server's mesh hash for it at `version`, and
/// the client's, or the 27 chunks to mesh for it.
#[derive(Debug)]
pub(crate) struct MeshCheck {
    pub pos: ChunkPos,
    pub version: u64,
    pub server: u64,
    pub key: MeshKey,
    /// The chunks around `pos`, x fastest then y then z (until meshed).
    pub around: Option<Box<[Arc<Chunk>; 27]>>,
    pub client: Option<u64>,
}

/// Checks taken from a replica at a tick's end.
#[derive(Debug)]
pub struct MeshChecks {
    pub(crate) items: Vec<MeshCheck>,
    pub(crate) pool: Arc<ChunkPool>,
}

impl MeshChecks {
    /// Whether there is nothing to check.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Meshes what the pool did not know (each hash kept there for the
    /// replicas sharing it).
    pub fn run(&mut self) {
        for c in &mut self.items {
            let Some(around) = c.around.take() else {
                continue;
            };
            let pos = c.pos;
            let nb = Neighborhood::from_chunks(pos, |p| {
                let d = |a: i32, b: i32| (a.wrapping_sub(b) + 1) as usize;
                let i = d(p.x, pos.x) + 3 * d(p.y, pos.y) + 9 * d(p.z, pos.z);
                around.get(i).map(|c| &**c)
            });
            let hash = mesh_chunk(&nb, &MeshOptions::default()).hash();
            self.pool.put_mesh_hash(c.key, hash);
            c.client = Some(hash);
        }
    }
}
