//! Live updates for watching consoles, as server-sent events.
//!
//! One hub task samples every `[console] sample_ms` while at least one
//! watcher is connected, and sleeps otherwise: then it reads nothing and
//! asks the engine nothing, so an unwatched console costs the tick nothing.
//! A sample holds the players (from the engine's admin request, served
//! between ticks), the zones, the edits committed since the last sample
//! (read from the store's edit log, not from the tick), the chunk columns
//! they changed (the page redraws those tiles), the chart figures (from the
//! metrics registry) and any snapshot in progress. Each watcher has a
//! bounded queue; a watcher too slow to take a sample misses it, and the
//! next sample it takes says `"lagged": true` (the page then redraws every
//! tile: the columns it missed are unknown). A sample that fails moves
//! the hub's place in the edit log nowhere, so the next lists its edits. A
//! watcher's token is checked again before each sample it is given: once
//! it has expired or been revoked, or its admin is banned, the stream ends.

use std::convert::Infallible;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::response::sse::Event;
use serde::Serialize;
use serde_json::json;
use strata_terrain::Edit;
use tokio::sync::{mpsc, oneshot, Notify};

use super::{auth, stats, Console};
use crate::auth::{unix_now, Claims};
use crate::engine::admin::AdminCommand;
use crate::net::admin_session::ask;
use crate::net::session::SessionContext;
use crate::store::{ChunkStore, LogCursor, LogEntry, StoreError};

/// Longest wait for the engine's answer within a sample.
const ENGINE_ANSWER_TIMEOUT: Duration = Duration::from_secs(2);

/// A watcher's queue.
#[derive(Debug)]
struct Watcher {
    tx: mpsc::Sender<Arc<str>>,
    /// Its queue was full for a sample since the last one it took.
    missed: bool,
}

/// The watchers' queues.
#[derive(Debug, Default)]
pub struct Hub {
    watchers: Mutex<Vec<Watcher>>,
    /// Set when the console stops: no stream is added after.
    closed: std::sync::atomic::AtomicBool,
    wake: Notify,
    /// Samples taken since the start (none while nobody watches).
    samples: AtomicU64,
}

impl Hub {
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Watcher>> {
        self.watchers.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new stream for the admin of `claims`, or `None` when `max` are
    /// connected.
    pub fn subscribe(
        &self,
        (max, queue): (usize, usize),
        ctx: Arc<SessionContext>,
        claims: Claims,
    ) -> Option<EventStream> {
        let mut w = self.lock();
        w.retain(|s| !s.tx.is_closed());
        if w.len() >= max || self.closed.load(Ordering::Acquire) {
            return None;
        }
        let (tx, rx) = mpsc::channel(queue);
        w.push(Watcher { tx, missed: false });
        drop(w);
        self.wake.notify_one();
        Some(EventStream { rx, ctx, claims })
    }

    /// Ends every event stream (their queues closed) and refuses new ones.
    pub fn close(&self) {
        let mut w = self.lock();
        self.closed.store(true, Ordering::Release);
        w.clear();
    }

    /// Samples taken so far.
    pub fn samples(&self) -> u64 {
        self.samples.load(Ordering::Relaxed)
    }

    /// Connected watchers.
    pub fn watchers(&self) -> usize {
        let mut w = self.lock();
        w.retain(|s| !s.tx.is_closed());
        w.len()
    }

    /// Queues `sample` to every watcher that has room; to one that missed
    /// a sample, marked `"lagged": true`.
    fn publish(&self, sample: serde_json::Value) {
        let plain: Arc<str> = sample.to_string().into();
        let mut lagged: Option<Arc<str>> = None;
        self.lock().retain_mut(|w| {
            let data = match w.missed {
                false => plain.clone(),
                true => lagged
                    .get_or_insert_with(|| {
                        let mut s = sample.clone();
                        s["lagged"] = true.into();
                        s.to_string().into()
                    })
                    .clone(),
            };
            match w.tx.try_send(data) {
                Ok(()) => w.missed = false,
                Err(mpsc::error::TrySendError::Full(_)) => w.missed = true,
                Err(mpsc::error::TrySendError::Closed(_)) => return false,
            }
            true
        });
    }
}

/// One watcher's events, while its token stays good.
#[derive(Debug)]
pub struct EventStream {
    rx: mpsc::Receiver<Arc<str>>,
    ctx: Arc<SessionContext>,
    /// The watcher's verified token, checked again before each sample.
    claims: Claims,
}

impl futures_core::Stream for EventStream {
    type Item = Result<Event, Infallible>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        if let Err(refused) = auth::still_admitted(&self.ctx, &self.claims, unix_now()) {
            tracing::info!(admin = %self.claims.player, %refused, "console watcher ended");
            // The hub drops a closed queue at its next sample.
            self.rx.close();
            return Poll::Ready(None);
        }
        self.rx
            .poll_recv(cx)
            .map(|o| o.map(|data| Ok(Event::default().event("sample").data(&*data))))
    }
}

/// Samples while anyone watches; sleeps otherwise.
pub async fn run_hub(console: Arc<Console>) {
    let period = Duration::from_millis(console.cfg.sample_ms);
    // The hub's own place in the edit log; `None` while nobody watches.
    let mut cursor: Option<LogCursor> = None;
    loop {
        if console.hub.watchers() == 0 {
            cursor = None;
            console.hub.wake.notified().await;
            continue;
        }
        console.hub.samples.fetch_add(1, Ordering::Relaxed);
        match take_sample(&console, &mut cursor).await {
            Ok(sample) => console.hub.publish(sample),
            Err(e) => tracing::warn!(error = %e, "console sample failed"),
        }
        tokio::time::sleep(period).await;
    }
}

/// An edit as the map shows it.
#[derive(Debug, Serialize)]
struct EditView {
    seq: u64,
    player: String,
    kind: &'static str,
    /// Where it happened (centre, box middle or structure origin).
    at: [f64; 3],
    time_ms: u64,
}

/// The point an edit is drawn at.
fn anchor(edit: &Edit) -> [f64; 3] {
    let mid = |a: i32, b: i32| (f64::from(a) + f64::from(b)) / 2.0;
    match edit {
        Edit::Mine { center, .. }
        | Edit::Explode { center, .. }
        | Edit::Build { center, .. }
        | Edit::Smooth { center, .. } => center.to_f64(),
        Edit::FillBox { min, max, .. } | Edit::ClearBox { min, max } => {
            [mid(min.x, max.x), mid(min.y, max.y), mid(min.z, max.z)]
        }
        Edit::PlaceStructure { origin, .. } => [origin.x, origin.y, origin.z].map(f64::from),
    }
}

/// Edits past `cursor` (moved past them): the newest `limit` of them, how
/// many more there were, and every chunk column they changed.
struct NewEdits {
    last_seq: u64,
    edits: Vec<EditView>,
    skipped: u64,
    columns: Vec<(i32, i32)>,
    /// More columns changed than a sample names: redraw them all.
    all_changed: bool,
}

/// Past `max_columns` changed columns the list is dropped (`columns`
/// empty, `all_changed`).
fn read_edits(
    store: &dyn ChunkStore,
    cursor: &mut LogCursor,
    limit: usize,
    max_columns: usize,
) -> Result<NewEdits, StoreError> {
    let mut out = NewEdits {
        last_seq: store.last_seq()?,
        edits: Vec::new(),
        skipped: 0,
        columns: Vec::new(),
        all_changed: false,
    };
    cursor.read(store, |entry| {
        let LogEntry {
            seq,
            player,
            time_ms,
            edit,
            changes,
        } = entry;
        if !out.all_changed {
            out.columns.extend(changes.iter().map(|(p, _)| (p.x, p.z)));
            if out.columns.len() > max_columns {
                out.columns.sort_unstable();
                out.columns.dedup();
                if out.columns.len() > max_columns {
                    out.columns = Vec::new();
                    out.all_changed = true;
                }
            }
        }
        out.edits.push(EditView {
            seq,
            player,
            kind: edit.kind().name(),
            at: anchor(&edit),
            time_ms,
        });
        // The oldest go (segments are read one after another), in batches:
        // a long backlog costs a sort per `limit` edits, not a scan each.
        if out.edits.len() >= limit.saturating_mul(2).max(2) {
            keep_newest(&mut out, limit);
        }
    })?;
    keep_newest(&mut out, limit);
    out.columns.sort_unstable();
    out.columns.dedup();
    Ok(out)
}

/// Sorts the edits oldest first and drops all but the newest `limit`,
/// counting those dropped as skipped.
fn keep_newest(out: &mut NewEdits, limit: usize) {
    out.edits.sort_by_key(|e| (e.time_ms, e.seq));
    let extra = out.edits.len().saturating_sub(limit);
    out.edits.drain(..extra);
    out.skipped += extra as u64;
}

/// An engine admin request, given up after [`ENGINE_ANSWER_TIMEOUT`].
async fn ask_in_time<T>(
    console: &Console,
    make: impl FnOnce(oneshot::Sender<T>) -> AdminCommand,
) -> anyhow::Result<T> {
    tokio::time::timeout(ENGINE_ANSWER_TIMEOUT, ask(&console.ctx, make))
        .await
        .map_err(|_| anyhow::anyhow!("the engine did not answer in time"))?
        .map_err(anyhow::Error::msg)
}

/// The next sample; the hub's place in the edit log moves only with one
/// taken whole.
async fn take_sample(
    console: &Arc<Console>,
    cursor: &mut Option<LogCursor>,
) -> anyhow::Result<serde_json::Value> {
    // The engine first: a sample it cannot answer reads no edits (an
    // engine slow for a while leaves its backlog to be read once, not
    // again by every sample given up meanwhile).
    let players = ask_in_time(console, AdminCommand::Players).await?;
    let zones = ask_in_time(console, AdminCommand::Zones).await?;
    let c = console.clone();
    let from = cursor.clone();
    let limit = console.cfg.edits_per_sample;
    let max_columns = console.cfg.columns_per_sample;
    let (edits, next) = tokio::task::spawn_blocking(move || {
        let store = c.world.store().as_ref();
        c.versions.catch_up(store)?;
        // A new watcher starts from now.
        let mut next = match from {
            Some(cursor) => cursor,
            None => LogCursor::at_end(store)?,
        };
        let edits = read_edits(store, &mut next, limit, max_columns)?;
        Ok::<_, StoreError>((edits, next))
    })
    .await??;
    let players: Vec<_> = players
        .into_iter()
        .map(|p| {
            json!({
                "session": p.session,
                "player": p.player,
                "role": p.role.name(),
                "at": p.position.map(|f| f.to_f64()),
            })
        })
        .collect();
    let mut sample = json!({
        "time_ms": crate::engine::now_ms(),
        "seq": edits.last_seq,
        "players": players,
        "zones": zones,
        "edits": edits.edits,
        "edits_skipped": edits.skipped,
        "columns": edits.columns,
        "stats": stats::sample(&console.metrics.render()),
        "snapshot": console.snapshots.status(),
        "watchers": console.hub.watchers(),
    });
    if edits.all_changed {
        sample["lagged"] = true.into();
    }
    *cursor = Some(next);
    Ok(sample)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample names the columns its edits changed, up to its limit;
    /// past it, none (the page redraws every tile).
    #[test]
    fn a_sample_names_changed_columns_up_to_its_limit() {
        use crate::store::{CommitBatch, SledStore};
        use strata_terrain::{Chunk, ChunkPos, FixedVec3, Voxel};
        let tmp = tempfile::tempdir().unwrap();
        let store = SledStore::open(tmp.path()).unwrap();
        store
            .init_meta(&crate::store::WorldMeta::new(1, 1, "seed = 1\n"))
            .unwrap();
        let positions: Vec<ChunkPos> = (0..3).map(|x| ChunkPos::new(x, 0, 7)).collect();
        let entry = |seq: u64, pos: ChunkPos| LogEntry {
            seq,
            player: "ana".into(),
            time_ms: 1,
            edit: Edit::Mine {
                center: FixedVec3::from_voxels(pos.x * 32, 5, 7 * 32),
                radius: strata_terrain::Fixed::from_voxels(2),
                strength: 255,
            },
            changes: vec![(pos, 1), (ChunkPos::new(pos.x, 1, 7), 1)],
        };
        let air = || std::sync::Arc::new(Chunk::uniform(Voxel::AIR));
        store
            .commit_batch(&CommitBatch {
                entries: (1..=3)
                    .map(|i| entry(i, positions[i as usize - 1]))
                    .collect(),
                chunks: positions
                    .iter()
                    .flat_map(|p| [(*p, 1, air()), (ChunkPos::new(p.x, 1, 7), 1, air())])
                    .collect(),
                deltas: Vec::new(),
                generated: Vec::new(),
                last_seq: 3,
                epochs: None,
            })
            .unwrap();
        let named = read_edits(&store, &mut LogCursor::default(), 10, 3).unwrap();
        assert_eq!(named.columns, [(0, 7), (1, 7), (2, 7)]);
        assert!(!named.all_changed);
        assert_eq!(named.edits.len(), 3);
        let past = read_edits(&store, &mut LogCursor::default(), 10, 2).unwrap();
        assert!(past.columns.is_empty() && past.all_changed);
        assert_eq!(past.edits.len(), 3, "the edits are listed all the same");
        // Past `limit` edits, the newest are kept and the rest counted.
        let one = read_edits(&store, &mut LogCursor::default(), 1, 3).unwrap();
        assert_eq!(one.edits.iter().map(|e| e.seq).collect::<Vec<_>>(), [3]);
        assert_eq!(one.skipped, 2);
        let two = read_edits(&store, &mut LogCursor::default(), 2, 3).unwrap();
        assert_eq!(two.edits.iter().map(|e| e.seq).collect::<Vec<_>>(), [2, 3]);
        assert_eq!(two.skipped, 1);
    }

    #[test]
    fn a_watcher_that_missed_a_sample_is_told_so_in_the_next_it_takes() {
        let hub = Hub::new();
        const QUEUE: usize = super::super::DEFAULT_EVENT_QUEUE;
        let (tx, mut rx) = mpsc::channel(QUEUE);
        hub.lock().push(Watcher { tx, missed: false });
        let sample = |n: u64| json!({ "seq": n, "columns": [[n, 0]] });
        for n in 0..QUEUE as u64 {
            hub.publish(sample(n));
        }
        // Full: this one is missed.
        hub.publish(sample(99));
        let lagged =
            |data: &str| serde_json::from_str::<serde_json::Value>(data).unwrap()["lagged"] == true;
        let first = rx.try_recv().unwrap();
        assert!(!lagged(&first));
        hub.publish(sample(100));
        let taken: Vec<Arc<str>> = std::iter::from_fn(|| rx.try_recv().ok()).collect();
        assert_eq!(taken.len(), QUEUE);
        let last = taken.last().unwrap();
        assert!(last.contains("\"seq\":100") && lagged(last), "{last}");
        assert!(taken[..QUEUE - 1].iter().all(|d| !lagged(d)));
        // Told once: the next is plain again.
        hub.publish(sample(101));
        assert!(!lagged(&rx.try_recv().unwrap()));
    }
}
