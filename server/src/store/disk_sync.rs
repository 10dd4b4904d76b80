//! The fsyncs sled 0.34 leaves out.
//!
//! On Linux sled 0.34.7 as published writes its log with
//! `sync_file_range`, which saves neither the file's size nor the drive's
//! write cache: a power cut can lose a "flushed" commit. It also writes
//! blob files (pages over a quarter segment) without any sync, and renames
//! snapshot files without syncing the directory. The vendored copy
//! (`vendor/sled/STRATA.md`) fdatasyncs its log writes and fsyncs each
//! blob through the handle that wrote it, so a write-back error reaches
//! sled; this stays as the barrier Strata owns, after every flush:
//! `fdatasync` of the `db` file, of each blob file not yet synced at its
//! current length, and an fsync of each directory whose entries changed
//! (snapshot renames included). Only then is a write durable.

use std::collections::{BTreeSet, HashMap};
use std::ffi::OsString;
use std::fs::{self, File};
use std::io;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::durable::sync_parent;

/// sled's log file inside the store directory.
const DB_FILE: &str = "db";
/// sled's config file, written once at creation.
const CONF_FILE: &str = "conf";
/// sled's directory of blob files.
const BLOBS_DIR: &str = "blobs";

/// Most blob files remembered as synced; past it the set starts over (and
/// the next sync fsyncs them all again). sled removes blobs as it cleans.
pub const MAX_TRACKED_BLOBS: usize = 4096;

#[derive(Debug)]
pub(super) struct DiskSync {
    dir: PathBuf,
    /// A second handle on sled's log file (fsync on any handle syncs the file).
    db: File,
    state: Mutex<Seen>,
}

/// What the last sync saw, to sync only what changed since.
#[derive(Debug, Default)]
struct Seen {
    /// Blob file name → length it was synced at.
    blobs: HashMap<OsString, u64>,
    /// Names in the store directory (sled's snapshot files come and go).
    entries: BTreeSet<OsString>,
    /// The first failed fsync. Linux reports a write-back error to each
    /// handle once and marks the lost pages clean: a later fsync would
    /// succeed over the hole. So one failure fails every later sync.
    failed: Option<String>,
}

impl DiskSync {
    /// Opens the handles and makes everything sled created so far durable:
    /// its files, its directories and the store directory's own entry.
    pub(super) fn open(dir: &Path) -> io::Result<Self> {
        let db = File::open(dir.join(DB_FILE))?;
        if let Ok(conf) = File::open(dir.join(CONF_FILE)) {
            conf.sync_all()?;
        }
        let me = Self {
            dir: dir.to_path_buf(),
            db,
            state: Mutex::new(Seen::default()),
        };
        // The first sync sees every entry as new and syncs the directory.
        me.sync()?;
        sync_parent(dir)?;
        Ok(me)
    }

    /// Makes everything sled has written so far durable. Call it after
    /// `flush`, before acknowledging anything. Once a sync failed, every
    /// later one fails too (see `Seen::failed`): only a restart, which
    /// recovers from what is on disk, writes again.
    pub(super) fn sync(&self) -> io::Result<()> {
        let mut seen = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(first) = &seen.failed {
            return Err(io::Error::other(format!(
                "an earlier sync of the store failed ({first}): writes since may be lost; restart to recover from the disk"
            )));
        }
        Self::sync_changed(&self.dir, &self.db, &mut seen)
    }

    fn sync_changed(dir: &Path, db: &File, seen: &mut Seen) -> io::Result<()> {
        // Blobs first: the log may point at them.
        let blob_dir = dir.join(BLOBS_DIR);
        let mut present = Vec::new();
        let mut changed = false;
        for entry in fs::read_dir(&blob_dir)? {
            let entry = entry?;
            let name = entry.file_name();
            let len = match entry.metadata() {
                Ok(m) => m.len(),
                // sled removed it meanwhile.
                Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                Err(e) => return Err(e),
            };
            if seen.blobs.get(&name) != Some(&len) {
                match File::open(entry.path()) {
                    Ok(f) => fsynced(&mut seen.failed, f.sync_data())?,
                    Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                    Err(e) => return Err(e),
                }
                changed |= !seen.blobs.contains_key(&name);
            }
            present.push((name, len));
        }
        changed |= present.len() != seen.blobs.len();
        if changed {
            fsynced(&mut seen.failed, File::open(&blob_dir)?.sync_all())?;
        }
        seen.blobs = present.into_iter().take(MAX_TRACKED_BLOBS).collect();
        fsynced(&mut seen.failed, db.sync_data())?;
        let entries = fs::read_dir(dir)?
            .map(|e| e.map(|e| e.file_name()))
            .collect::<io::Result<BTreeSet<_>>>()?;
        if entries != seen.entries {
            fsynced(&mut seen.failed, File::open(dir)?.sync_all())?;
            seen.entries = entries;
        }
        Ok(())
    }
}

/// `synced`, remembering its failure in `failed`: a failed fsync is never
/// retried (other errors, such as a failed directory read, are).
fn fsynced(failed: &mut Option<String>, synced: io::Result<()>) -> io::Result<()> {
    if let Err(e) = &synced {
        failed.get_or_insert_with(|| e.to_string());
    }
    synced
}

#[cfg(test)]
mod tests {
    use super::*;

    fn synced_blobs(s: &DiskSync) -> Vec<(String, u64)> {
        let seen = s.state.lock().unwrap();
        let mut v: Vec<_> = seen
            .blobs
            .iter()
            .map(|(n, l)| (n.to_string_lossy().into_owned(), *l))
            .collect();
        v.sort();
        v
    }

    #[test]
    fn remembers_each_blob_file_at_the_length_it_was_synced() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("store");
        fs::create_dir_all(dir.join(BLOBS_DIR)).unwrap();
        fs::write(dir.join(DB_FILE), b"log").unwrap();
        let s = DiskSync::open(&dir).unwrap();
        assert!(synced_blobs(&s).is_empty());
        fs::write(dir.join(BLOBS_DIR).join("17"), b"abc").unwrap();
        s.sync().unwrap();
        assert_eq!(synced_blobs(&s), [("17".to_string(), 3)]);
        // A blob still being written is synced again once it grew.
        fs::write(dir.join(BLOBS_DIR).join("17"), b"abcdef").unwrap();
        fs::write(dir.join(BLOBS_DIR).join("40"), b"x").unwrap();
        s.sync().unwrap();
        assert_eq!(
            synced_blobs(&s),
            [("17".to_string(), 6), ("40".to_string(), 1)]
        );
        // Removed blobs are forgotten; a new snapshot file is a new entry.
        fs::remove_file(dir.join(BLOBS_DIR).join("17")).unwrap();
        fs::write(dir.join("snap.0000000000000001"), b"s").unwrap();
        s.sync().unwrap();
        assert_eq!(synced_blobs(&s), [("40".to_string(), 1)]);
        assert!(s
            .state
            .lock()
            .unwrap()
            .entries
            .contains(std::ffi::OsStr::new("snap.0000000000000001")));
    }

    #[test]
    fn once_an_fsync_failed_every_later_sync_fails() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("store");
        fs::create_dir_all(dir.join(BLOBS_DIR)).unwrap();
        fs::write(dir.join(DB_FILE), b"log").unwrap();
        let s = DiskSync::open(&dir).unwrap();
        // A failed directory read is an error, and the next sync tries again.
        fs::remove_dir(dir.join(BLOBS_DIR)).unwrap();
        assert!(s.sync().is_err());
        fs::create_dir(dir.join(BLOBS_DIR)).unwrap();
        s.sync().unwrap();
        // A failed fsync is not retried into a success.
        let mut failed = s.state.lock().unwrap().failed.take();
        assert!(failed.is_none());
        assert!(fsynced(&mut failed, Err(io::Error::other("EIO"))).is_err());
        s.state.lock().unwrap().failed = failed;
        let err = s.sync().unwrap_err().to_string();
        assert!(
            err.contains("an earlier sync of the store failed (EIO)"),
            "{err}"
        );
        // A new handle (a restart) syncs again.
        DiskSync::open(&dir).unwrap().sync().unwrap();
    }

    #[test]
    fn a_store_without_its_log_file_does_not_open() {
        let tmp = tempfile::tempdir().unwrap();
        assert!(DiskSync::open(tmp.path()).is_err());
    }
}
