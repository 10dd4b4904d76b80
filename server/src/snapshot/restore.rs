//! Writing a snapshot's world into an empty store.

use std::path::Path;

use strata_terrain::chunk_codec::decode_chunk;

use super::error::SnapshotError;
use super::reader::SnapshotReader;
use crate::store::{ImportTarget, RawChunk, StoreError, WorldMeta};

/// Why a restore failed.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    #[error(transparent)]
    Snapshot(#[from] SnapshotError),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("cannot encode the zones: {0}")]
    Zones(String),
}

/// Chunks imported per store batch.
pub const RESTORE_BATCH_CHUNKS: usize = 1024;

/// Imports `snapshot` into `store`, which must be empty or replace what it
/// holds ([`ImportTarget::begin_import`]): world metadata at
/// the snapshot's seq, every chunk, and the protected zones. The file is
/// checked again as it is read; run [`super::verify`] first so a bad file
/// is refused before anything is written. `progress` gets chunks imported.
pub fn import(
    snapshot: &Path,
    store: &dyn ImportTarget,
    zones_blob: &str,
    mut progress: impl FnMut(u64),
) -> Result<u64, RestoreError> {
    let mut reader = SnapshotReader::open(snapshot)?;
    let h = reader.header().clone();
    h.check_usable().map_err(SnapshotError::from)?;
    let zones = h.zones().map_err(SnapshotError::from)?;
    let zones = serde_json::to_vec(&zones).map_err(|e| RestoreError::Zones(e.to_string()))?;
    let mut meta = WorldMeta::new(h.seed, h.generator_version, h.generator_params.clone());
    meta.last_seq = h.seq;
    let mut batch = Vec::with_capacity(RESTORE_BATCH_CHUNKS);
    let mut count = 0u64;
    store.begin_import()?;
    while let Some(c) = reader.next_chunk()? {
        decode_chunk(&c.payload).map_err(|e| SnapshotError::Record {
            index: c.index,
            offset: c.offset,
            pos: Some(format!("chunk ({}, {}, {})", c.pos.x, c.pos.y, c.pos.z)),
            reason: format!("chunk does not decode: {e}"),
        })?;
        batch.push(RawChunk {
            pos: c.pos,
            version: c.version,
            encoded: c.payload,
        });
        if batch.len() == RESTORE_BATCH_CHUNKS {
            count += batch.len() as u64;
            store.import_chunks(&batch)?;
            batch.clear();
            progress(count);
        }
    }
    count += batch.len() as u64;
    store.import_chunks(&batch)?;
    progress(count);
    store.finish_import(&meta, zones_blob, &zones)?;
    Ok(count)
}
