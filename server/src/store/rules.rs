//! Rules every backend applies before it writes: blob names, the
//! metadata of a new world, and the generation inputs a world keeps.

use super::error::StoreError;
use super::sled_store::{MAX_BLOB_BYTES, MAX_BLOB_NAME_BYTES, MAX_GENERATOR_PARAMS_BYTES};
use super::types::{WorldMeta, STORE_FORMAT_VERSION};

/// Refuses an empty or overlong blob name.
pub fn check_blob_name(name: &str) -> Result<(), StoreError> {
    if name.is_empty() || name.len() > MAX_BLOB_NAME_BYTES {
        return Err(StoreError::InvalidBlob {
            reason: format!(
                "name is {} bytes, must be 1..={MAX_BLOB_NAME_BYTES}",
                name.len()
            ),
        });
    }
    Ok(())
}

/// Refuses a bad name or a body over [`MAX_BLOB_BYTES`].
pub fn check_blob(name: &str, bytes: &[u8]) -> Result<(), StoreError> {
    check_blob_name(name)?;
    if bytes.len() > MAX_BLOB_BYTES {
        return Err(StoreError::InvalidBlob {
            reason: format!("{name:?} is {} bytes, limit {MAX_BLOB_BYTES}", bytes.len()),
        });
    }
    Ok(())
}

/// Refuses the metadata of a new world this build cannot write.
pub fn check_new_meta(m: &WorldMeta) -> Result<(), StoreError> {
    if m.format_version != STORE_FORMAT_VERSION {
        return Err(StoreError::UnsupportedFormat {
            found: m.format_version,
            supported: STORE_FORMAT_VERSION,
        });
    }
    if m.last_seq != 0 {
        return Err(StoreError::InvalidMeta {
            reason: format!("a new world starts at last_seq 0, got {}", m.last_seq),
        });
    }
    if m.generator_params.len() > MAX_GENERATOR_PARAMS_BYTES {
        return Err(StoreError::InvalidMeta {
            reason: format!(
                "generator params are {} bytes, limit {MAX_GENERATOR_PARAMS_BYTES}",
                m.generator_params.len()
            ),
        });
    }
    Ok(())
}

/// [`StoreError::MetaMismatch`] when `given` has other generation inputs.
pub fn compare_meta(stored: &WorldMeta, given: &WorldMeta) -> Result<(), StoreError> {
    let mismatch = |field, stored: String, given: String| StoreError::MetaMismatch {
        field,
        stored,
        given,
    };
    if stored.seed != given.seed {
        return Err(mismatch(
            "seed",
            stored.seed.to_string(),
            given.seed.to_string(),
        ));
    }
    if stored.generator_version != given.generator_version {
        return Err(mismatch(
            "generator_version",
            stored.generator_version.to_string(),
            given.generator_version.to_string(),
        ));
    }
    if stored.generator_params != given.generator_params {
        return Err(mismatch(
            "generator_params",
            format!("{:?}", stored.generator_params),
            format!("{:?}", given.generator_params),
        ));
    }
    Ok(())
}
