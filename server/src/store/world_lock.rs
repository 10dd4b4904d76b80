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

    /// Takes the lock, then finishes the swap of a restore cut short
    /// between its renames (no world, the replaced one beside it): the
    /// restored world goes into place when it is there (a restore syncs
    /// it whole before it moves the old one aside), else the old one goes
    /// back. Moved forward, the old world is removed, as the restore would
    /// have. What was done is logged; a rename that fails is the error.
    pub fn take_whole(world: &Path) -> Result<Self, StoreError> {
        let lock = Self::take(world)?;
        let replaced = with_suffix(world, REPLACED_SUFFIX);
        if !world.exists() && replaced.exists() {
            let restored = with_suffix(world, RESTORING_SUFFIX);
            let (from, done) = if restored.exists() {
                (restored, "the restored world moved into place")
            } else {
                (replaced.clone(), "the replaced world moved back")
            };
            crate::durable::rename(&from, world).map_err(|source| StoreError::RestoreCutShort {
                world: world.to_path_buf(),
                replaced: replaced.clone(),
                source,
            })?;
            tracing::warn!(world = %world.display(), from = %from.display(), "a restore was cut short between its renames: {done}");
            if from != replaced {
                if let Err(e) = std::fs::remove_dir_all(&replaced) {
                    tracing::warn!(dir = %replaced.display(), error = %e, "removing the replaced world failed");
                }
            }
        }
        Ok(lock)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_holder_at_a_time() {
        let dir = tempfile::tempdir().unwrap();
        let world = dir.path().join("world.sled");
        let held = WorldLock::take_whole(&world).unwrap();
        let err = WorldLock::take(&world).unwrap_err();
        assert!(matches!(err, StoreError::WorldInUse { .. }), "{err}");
        drop(held);
        WorldLock::take(&world).unwrap();
    }

    /// A world directory holding one file that names it.
    fn world_named(path: &Path, name: &str) {
        std::fs::create_dir(path).unwrap();
        std::fs::write(path.join("name"), name).unwrap();
    }

    fn name_of(world: &Path) -> String {
        std::fs::read_to_string(world.join("name")).unwrap()
    }

    #[test]
    fn a_swap_cut_short_is_finished_forward_when_the_restored_world_is_there() {
        let dir = tempfile::tempdir().unwrap();
        let world = dir.path().join("world.sled");
        world_named(&with_suffix(&world, REPLACED_SUFFIX), "old");
        world_named(&with_suffix(&world, RESTORING_SUFFIX), "new");
        drop(WorldLock::take_whole(&world).unwrap());
        assert_eq!(name_of(&world), "new");
        assert!(!with_suffix(&world, RESTORING_SUFFIX).exists());
        assert!(!with_suffix(&world, REPLACED_SUFFIX).exists());
    }

    #[test]
    fn a_swap_cut_short_with_no_restored_world_puts_the_old_one_back() {
        let dir = tempfile::tempdir().unwrap();
        let world = dir.path().join("world.sled");
        world_named(&with_suffix(&world, REPLACED_SUFFIX), "old");
        drop(WorldLock::take_whole(&world).unwrap());
        assert_eq!(name_of(&world), "old");
        assert!(!with_suffix(&world, REPLACED_SUFFIX).exists());
        // A world in place is never touched.
        world_named(&with_suffix(&world, RESTORING_SUFFIX), "new");
        world_named(&with_suffix(&world, REPLACED_SUFFIX), "older");
        drop(WorldLock::take_whole(&world).unwrap());
        assert_eq!(name_of(&world), "old");
    }
}
