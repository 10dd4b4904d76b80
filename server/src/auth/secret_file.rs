//! The secret's file in the data dir: its hex text, written atomically
//! with owner-only permissions (0600 on Unix).

use std::path::Path;

use strata_auth::{Secret, SecretError};

use crate::datadir::{read_private_file, write_private_file};

/// Loading and saving a [`Secret`] as a private file.
pub trait SecretFile: Sized {
    /// Reads a key file written by [`SecretFile::save`].
    fn load(path: &Path) -> Result<Self, SecretError>;
    /// Writes the key atomically, readable by the owner only.
    fn save(&self, path: &Path) -> Result<(), SecretError>;
}

impl SecretFile for Secret {
    fn load(path: &Path) -> Result<Self, SecretError> {
        let raw = read_private_file(path).map_err(|source| SecretError::Read {
            path: path.to_owned(),
            source,
        })?;
        let invalid = |reason| SecretError::Invalid {
            path: path.to_owned(),
            reason,
        };
        let text = std::str::from_utf8(&raw).map_err(|_| invalid("not text"))?;
        Secret::from_hex(text).map_err(invalid)
    }

    fn save(&self, path: &Path) -> Result<(), SecretError> {
        write_private_file(path, self.to_hex().as_bytes()).map_err(|source| SecretError::Write {
            path: path.to_owned(),
            source,
        })
    }
}
