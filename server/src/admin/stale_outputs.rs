//! Output files a killed writer left unfinished: a snapshot's `.partial`
//! (`OUT.PID-N.partial`, `snapshot_cmd::write_atomically`) and an export's
//! staged file (`.strata-out-PID-*`, `export::stage_output`). Each names
//! its writer's process id, so a later writer removes those whose process
//! is gone: no run after a Ctrl-C or a kill ever finishes them.

use std::path::{Path, PathBuf};

/// Prefix of an export's staged output; the writer's id follows.
pub const STAGED_PREFIX: &str = ".strata-out-";

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

/// Whether the process `pid` may still be writing its file: this process
/// is not (a caller makes its own outputs one at a time, and calls this
/// before it starts one), others are while they run. Where that cannot be
/// told, yes.
pub fn may_still_write(pid: u32) -> bool {
    if pid == std::process::id() {
        return false;
    }
    if cfg!(target_os = "linux") {
        Path::new("/proc").join(pid.to_string()).exists()
    } else {
        true
    }
}

/// Removes the files in `dir` that `writer_of` names as some process's
/// unfinished output and whose process is gone; returns each with the
/// outcome of its removal. A directory that does not list removes nothing.
pub fn remove_stale(
    dir: &Path,
    writer_of: impl Fn(&str) -> Option<u32>,
) -> Vec<(PathBuf, std::io::Result<()>)> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .filter_map(Result::ok)
        .filter(|e| {
            e.file_name()
                .to_str()
                .and_then(&writer_of)
                .is_some_and(|pid| !may_still_write(pid))
        })
        .map(|e| {
            let path = e.path();
            let removed = std::fs::remove_file(&path);
            (path, removed)
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
    fn only_a_gone_writers_files_of_this_output_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let ours = std::process::id();
        // No such process (above Linux's largest pid), and one that runs.
        let (gone, running) = (u32::MAX, 1);
        let names = [
            format!("w.snap.{gone}-0.partial"),
            format!("w.snap.{ours}-3.partial"),
            format!("{STAGED_PREFIX}{gone}-x1"),
            format!("w.snap.{running}-0.partial"),
            format!("other.snap.{gone}-0.partial"),
            format!("{STAGED_PREFIX}{running}-x2"),
            "w.snap".to_string(),
            "w.snap.partial".to_string(),
        ];
        for n in &names {
            std::fs::write(dir.path().join(n), b"x").unwrap();
        }
        clear_for(&dir.path().join("w.snap"));
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        let mut want = names[3..].to_vec();
        want.sort();
        assert_eq!(left, want);
    }
}
