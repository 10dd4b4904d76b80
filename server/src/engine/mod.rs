//! The engine: one thread that owns the [`Sequencer`], the store handle and
//! every session's streaming state. It is the only writer of the world.
//!
//! Each tick: apply queued edits ([`Sequencer::tick`]), make them durable
//! with one group commit, and only then acknowledge them and fan their
//! deltas out; then stream snapshots to sessions under a byte budget. The
//! engine never blocks on a client: it `try_send`s encoded frames to each
//! connection's bounded writer, and a client whose queue is full loses its
//! pending deltas and gets fresh snapshots later.

pub mod admin;
mod command;
mod commit;
mod config;
mod dispatch;
mod fanout;
mod frame_cache;
mod generated;
mod holders;
mod inbox;
mod latest;
mod ops;
mod owners;
mod ownership;
mod peer;
mod pending;
mod pool;
mod position_refusal;
mod prebuild;
mod premesh;
mod residency;
mod session_share;
pub mod snapshot;
mod stream;
mod tick;
mod unreadable;

pub use command::{Command, JoinReply, Kick, REPLACED};
pub use config::{
    EngineConfig, StreamPolicy, DEFAULT_COMMAND_QUEUE, DEFAULT_CONTROL_QUEUE,
    DEFAULT_SESSIONS_PER_PLAYER, DEFAULT_STREAM_US, DEFAULT_TICK_MS, MAX_COMMAND_QUEUE,
    MAX_ENGINE_CACHE, MAX_STREAM_US, MAX_TICK_MS, MAX_WORKERS, POSITION_SAVE_EVERY,
    SLOW_TICK_PERIODS,
};
pub use fanout::encode_control as fanout_control;
pub use frame_cache::{DEFAULT_FULL_FRAME_CACHE_ENTRIES, DEFAULT_SNAPSHOT_CACHE_ENTRIES};
pub use inbox::{channel as inbox_channel, EngineHandle, Inbox, Queued};
pub use latest::LatestPosition;
pub use ownership::RELOAD_RETRY;
pub use premesh::{
    DEFAULT_PREMESH_BACKLOG, DEFAULT_PREMESH_GENERATED_CHUNKS, DEFAULT_PREMESH_INFLIGHT,
    DEFAULT_PREMESH_RADIUS, DEFAULT_PREMESH_THREADS, MAX_PREMESH_RADIUS, MAX_PREMESH_THREADS,
};
pub use residency::{DEFAULT_RESIDENT_CHUNKS, MIN_RESIDENT_CHUNKS};
pub use session_share::{QueueSlot, SessionShare, DEFAULT_SESSION_COMMANDS};
pub use stream::DEFAULT_PATCH_BASE_CHUNKS;
pub(crate) use tick::Applied;
pub use tick::MAX_CHAINED_COMMITS;

use std::collections::HashMap;
use std::sync::mpsc::RecvTimeoutError;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use strata_protocol::ErrorCode;
use strata_terrain::ChunkPos;
use tracing::{error, info, warn};

use crate::health::StoreWork;
use crate::interest::InterestConfig;
use crate::sequencer::Sequencer;
use crate::store::ChunkStore;
use crate::validate::bounds::WorldBounds;
use peer::Peer;

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Everything the engine thread owns.
pub struct Engine {
    seq: Sequencer,
    store: Arc<dyn ChunkStore>,
    cfg: EngineConfig,
    stream: StreamPolicy,
    interest: InterestConfig,
    bounds: WorldBounds,
    peers: HashMap<u64, Peer>,
    /// Which sessions hold each chunk: the fan-out visits only those.
    holders: holders::Holders,
    /// Durable version of every modified chunk (absent = version 0).
    versions: HashMap<ChunkPos, u64>,
    snapshots: frame_cache::SnapshotCache,
    /// The session last streamed to; the next tick starts after it.
    stream_cursor: u64,
    patch_bases: generated::GeneratedCache,
    /// What a snapshot frame built ahead has cost lately.
    prebuild_cost: prebuild::PrebuildCost,
    /// Stored chunks found unreadable lately: not streamed meanwhile.
    unreadable: unreadable::Unreadable,
    premesh: premesh::Premesher,
    last_evict: Option<Instant>,
    /// Online snapshots in progress (their copy-on-write pre-images).
    snapshots_running: Vec<Arc<snapshot::PreImages>>,
    /// Commands that arrived during a commit and must wait for it.
    deferred: commit::Deferred,
    /// The commit thread (started with the engine's loop; `None` before,
    /// or if no thread could be had: then ticks commit inline).
    committer: Option<commit::Committer>,
    /// The last seq the store holds durably. The sequencer's own runs
    /// ahead of it while a commit is in flight; clients are told only this.
    durable_seq: u64,
    /// The `[engine] workers` threads; on the engine's own thread, with
    /// two or more, the engine thread is one of them ([`pool::build`]).
    pool: Arc<rayon::ThreadPool>,
    /// Signs `RegionOwners` tickets (the cluster's shared auth secret, for
    /// its world).
    ticket_key: Option<crate::cluster::ticket::TicketKey>,
    /// Told after every tick (`/healthz`: an engine that stops ticking is
    /// not ready).
    health: Option<Arc<crate::health::Health>>,
    /// When the sessions' region holders are next looked at.
    owners_due: Instant,
    /// A cluster node's lease epoch for each region it last reloaded
    /// (`ownership.rs`): what its batches are fenced by.
    region_epochs: HashMap<crate::sequencer::regions::RegionId, u64>,
    /// Regions reported fresh whose reload failed, with the epoch to take
    /// once it succeeds; until then their batches carry no epoch and are
    /// fenced. Retried at most every [`ownership::RELOAD_RETRY`].
    reload_retry: std::collections::BTreeMap<crate::sequencer::regions::RegionId, Option<u64>>,
    reload_retry_at: Option<Instant>,
    /// Free regions read from the store for an edit's sight check, and
    /// when: read again only after [`ownership::FREE_REREAD`] (at most
    /// [`ownership::MAX_FREE_READ`] kept).
    free_read: std::collections::BTreeMap<crate::sequencer::regions::RegionId, Instant>,
    /// Regions of the sessions' views no node holds, as `tell_owners` last
    /// read them (none after a failed read): a move is swept through
    /// these and this node's own, not through others' copies here.
    free_regions: std::collections::HashSet<crate::sequencer::regions::RegionId>,
    /// The mark (claim epoch, last seq) at which each free region's copies
    /// here were last brought current (`Engine::bring_free_current`; at
    /// most `owners::MAX_FREE_SEEN`).
    free_seen: HashMap<crate::sequencer::regions::RegionId, crate::store::RegionMark>,
    /// The free regions current here at the last check, and when it ran
    /// (one every `owners::FREE_CHECK_EVERY`).
    free_current: std::collections::HashSet<crate::sequencer::regions::RegionId>,
    free_checked: Option<Instant>,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("peers", &self.peers.len())
            .finish_non_exhaustive()
    }
}

impl Engine {
    pub fn new(
        seq: Sequencer,
        store: Arc<dyn ChunkStore>,
        cfg: EngineConfig,
        stream: StreamPolicy,
        interest: InterestConfig,
        bounds: WorldBounds,
        versions: HashMap<ChunkPos, u64>,
    ) -> std::io::Result<Self> {
        let mut seq = seq;
        if store.clustered() {
            // Until this node knows a region is its own or free, a move is
            // not swept through it (`ownership::follow_leases`).
            seq.set_swept_regions(Some(Default::default()));
        }
        let workers = match cfg.workers {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            n => n.min(MAX_WORKERS),
        };
        let pool = pool::build(workers, false)?;
        Ok(Self {
            pool: Arc::new(pool),
            premesh: premesh::Premesher::new(premesh::PremeshLimits {
                inflight: cfg.premesh_inflight,
                backlog: cfg.premesh_backlog,
                generated_chunks: cfg.premesh_generated_chunks,
                threads: cfg.premesh_threads,
            })?,
            durable_seq: seq.last_seq(),
            seq,
            store,
            cfg,
            stream,
            interest,
            bounds,
            peers: HashMap::new(),
            holders: Default::default(),
            versions,
            snapshots: frame_cache::SnapshotCache::new(
                cfg.snapshot_cache_entries,
                cfg.full_frame_cache_entries,
                stream.regenerable,
            ),
            stream_cursor: 0,
            patch_bases: generated::GeneratedCache::new(
                cfg.patch_base_chunks,
                generated::Use::PatchBase,
            ),
            prebuild_cost: Default::default(),
            unreadable: Default::default(),
            last_evict: None,
            snapshots_running: Vec::new(),
            deferred: Default::default(),
            committer: None,
            ticket_key: None,
            health: None,
            owners_due: Instant::now(),
            region_epochs: HashMap::new(),
            reload_retry: Default::default(),
            reload_retry_at: None,
            free_read: Default::default(),
            free_regions: Default::default(),
            free_seen: Default::default(),
            free_current: Default::default(),
            free_checked: None,
        })
    }

    /// Signs the tickets `RegionOwners` carries with `key`.
    pub fn with_ticket_key(mut self, key: crate::cluster::ticket::TicketKey) -> Self {
        self.ticket_key = Some(key);
        self
    }

    /// Reports each tick, and its store operations' outcomes, to `health`.
    pub fn with_health(mut self, health: Arc<crate::health::Health>) -> Self {
        self.health = Some(health);
        self
    }

    /// Tells `health` how an operation that reached the store went
    /// (`/healthz` turns unready while they keep failing). An error that is
    /// not the store's (a record that does not decode, a lease lost) is
    /// neither (`StoreError::is_store_fault`).
    fn store_answered<T>(&self, result: &Result<T, crate::store::StoreError>) {
        if let Some(h) = &self.health {
            h.report(StoreWork::Engine, result);
        }
    }

    /// [`Self::store_answered`] for a failure only: for calls that may be
    /// answered from memory, whose success says nothing of the store.
    fn store_failed(&self, error: &crate::store::StoreError) {
        if let Some(h) = &self.health {
            h.store_error(StoreWork::Engine, error);
        }
    }

    /// Starts the engine thread. It stops on [`Command::Stop`] or when
    /// every handle is dropped, after flushing the batch in flight, or on a
    /// failed commit. `on_exit` runs when the thread ends, however it ends
    /// (a panic included).
    pub fn spawn(
        self,
        on_exit: impl FnOnce() + Send + 'static,
    ) -> std::io::Result<(EngineHandle, std::thread::JoinHandle<anyhow::Result<()>>)> {
        let (tx, rx) = inbox::channel(self.cfg.command_queue, self.cfg.control_queue);
        let tx = tx.with_session_commands(self.cfg.session_commands);
        let handle = std::thread::Builder::new()
            .name("strata-engine".into())
            .spawn(move || {
                let _exit = OnExit(Some(on_exit));
                self.run(rx)
            })?;
        Ok((tx, handle))
    }

    fn run(mut self, rx: Inbox) -> anyhow::Result<()> {
        let workers = self.pool.current_num_threads();
        if workers >= 2 {
            // A failure leaves this thread attached to a pool that is gone:
            // no engine.
            self.pool = Arc::new(pool::build(workers, true)?);
        }
        self.store.encode_on(Some(self.pool.clone()));
        let ended = self.serve(rx);
        // The pool's threads end with the engine, not with the store.
        self.store.encode_on(None);
        // However it ends: a snapshot still being read stops at its next
        // chunk instead of holding the process's exit (or a console job's
        // file) until the whole world is read.
        self.abort_snapshots(snapshot::STOPPING);
        ended
    }

    fn serve(&mut self, rx: Inbox) -> anyhow::Result<()> {
        if let Some(h) = &self.health {
            h.expect_every(StoreWork::PositionSaves, POSITION_SAVE_EVERY);
        }
        match commit::Committer::spawn(self.store.clone(), rx.waker(), self.health.clone()) {
            Ok(c) => self.committer = Some(c),
            Err(e) => warn!(error = %e, "no commit thread; ticks commit inline"),
        }
        let period = Duration::from_millis(self.cfg.tick_ms.max(1));
        let mut next_tick = Instant::now() + period;
        // When ticks overrun their period, commands already queued still
        // get until this (half a period after the last tick ended) before
        // the next tick: else a busy engine would take one command per tick
        // and submit edits only while commits run.
        let mut commands_until = Instant::now();
        let mut next_position_save = Instant::now() + POSITION_SAVE_EVERY;
        loop {
            let next = match self.deferred.pop() {
                Some(cmd) => Ok(cmd),
                None => self.next_command(&rx, next_tick),
            };
            let mut handled = false;
            match next {
                Ok(Command::Stop) | Err(RecvTimeoutError::Disconnected) => {
                    info!("engine stopping: final tick and flush");
                    self.tick(None)?;
                    self.close_all();
                    self.save_positions();
                    // Joins the commit thread once it has done every job
                    // queued: the last positions are stored, after the
                    // earlier ones. Those a failed save left are tried
                    // once more here.
                    if let Some(committer) = self.committer.take() {
                        for player in committer.finish() {
                            self.seq.mark_moved(player);
                        }
                        self.save_positions();
                    }
                    return Ok(());
                }
                Ok(cmd) => {
                    self.handle(cmd);
                    handled = true;
                }
                Err(RecvTimeoutError::Timeout) => {}
            }
            self.collect_premeshed();
            let now = Instant::now();
            if now >= next_tick && !(handled && now < commands_until) {
                self.tick(Some(&rx))?;
                if let Some(h) = &self.health {
                    h.ticked();
                }
                // A fixed rate: a long tick shortens the wait for the next
                // one instead of adding to it (no catching up past now).
                next_tick = (next_tick + period).max(now);
                commands_until = Instant::now() + period / 2;
            }
            if now >= next_position_save {
                self.save_positions();
                next_position_save = now + POSITION_SAVE_EVERY;
            }
        }
    }

    /// The next command, waiting until `next_tick` at most. Edits awaiting
    /// their sight check are checked first if none is waiting, so the
    /// check runs while the engine would idle, not at the tick (which
    /// checks whatever arrived since).
    fn next_command(
        &mut self,
        rx: &Inbox,
        next_tick: Instant,
    ) -> Result<Command, RecvTimeoutError> {
        if self.seq.sighting() > 0 {
            match rx.recv_or_wake(Duration::ZERO) {
                Ok(Some(cmd)) => return Ok(cmd),
                Ok(None) => self.check_sighted(),
                Err(e) => return Err(e),
            }
        }
        rx.recv_timeout(next_tick.saturating_duration_since(Instant::now()))
    }

    /// Stores the positions of players who moved since the last save: on
    /// the commit thread (no commit runs now, so it goes next), or here
    /// without that thread. A failure is logged, and those players are
    /// saved again at the next save (where they are then): positions are
    /// recoverable state, unlike edits, but a logout's spot is not lost to
    /// a store that failed for a while.
    fn save_positions(&mut self) {
        if let Some(committer) = &self.committer {
            for player in committer.take_unsaved() {
                self.seq.mark_moved(player);
            }
        }
        let mut moved = self.seq.take_moved();
        if moved.is_empty() {
            return;
        }
        if let Some(committer) = &self.committer {
            match committer.save_positions(moved) {
                Ok(()) => return,
                Err(back) => moved = back,
            }
        }
        let saved = self.store.save_positions(&moved);
        if let Some(h) = &self.health {
            h.report(StoreWork::PositionSaves, &saved);
        }
        if let Err(e) = saved {
            error!(error = %e, players = moved.len(), "saving player positions failed; they are saved again next time");
            for (player, _) in moved {
                self.seq.mark_moved(player);
            }
        }
    }

    /// Live sessions of `player` (the sequencer's index: no scan of
    /// every session).
    fn sessions_of(&self, player: &str) -> Vec<u64> {
        self.seq
            .sessions_of(player)
            .iter()
            .copied()
            .filter(|id| self.peers.contains_key(id))
            .collect()
    }

    /// Ends a session now: its connection closes with `code`, and the
    /// engine forgets it (its later `Leave` finds nothing).
    fn end_session(&mut self, id: u64, code: ErrorCode, message: &str) {
        if let Some(mut p) = self.peers.remove(&id) {
            p.unlist_all(&mut self.holders, id);
            p.kick(code, message);
        }
        self.seq.session_left(id);
    }

    fn close_all(&mut self) {
        for (id, mut p) in self.peers.drain() {
            p.kick(ErrorCode::ShuttingDown, "server is shutting down");
            self.seq.session_left(id);
        }
        self.holders.clear();
    }
}

/// Calls its function when dropped: at the end of the engine thread,
/// whether it returned or unwound.
struct OnExit<F: FnOnce()>(Option<F>);

impl<F: FnOnce()> Drop for OnExit<F> {
    fn drop(&mut self) {
        if let Some(f) = self.0.take() {
            f();
        }
    }
}
