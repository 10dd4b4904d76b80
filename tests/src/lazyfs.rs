//! LazyFS, a FUSE file system that keeps every write it was not asked to
//! fsync in a cache of its own, for power-cut tests.
//!
//! [`LazyFs::power_cut`] drops that cache (`lazyfs::clear-cache`), kills
//! the file system and mounts it again: what is left in the backing
//! directory is exactly what was fsynced.
//!
//! `STRATA_LAZYFS` names the `lazyfs` binary (`scripts/test` builds it
//! from `../shared/tools/lazyfs`). Without it a test that needs LazyFS
//! fails under `CI=true` and otherwise says that it did not run.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::Guard;

/// Environment variable naming the `lazyfs` binary.
pub const LAZYFS_ENV: &str = "STRATA_LAZYFS";
/// Longest wait for a mount to appear (LazyFS allocates its cache first).
pub const MOUNT_TIMEOUT: Duration = Duration::from_secs(60);
/// Longest wait for LazyFS to confirm a dropped cache.
pub const CLEAR_TIMEOUT: Duration = Duration::from_secs(30);
/// LazyFS's cache: room for every unsynced write of a test run.
const CACHE_SIZE: &str = "256mb";

/// The `lazyfs` binary from [`LAZYFS_ENV`], or `None` (after saying so)
/// outside CI. Under `CI=true` a missing LazyFS fails the test.
pub fn binary_or_skip(test: &str) -> Option<PathBuf> {
    match std::env::var_os(LAZYFS_ENV).map(PathBuf::from) {
        Some(p) if p.is_file() => Some(p),
        other => {
            let why = match other {
                Some(p) => format!("{LAZYFS_ENV}={} is not a file", p.display()),
                None => format!("{LAZYFS_ENV} is not set (scripts/test sets it)"),
            };
            crate::not_run(test, "LazyFS", &why)
        }
    }
}

/// A mounted LazyFS: `mount_dir()` shows the files, `root/` holds what was
/// synced.
#[derive(Debug)]
pub struct LazyFs {
    bin: PathBuf,
    dir: PathBuf,
    proc: Option<Guard>,
    /// Removed after the file system is unmounted (drop runs first).
    _temp: Option<tempfile::TempDir>,
}

impl LazyFs {
    /// For a test: LazyFS mounted in a new temporary directory, or `None`
    /// when it cannot run here (see [`binary_or_skip`]).
    pub fn for_test(test: &str) -> Option<LazyFs> {
        let bin = binary_or_skip(test)?;
        let temp = tempfile::tempdir().expect("temp dir");
        let mut fs = LazyFs::mount(&bin, temp.path());
        fs._temp = Some(temp);
        Some(fs)
    }

    /// The directory holding the mount, its backing `root/` and LazyFS's
    /// files; free for other files of the test.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Mounts a new LazyFS under `dir` (which must exist).
    pub fn mount(bin: &Path, dir: &Path) -> LazyFs {
        for sub in ["mnt", "root"] {
            std::fs::create_dir_all(dir.join(sub)).expect("lazyfs dirs");
        }
        let config = format!(
            "[faults]\nfifo_path=\"{}\"\nfifo_path_completed=\"{}\"\n\
             [cache]\napply_eviction=false\n\
             [cache.simple]\ncustom_size=\"{CACHE_SIZE}\"\nblocks_per_page=1\n\
             [filesystem]\nlog_all_operations=false\nlogfile=\"{}\"\n",
            dir.join("faults.fifo").display(),
            dir.join("done.fifo").display(),
            dir.join("lazyfs.log").display(),
        );
        std::fs::write(dir.join("lazyfs.toml"), config).expect("lazyfs config");
        let mut fs = LazyFs {
            bin: bin.to_path_buf(),
            dir: dir.to_path_buf(),
            proc: None,
            _temp: None,
        };
        fs.start();
        fs
    }

    /// Where the file system is mounted.
    pub fn mount_dir(&self) -> PathBuf {
        self.dir.join("mnt")
    }

    fn start(&mut self) {
        let mnt = self.mount_dir();
        let child = Command::new(&self.bin)
            .arg(&mnt)
            .arg("--config-path")
            .arg(self.dir.join("lazyfs.toml"))
            .args(["-o", "allow_other", "-o", "modules=subdir", "-o"])
            .arg(format!("subdir={}", self.dir.join("root").display()))
            .arg("-f")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("{} starts: {e}", self.bin.display()));
        self.proc = Some(Guard(child));
        let start = Instant::now();
        while !is_mounted(&mnt) {
            if let Some(Some(status)) = self.proc.as_mut().map(|p| p.0.try_wait().ok().flatten()) {
                panic!("lazyfs exited with {status} before mounting");
            }
            assert!(start.elapsed() < MOUNT_TIMEOUT, "lazyfs did not mount");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// A power cut: every write never fsynced is dropped, the file system
    /// dies with whatever the kernel still held for it, and comes back over
    /// the same backing directory. Stop the programs using it first.
    pub fn power_cut(&mut self) {
        // Read the completion FIFO on a handle that is also a writer, so
        // opening it does not wait for LazyFS.
        let done = OpenOptions::new()
            .read(true)
            .write(true)
            .open(self.dir.join("done.fifo"))
            .expect("open lazyfs completion fifo");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(done).read_line(&mut line);
            let _ = tx.send(line);
        });
        let mut faults = File::options()
            .write(true)
            .open(self.dir.join("faults.fifo"))
            .expect("open lazyfs fault fifo");
        faults
            .write_all(b"lazyfs::clear-cache\n")
            .expect("send clear-cache");
        drop(faults);
        let answer = rx
            .recv_timeout(CLEAR_TIMEOUT)
            .expect("lazyfs confirmed the cleared cache");
        assert!(answer.contains("clear-cache"), "lazyfs said {answer:?}");
        self.kill();
        self.start();
    }

    /// The file system dies and stays dead: every later I/O on it fails
    /// (a disk that went away).
    pub fn fail(&mut self) {
        self.kill();
    }

    fn kill(&mut self) {
        if let Some(mut p) = self.proc.take() {
            let _ = p.0.kill();
            let _ = p.0.wait();
        }
        // The dead daemon leaves its mount behind: detach it.
        let _ = Command::new("fusermount3")
            .args(["-u", "-z"])
            .arg(self.mount_dir())
            .stderr(Stdio::null())
            .status();
    }
}

impl Drop for LazyFs {
    fn drop(&mut self) {
        self.kill();
    }
}

fn is_mounted(dir: &Path) -> bool {
    let Ok(mounts) = std::fs::read_to_string("/proc/mounts") else {
        return false;
    };
    let dir = dir.to_string_lossy();
    mounts
        .lines()
        .any(|l| l.split_whitespace().nth(1) == Some(&*dir))
}
