//! Filling an empty store from a snapshot (`strata-admin snapshot restore`).
//!
//! Chunks go in first, the metadata last: a restore cut short leaves a
//! store without metadata, which no server mistakes for a world. The
//! metadata names the snapshot's seq as both `last_seq` and the log base
//! ([`super::META_LOG_BASE`]): the next edit gets `seq + 1`.

use super::error::StoreError;
use super::keys::chunk_key;
use super::record::encode_meta;
use super::sled_store::{META_LAST_SEQ, META_LOG_BASE, META_WORLD};
use super::types::{RawChunk, WorldMeta, STORE_FORMAT_VERSION};
use super::SledStore;

/// A store a snapshot can be restored into: sled's, or PostgreSQL's
/// (`pg/import.rs`).
pub trait ImportTarget {
    /// Refuses a store that holds a world, or, for one that replaces it
    /// (a forced PostgreSQL restore), empties it first.
    fn begin_import(&self) -> Result<(), StoreError>;
    /// Writes chunk records as they are.
    fn import_chunks(&self, chunks: &[RawChunk]) -> Result<(), StoreError>;
    /// Writes the zones blob and the metadata at `meta.last_seq`, durably.
    fn finish_import(
        &self,
        meta: &WorldMeta,
        zones_blob: &str,
        zones: &[u8],
    ) -> Result<(), StoreError>;
}

/// Refuses metadata of a store format this build does not write.
pub(super) fn check_import_format(meta: &WorldMeta) -> Result<(), StoreError> {
    if meta.format_version != STORE_FORMAT_VERSION {
        return Err(StoreError::UnsupportedFormat {
            found: meta.format_version,
            supported: STORE_FORMAT_VERSION,
        });
    }
    Ok(())
}

impl ImportTarget for SledStore {
    /// Refuses a store that holds anything.
    fn begin_import(&self) -> Result<(), StoreError> {
        for (name, tree) in [
            ("meta", &self.meta),
            ("chunks", &self.chunks),
            ("log", &self.log),
            ("blobs", &self.blobs),
        ] {
            if !tree.is_empty() {
                return Err(StoreError::InvalidMeta {
                    reason: format!("cannot import into a store whose {name} tree is not empty"),
                });
            }
        }
        Ok(())
    }

    /// Writes chunk records as they are (made durable by [`Self::finish_import`]).
    fn import_chunks(&self, chunks: &[RawChunk]) -> Result<(), StoreError> {
        let mut b = sled::Batch::default();
        for c in chunks {
            if c.version == 0 {
                return Err(StoreError::batch("imported chunk at version 0"));
            }
            let mut value = c.version.to_be_bytes().to_vec();
            value.extend_from_slice(&c.encoded);
            b.insert(&chunk_key(c.pos)[..], value);
        }
        self.chunks.apply_batch(b)?;
        Ok(())
    }

    /// Writes the zones blob and the metadata at `meta.last_seq`, then flushes.
    fn finish_import(
        &self,
        meta: &WorldMeta,
        zones_blob: &str,
        zones: &[u8],
    ) -> Result<(), StoreError> {
        check_import_format(meta)?;
        self.blobs.insert(zones_blob.as_bytes(), zones)?;
        let mut b = sled::Batch::default();
        b.insert(META_WORLD, encode_meta(meta)?);
        b.insert(META_LAST_SEQ, &meta.last_seq.to_be_bytes()[..]);
        b.insert(META_LOG_BASE, &meta.last_seq.to_be_bytes()[..]);
        self.meta.apply_batch(b)?;
        self.flush()
    }
}
