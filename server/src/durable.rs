//! What "durable" means on disk: a file's bytes are fsynced, and so is the
//! directory that names it. A rename or a new file is only durable once
//! its directory is synced; a file's data only once the file is.
//!
//! Every write that recovery needs (the store, the data dir's identity
//! files, snapshot files) goes through these helpers.

use std::fs::{self, File};
use std::io;
use std::path::Path;

/// fsyncs a directory, making the entries created, renamed or removed in
/// it durable.
pub fn sync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

/// fsyncs the directory that holds `path` (the current directory for a
/// bare file name).
pub fn sync_parent(path: &Path) -> io::Result<()> {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => sync_dir(p),
        _ => sync_dir(Path::new(".")),
    }
}

/// Renames `from` over `to` and syncs the directory of `to`, so the new
/// name survives a power cut. `from` must already be synced.
pub fn rename(from: &Path, to: &Path) -> io::Result<()> {
    fs::rename(from, to)?;
    sync_parent(to)
}

/// Creates `path` and any missing parents with `builder`, syncing the
/// directory above each one created.
pub fn create_dir_all(builder: &fs::DirBuilder, path: &Path) -> io::Result<()> {
    let mut missing = Vec::new();
    let mut cur = Some(path);
    while let Some(p) = cur.filter(|p| !p.as_os_str().is_empty() && !p.exists()) {
        missing.push(p);
        cur = p.parent();
    }
    for p in missing.into_iter().rev() {
        match builder.create(p) {
            Ok(()) => {}
            // Another process made it meanwhile; its parent still gets synced.
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists && p.is_dir() => {}
            Err(e) => return Err(e),
        }
        sync_parent(p)?;
    }
    Ok(())
}

/// Syncs `file` and moves it into place at `to` (see [`rename`]).
pub fn persist_file(file: &File, from: &Path, to: &Path) -> io::Result<()> {
    file.sync_all()?;
    rename(from, to)
}

/// Syncs a staged temporary file and moves it into place at `to`, syncing
/// the directory (for the admin commands' output files).
pub fn persist_temp(tmp: tempfile::NamedTempFile, to: &Path) -> io::Result<()> {
    tmp.as_file().sync_all()?;
    tmp.persist(to).map_err(|e| e.error)?;
    sync_parent(to)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn creates_nested_dirs_and_renames() {
        let tmp = tempfile::tempdir().unwrap();
        let deep = tmp.path().join("a/b/c");
        create_dir_all(&fs::DirBuilder::new(), &deep).unwrap();
        assert!(deep.is_dir());
        // Existing: nothing to do, no error.
        create_dir_all(&fs::DirBuilder::new(), &deep).unwrap();
        let from = deep.join("x.tmp");
        let file = File::create(&from).unwrap();
        persist_file(&file, &from, &deep.join("x")).unwrap();
        assert!(deep.join("x").exists() && !from.exists());
        assert!(sync_parent(Path::new("bare-name")).is_ok());
    }

    #[test]
    fn a_missing_directory_is_an_error() {
        let tmp = tempfile::tempdir().unwrap();
        assert!(sync_dir(&tmp.path().join("none")).is_err());
    }
}
