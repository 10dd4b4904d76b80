//! Snapshots started from the console: registered with the engine and read
//! through the pre-images exactly as `strata-admin snapshot create` online
//! (the admin session's `begin_snapshot` and `walk_snapshot`), written on
//! the server into the console's snapshot directory through a `.partial`
//! file renamed into place. One runs at a time; watchers see its progress.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use serde::Serialize;
use tracing::{info, warn};

use crate::admin::snapshot_cmd::{write_atomically, Created};
use crate::net::admin_session::{begin_snapshot, walk_snapshot};
use crate::net::session::SessionContext;
use crate::snapshot::{SnapshotHeader, SnapshotWriter};

/// The console's snapshot, running or last finished.
#[derive(Debug)]
pub struct SnapshotJobs {
    dir: PathBuf,
    busy: Arc<AtomicBool>,
    last: Mutex<Option<Arc<Job>>>,
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
    pub fn new(dir: PathBuf) -> Self {
        Self {
            dir,
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

    /// Starts a snapshot for `admin`; refused while one runs.
    pub async fn start(&self, ctx: &Arc<SessionContext>, admin: &str) -> Result<JobStatus, String> {
        if self.busy.swap(true, Ordering::AcqRel) {
            return Err("a snapshot is already running".into());
        }
        let started = self.spawn(ctx, admin).await;
        if started.is_err() {
            self.busy.store(false, Ordering::Release);
        }
        started
    }

    async fn spawn(&self, ctx: &Arc<SessionContext>, admin: &str) -> Result<JobStatus, String> {
        let start = begin_snapshot(ctx, 0).await??;
        let info = start.info;
        crate::durable::create_dir_all(&std::fs::DirBuilder::new(), &self.dir)
            .map_err(|e| format!("cannot create {}: {e}", self.dir.display()))?;
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
        let store = ctx.store.clone();
        let pre = start.preimages;
        let busy = self.busy.clone();
        let j = job.clone();
        tokio::task::spawn_blocking(move || {
            let result = write_atomically(&file, |out| {
                let mut w = SnapshotWriter::new(out, &header)?;
                walk_snapshot(&*store, &pre, |c| {
                    w.chunk(c.pos, c.version, &c.encoded)
                        .map_err(|e| e.to_string())?;
                    j.written.fetch_add(1, Ordering::Relaxed);
                    Ok(())
                })
                .map_err(anyhow::Error::msg)?;
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
                    info!(admin = %j.admin, file = %file.display(), seq = c.seq, chunks = c.chunks, "console snapshot written")
                }
                Err(e) => warn!(admin = %j.admin, error = %e, "console snapshot failed"),
            }
            *j.outcome.lock().unwrap_or_else(|p| p.into_inner()) =
                Some(result.map_err(|e| format!("{e:#}")));
            busy.store(false, Ordering::Release);
        });
        self.status()
            .ok_or_else(|| "the snapshot was not recorded".to_string())
    }
}
