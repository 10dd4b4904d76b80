//! The lock beside a sled world (`world.sled.lock`): held by whoever has
//! the world open through [`super::open_store`] (a server, an offline admin
//! tool) and by a restore for its whole swap, so neither runs while the
//! other does. It lies beside the world's directory, not in it, so the
//! swap's renames leave it where it is.

use std::fs::File;
use std::path::{Path, PathBuf};

use super::sled_store::LOCK_WAIT;
use super::StoreError;

/// Suffix of the store a restore fills before it replaces the world.
pub const RESTORING_SUFFIX: &str = ".restoring";
/// Suffix of the replaced world while the new one moves into place.
pub const REPLACED_SUFFIX: &str = ".replaced";
/// Suffix of the lock file.
pub const LOCK_SUFFIX: &str = ".lock";

/// `path` with `suffix` added to its file name.
pub fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(suffix);
    path.with_file_name(name)
}

/// An exclusive hold on a sled world; let go when dropped (or when the
/// process ends, however it ends).
#[derive(Debug)]
pub struct WorldLock {
    _file: File,
}

impl WorldLock {
    /// Takes the lock of the world at `world`, waiting at most
    /// [`LOCK_WAIT`] for a holder that is closing.
    pub fn take(world: &Path) -> Result<Self, StoreError> {
        let path = with_suffix(world, LOCK_SUFFIX);
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)?;
        }
        let file = File::options()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)?;
        let start = std::time::Instant::now();
        loop {
            match fs2::FileExt::try_lock_exclusive(&file) {
                Ok(()) => return Ok(Self { _file: file }),
                Err(e) if e.kind() != fs2::lock_contended_error().kind() => return Err(e.into()),
                Err(_) if start.elapsed() < LOCK_WAIT => {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                Err(_) => {
                    return Err(StoreError::WorldInUse {
                        world: world.to_path_buf(),
                    })
                }
            }
        }
    }

    /// Takes the lock, then refuses a world a restore left half swapped:
    /// no world, and the replaced one still beside it.
    pub fn take_whole(world: &Path) -> Result<Self, StoreError> {
        let lock = Self::take(world)?;
        let replaced = with_suffix(world, REPLACED_SUFFIX);
        if !world.exists() && replaced.exists() {
            return Err(StoreError::RestoreCutShort {
                world: world.to_path_buf(),
                replaced,
            });
        }
        Ok(lock)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time_and_a_half_swapped_world_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let world = dir.path().join("world.sled");
        let held = WorldLock::take_whole(&world).unwrap();
        let err = WorldLock::take(&world).unwrap_err();
        assert!(matches!(err, StoreError::WorldInUse { .. }), "{err}");
        drop(held);
        let again = WorldLock::take(&world).unwrap();
        drop(again);
        // A swap cut short: the world moved aside, nothing in its place.
        std::fs::create_dir(with_suffix(&world, REPLACED_SUFFIX)).unwrap();
        let err = WorldLock::take_whole(&world).unwrap_err();
        assert!(matches!(err, StoreError::RestoreCutShort { .. }), "{err}");
        assert!(err.to_string().contains("world.sled.replaced"), "{err}");
        // Back in place, it opens.
        std::fs::rename(with_suffix(&world, REPLACED_SUFFIX), &world).unwrap();
        WorldLock::take_whole(&world).unwrap();
    }
}
