//! Snapshots started from the console: registered with the engine and read
//! through the pre-images exactly as `strata-admin snapshot create` online
//! (the admin session's `begin_snapshot` and `walk_snapshot`), written on
//! the server into the console's snapshot directory through a `.partial`
//! file renamed into place. One runs at a time; watchers see its progress.
//! It stops, keeping no file, once its admin's token is no longer good
//! (expired, revoked, the admin banned): checked before its first chunk,
//! every [`ADMISSION_CHECK_CHUNKS`] and before the file is renamed.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use serde::Serialize;
use tracing::{info, warn};

use crate::admin::snapshot_cmd::{write_atomically, Created};
use crate::admin::stale_outputs;
use crate::auth::Claims;
use crate::console::auth::still_admitted;
use crate::net::admin_session::{begin_snapshot, walk_snapshot};
use crate::net::session::SessionContext;
use crate::snapshot::{SnapshotHeader, SnapshotWriter};

/// Chunks a console snapshot writes between two checks of its admin.
pub const ADMISSION_CHECK_CHUNKS: u64 = 256;

/// The console's snapshot, running or last finished.
#[derive(Debug)]
pub struct SnapshotJobs {
    dir: PathBuf,
    /// `[console] keep_snapshots`.
    keep: usize,
    busy: Arc<AtomicBool>,
    last: Mutex<Option<Arc<Job>>>,
}

/// The running mark, held by a snapshot being started or written; dropped
/// (the job done, failed, or its start abandoned), it clears the mark.
#[derive(Debug)]
struct Busy(Arc<AtomicBool>);

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Release);
    }
}

/// One snapshot's progress.
#[derive(Debug)]
struct Job {
    admin: String,
    file: PathBuf,
    seq: u64,
    /// Modified chunks when it started (the snapshot may hold fewer).
    total: u64,
    written: AtomicU64,
    outcome: Mutex<Option<Result<Created, String>>>,
}

/// What watchers are shown.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JobStatus {
    pub admin: String,
    pub file: String,
    pub seq: u64,
    pub total: u64,
    pub written: u64,
    /// `running`, `done` or `failed`.
    pub state: &'static str,
    pub bytes: Option<u64>,
    pub error: Option<String>,
}

impl SnapshotJobs {
    pub fn new(dir: PathBuf, keep: usize) -> Self {
        Self {
            dir,
            keep: keep.max(1),
            busy: Arc::default(),
            last: Mutex::default(),
        }
    }

    pub fn status(&self) -> Option<JobStatus> {
        let job = self
            .last
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()?;
        let outcome = job
            .outcome
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone();
        let (state, bytes, error) = match outcome {
            None => ("running", None, None),
            Some(Ok(c)) => ("done", Some(c.bytes), None),
            Some(Err(e)) => ("failed", None, Some(e)),
        };
        Some(JobStatus {
            admin: job.admin.clone(),
            file: job.file.display().to_string(),
            seq: job.seq,
            total: job.total,
            written: job.written.load(Ordering::Relaxed),
            state,
            bytes,
            error,
        })
    }

    /// Starts a snapshot for the admin of `claims`; refused while one
    /// runs. Dropped before the job is handed to its writer (a client
    /// gone, a timeout), it leaves none running.
    pub async fn start(
        &self,
        ctx: &Arc<SessionContext>,
        claims: &Claims,
    ) -> Result<JobStatus, String> {
        if self.busy.swap(true, Ordering::AcqRel) {
            return Err("a snapshot is already running".into());
        }
        let busy = Busy(self.busy.clone());
        self.spawn(ctx, claims, busy).await
    }

    /// `busy` goes with the job to its writer, or is dropped on a failure.
    async fn spawn(
        &self,
        ctx: &Arc<SessionContext>,
        claims: &Claims,
        busy: Busy,
    ) -> Result<JobStatus, String> {
        let admin = claims.player.as_str();
        let start = begin_snapshot(ctx, 0).await??;
        let info = start.info;
        // Directory work (with its fsyncs) off the async threads.
        let dir = self.dir.clone();
        tokio::task::spawn_blocking(move || {
            crate::durable::create_dir_all(&std::fs::DirBuilder::new(), &dir)
                .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
            // None of this process's runs now (`busy`): any left was cut
            // short.
            remove_stale_partials(&dir);
            Ok::<_, String>(())
        })
        .await
        .map_err(|e| e.to_string())??;
        let file = self.dir.join(format!(
            "strata-seq{}-{}.snap",
            info.seq,
            crate::auth::unix_now()
        ));
        let job = Arc::new(Job {
            admin: admin.to_string(),
            file: file.clone(),
            seq: info.seq,
            total: info.modified_chunks,
            written: AtomicU64::new(0),
            outcome: Mutex::new(None),
        });
        let header = SnapshotHeader::from(info);
        *self.last.lock().unwrap_or_else(|p| p.into_inner()) = Some(job.clone());
        let (ctx, claims) = (ctx.clone(), claims.clone());
        let pre = start.preimages;
        let j = job.clone();
        let (dir, keep) = (self.dir.clone(), self.keep);
        tokio::task::spawn_blocking(move || {
            let admitted = || {
                still_admitted(&ctx, &claims, crate::auth::unix_now())
                    .map_err(|r| format!("stopped: {r}"))
            };
            let result = write_atomically(&file, |out| {
                admitted().map_err(anyhow::Error::msg)?;
                let mut w = SnapshotWriter::new(out, &header)?;
                walk_snapshot(&*ctx.store, &pre, |c| {
                    w.chunk(c.pos, c.version, &c.encoded)
                        .map_err(|e| e.to_string())?;
                    let written = j.written.fetch_add(1, Ordering::Relaxed) + 1;
                    if written % ADMISSION_CHECK_CHUNKS == 0 {
                        admitted()?;
                    }
                    Ok(())
                })
                .map_err(anyhow::Error::msg)?;
                // Not renamed into place for an admin no longer let in.
                admitted().map_err(anyhow::Error::msg)?;
                let chunks = w.records();
                let (out, bytes) = w.finish()?;
                Ok((
                    out,
                    Created {
                        seq: header.seq,
                        chunks,
                        bytes,
                    },
                ))
            });
            drop(pre);
            match &result {
                Ok(c) => {
                    info!(admin = %j.admin, file = %file.display(), seq = c.seq, chunks = c.chunks, "console snapshot written");
                    prune(&dir, keep);
                }
                Err(e) => warn!(admin = %j.admin, error = %e, "console snapshot failed"),
            }
            *j.outcome.lock().unwrap_or_else(|p| p.into_inner()) =
                Some(result.map_err(|e| format!("{e:#}")));
            drop(busy);
        });
        self.status()
            .ok_or_else(|| "the snapshot was not recorded".to_string())
    }
}

/// Whether `name` is a console snapshot's file name, exactly as
/// [`SnapshotJobs::start`] names them (`strata-seqS-T.snap`, digits only):
/// an operator's own `strata-seq5.snap` or `strata-seq5-old.snap` beside
/// them is never pruned.
fn is_console_snapshot(name: &str) -> bool {
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    name.strip_prefix("strata-seq")
        .and_then(|n| n.strip_suffix(".snap"))
        .and_then(|n| n.split_once('-'))
        .is_some_and(|(seq, time)| digits(seq) && digits(time))
}

/// Removes the `.partial` files of console snapshots cut short (the
/// server killed while writing one): each is as large as a snapshot, and
/// no finished one would ever prune it. Failures are logged.
fn remove_stale_partials(dir: &std::path::Path) {
    let console_partial = |name: &str| {
        stale_outputs::partial_writer(name)
            .filter(|(snap, _)| is_console_snapshot(snap))
            .map(|(_, pid)| pid)
    };
    for (path, result) in stale_outputs::remove_stale(dir, console_partial) {
        match result {
            Ok(()) => info!(file = %path.display(), "an unfinished console snapshot removed"),
            Err(e) => {
                warn!(file = %path.display(), error = %e, "removing an unfinished console snapshot failed")
            }
        }
    }
}

/// Removes the oldest console snapshots in `dir` beyond `keep` (oldest by
/// modification time); other files are left alone. Failures are logged.
fn prune(dir: &std::path::Path, keep: usize) {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) => {
            return warn!(dir = %dir.display(), error = %e, "listing console snapshots failed")
        }
    };
    let mut snaps: Vec<(std::time::SystemTime, PathBuf)> = entries
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_str().is_some_and(is_console_snapshot))
        .filter_map(|e| {
            let modified = e.metadata().ok()?.modified().ok()?;
            Some((modified, e.path()))
        })
        .collect();
    if snaps.len() <= keep {
        return;
    }
    snaps.sort();
    for (_, path) in &snaps[..snaps.len() - keep] {
        match std::fs::remove_file(path) {
            Ok(()) => info!(file = %path.display(), "old console snapshot removed"),
            Err(e) => {
                warn!(file = %path.display(), error = %e, "removing an old console snapshot failed")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use tokio::sync::oneshot;

    use super::*;
    use crate::engine::admin::{AdminCommand, SnapshotStart};
    use crate::engine::{Command, Inbox};

    /// How long a start may wait on the engine before it is abandoned.
    const ABANDON_AFTER: Duration = Duration::from_millis(200);
    /// How long the stand-in engine waits for a command.
    const ENGINE_WAIT: Duration = Duration::from_secs(5);
    /// How often the stand-in engine looks at its queue.
    const ENGINE_POLL: Duration = Duration::from_millis(5);
    /// Queue room on each lane of the stand-in engine.
    const ENGINE_QUEUE: usize = 4;
    /// What the stand-in engine answers a snapshot start with.
    const REFUSAL: &str = "the engine refused";

    type Reply = oneshot::Sender<Result<SnapshotStart, String>>;

    /// An admin's claims, good for an hour.
    fn claims(player: &str) -> Claims {
        let now = crate::auth::unix_now();
        Claims {
            player: player.into(),
            role: strata_protocol::Role::Admin,
            issued_at: now,
            expires_at: now + 3_600,
            nonce: Default::default(),
        }
    }

    /// Starts a snapshot for `player`, the stand-in engine answering, and
    /// waits for its end: its state and the files left in `snapshots`.
    async fn snapshot_of(
        jobs: &SnapshotJobs,
        ctx: &Arc<SessionContext>,
        inbox: &Inbox,
        player: &str,
    ) -> (JobStatus, Vec<String>) {
        let engine = async {
            let reply = snapshot_begin(inbox).await.expect("the engine was asked");
            let start = SnapshotStart {
                info: strata_protocol::admin::SnapshotInfo {
                    seq: 0,
                    world_seed: 1,
                    generator_version: 1,
                    generator_params: String::new(),
                    zones: Vec::new(),
                    modified_chunks: 0,
                },
                preimages: Arc::new(crate::engine::snapshot::PreImages::new(0, 16, 1 << 20)),
            };
            assert!(reply.send(Ok(start)).is_ok());
        };
        let admin = claims(player);
        let (started, ()) = tokio::join!(jobs.start(ctx, &admin), engine);
        started.unwrap();
        let deadline = tokio::time::Instant::now() + ENGINE_WAIT;
        let status = loop {
            let status = jobs.status().unwrap();
            if status.state != "running" {
                break status;
            }
            assert!(tokio::time::Instant::now() < deadline, "still running");
            tokio::time::sleep(ENGINE_POLL).await;
        };
        let mut files: Vec<String> = std::fs::read_dir(&jobs.dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        files.sort();
        (status, files)
    }

    /// A context whose engine is the returned inbox (nobody serves it).
    fn context(dir: &std::path::Path) -> (Arc<SessionContext>, Inbox) {
        crate::net::session::test_context(dir, ENGINE_QUEUE)
    }

    /// The reply channel of the next snapshot start the engine is asked
    /// for, or `None` if none comes within [`ENGINE_WAIT`].
    async fn snapshot_begin(inbox: &Inbox) -> Option<Reply> {
        let deadline = tokio::time::Instant::now() + ENGINE_WAIT;
        while tokio::time::Instant::now() < deadline {
            match inbox.recv_timeout(Duration::ZERO) {
                Ok(Command::Admin(AdminCommand::SnapshotBegin { reply, .. })) => {
                    return Some(reply)
                }
                Ok(other) => panic!("not a snapshot start: {other:?}"),
                Err(_) => tokio::time::sleep(ENGINE_POLL).await,
            }
        }
        None
    }

    #[test]
    fn only_console_snapshots_named_as_written_are_pruned() {
        let dir = tempfile::tempdir().unwrap();
        let console = [
            "strata-seq5-100.snap",
            "strata-seq9-300.snap",
            "strata-seq7-200.snap",
        ];
        let operators = [
            "strata-seq5.snap",
            "strata-seq5-old.snap",
            "strata-seq-100.snap",
            "strata-seq5-.snap",
            "strata-seq5-1-2.snap",
        ];
        for (i, n) in console.iter().chain(&operators).enumerate() {
            let path = dir.path().join(n);
            std::fs::write(&path, b"x").unwrap();
            // Operators' files oldest: pruned by mistake, they would go first.
            let secs = if operators.contains(n) { 0 } else { 1_000_000 };
            let at = std::time::UNIX_EPOCH + Duration::from_secs(secs + i as u64);
            std::fs::File::options()
                .write(true)
                .open(&path)
                .unwrap()
                .set_modified(at)
                .unwrap();
        }
        prune(dir.path(), 1);
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        left.sort();
        let mut want: Vec<String> = operators.iter().map(|s| s.to_string()).collect();
        // The newest console snapshot is kept.
        want.push("strata-seq7-200.snap".into());
        want.sort();
        assert_eq!(left, want);
    }

    #[test]
    fn partial_files_of_snapshots_cut_short_are_removed_and_nothing_else() {
        use stale_outputs::testing;
        let dir = tempfile::tempdir().unwrap();
        let names = [
            "strata-seq5-100.snap.9-3.partial",
            "strata-seq7-200.snap.9-0.partial",
            "strata-seq7-300.snap.9-0.partial",
            "strata-seq5-100.snap",
            "world.snap.9-0.partial",
            "strata-seq5-100.snap.partial",
        ];
        // One still being written: its writer holds it.
        let held = testing::files(dir.path(), &names, &[names[2]]);
        remove_stale_partials(dir.path());
        assert_eq!(testing::names_in(dir.path()), testing::sorted(&names[2..]));
        drop(held);
    }

    #[tokio::test]
    async fn an_abandoned_start_leaves_no_snapshot_running() {
        let dir = tempfile::tempdir().unwrap();
        let (ctx, inbox) = context(&dir.path().join("store"));
        let jobs = SnapshotJobs::new(dir.path().join("snapshots"), 8);
        // The engine is asked but does not answer, and the request goes
        // away (a client gone, a timeout).
        let abandoned = tokio::time::timeout(ABANDON_AFTER, jobs.start(&ctx, &claims("ops"))).await;
        assert!(abandoned.is_err(), "{abandoned:?}");
        assert!(
            snapshot_begin(&inbox).await.is_some(),
            "the engine was asked"
        );
        // The next start is not refused as running: it asks the engine too
        // and gets its answer.
        let engine = async {
            let reply = snapshot_begin(&inbox).await;
            reply.map(|r| r.send(Err(REFUSAL.into())).is_ok())
        };
        let ops = claims("ops");
        let (second, answered) = tokio::join!(jobs.start(&ctx, &ops), engine);
        assert_eq!(second.unwrap_err(), REFUSAL);
        assert_eq!(answered, Some(true));
        assert!(jobs.status().is_none(), "no job was recorded");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_snapshot_of_an_admin_no_longer_let_in_stops_and_keeps_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let (ctx, inbox) = context(&dir.path().join("store"));
        let jobs = SnapshotJobs::new(dir.path().join("snapshots"), 8);
        let now = crate::auth::unix_now();
        ctx.access.write().unwrap().ban("eve", None, now).unwrap();
        let (status, files) = snapshot_of(&jobs, &ctx, &inbox, "eve").await;
        assert_eq!(status.state, "failed");
        let error = status.error.unwrap();
        assert!(
            error.contains("stopped") && error.contains("banned"),
            "{error}"
        );
        assert!(files.is_empty(), "{files:?}");
        // Another admin's snapshot of the same world is written.
        let (status, files) = snapshot_of(&jobs, &ctx, &inbox, "ops").await;
        assert_eq!(status.state, "done", "{:?}", status.error);
        assert_eq!(files.len(), 1, "{files:?}");
        assert!(is_console_snapshot(&files[0]), "{files:?}");
    }
}
