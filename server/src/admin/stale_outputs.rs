//! Output files a killed writer left unfinished: a snapshot's `.partial`
//! (`OUT.PID-N.partial`, `snapshot_cmd::write_atomically`) and an export's
//! staged file (`.strata-out-PID-*`, `export::stage_output`). A writer
//! holds an exclusive `flock` on its file until it is renamed into place,
//! so a later writer removes those it can lock: no run after a Ctrl-C or
//! a kill ever finishes them, and one still writing (in this process, or
//! another, whatever its process id says: containers share ids) keeps its
//! file.

use std::fs::File;
use std::path::{Path, PathBuf};

use fs2::FileExt;

/// Prefix of an export's staged output; the writer's id follows.
pub const STAGED_PREFIX: &str = ".strata-out-";

/// Marks `file` as being written: held until it is dropped.
pub fn hold(file: &File) -> std::io::Result<()> {
    file.try_lock_exclusive()
}

/// `(BASE, PID)` when `name` is `BASE.PID-N.partial`.
pub fn partial_writer(name: &str) -> Option<(&str, u32)> {
    let rest = name.strip_suffix(".partial")?;
    let (base, tag) = rest.rsplit_once('.')?;
    let (pid, n) = tag.split_once('-')?;
    n.parse::<u64>().ok()?;
    Some((base, pid.parse().ok()?))
}

/// The writer's id when `name` is an export's staged output.
pub fn staged_writer(name: &str) -> Option<u32> {
    let (pid, _) = name.strip_prefix(STAGED_PREFIX)?.split_once('-')?;
    pid.parse().ok()
}

/// Removes the files in `dir` that `writer_of` names as some writer's
/// unfinished output and that no writer holds ([`hold`]); returns each
/// with the outcome of its removal. A directory that does not list
/// removes nothing.
pub fn remove_stale(
    dir: &Path,
    writer_of: impl Fn(&str) -> Option<u32>,
) -> Vec<(PathBuf, std::io::Result<()>)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_str().and_then(&writer_of).is_some())
        .filter_map(|e| {
            let path = e.path();
            // Held while it is removed: a writer cannot take it meanwhile.
            let file = File::options().read(true).open(&path).ok()?;
            file.try_lock_exclusive().ok()?;
            let removed = std::fs::remove_file(&path);
            drop(file);
            Some((path, removed))
        })
        .collect()
}

/// The directory a file `out` is written in.
pub fn dir_of(out: &Path) -> &Path {
    match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Removes what killed writers left of `out` (its `.partial` files) and
/// of exports beside it (their staged files), telling the operator.
pub fn clear_for(out: &Path) {
    let Some(name) = out.file_name().and_then(|n| n.to_str()) else {
        return;
    };
    let removed = remove_stale(dir_of(out), |n| {
        partial_writer(n)
            .filter(|(base, _)| *base == name)
            .map(|(_, pid)| pid)
            .or_else(|| staged_writer(n))
    });
    for (path, result) in removed {
        match result {
            Ok(()) => eprintln!(
                "removed {}, left unfinished by a run that was stopped",
                path.display()
            ),
            Err(e) => eprintln!(
                "warning: removing {}, left unfinished by a run that was stopped: {e}",
                path.display()
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_give_their_writers() {
        assert_eq!(partial_writer("x.snap.42-0.partial"), Some(("x.snap", 42)));
        assert_eq!(
            partial_writer("a.b.snap.7-13.partial"),
            Some(("a.b.snap", 7))
        );
        assert_eq!(partial_writer("x.snap.partial"), None);
        assert_eq!(partial_writer("x.snap.42-a.partial"), None);
        assert_eq!(partial_writer("x.snap.42-0"), None);
        assert_eq!(staged_writer(".strata-out-42-AbC9"), Some(42));
        assert_eq!(staged_writer(".strata-out-AbC9"), None);
        assert_eq!(staged_writer("strata-out-42-AbC9"), None);
    }

    #[test]
    fn only_unheld_files_of_this_output_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let names = [
            "w.snap.7-0.partial",
            ".strata-out-7-x1",
            "w.snap.1-0.partial",
            "other.snap.7-0.partial",
            ".strata-out-1-x2",
            "w.snap",
            "w.snap.partial",
        ];
        // Two writers still at work (their process ids say nothing).
        let held = testing::files(dir.path(), &names, &[names[2], names[4]]);
        clear_for(&dir.path().join("w.snap"));
        assert_eq!(testing::names_in(dir.path()), testing::sorted(&names[2..]));
        drop(held);
    }
}

/// Files of a test directory.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;

    /// Writes each of `names` in `dir`, and holds those in `held` as
    /// their writers would; the holds go when the files returned drop.
    pub fn files(dir: &Path, names: &[&str], held: &[&str]) -> Vec<File> {
        for n in names {
            std::fs::write(dir.join(n), b"x").unwrap();
        }
        held.iter()
            .map(|n| {
                let f = File::options().write(true).open(dir.join(n)).unwrap();
                hold(&f).unwrap();
                f
            })
            .collect()
    }

    /// The names in `dir`, sorted.
    pub fn names_in(dir: &Path) -> Vec<String> {
        let names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        sorted(&names)
    }

    /// `names` as owned strings, sorted.
    pub fn sorted(names: &[impl AsRef<str>]) -> Vec<String> {
        let mut out: Vec<String> = names.iter().map(|n| n.as_ref().to_string()).collect();
        out.sort();
        out
    }
}
