//! A session for a game loop: the connection runs on its own thread (a
//! one-worker tokio runtime owned by the session), and the game calls plain
//! functions that never wait on the network, except [`Session::connect`].
//! Edits return a ticket at once; their verdicts, chunk changes and the
//! end of the connection come out of [`Session::poll`].
//!
//! [`Session::connect_cluster`] plays on a cluster of nodes through a
//! [`ClusterClient`]: positions go to every node, each edit to the node
//! that writes its region, and each chunk is read from that node's replica;
//! the connection thread follows the nodes' `RegionOwners` every
//! [`FOLLOW_EVERY`].

mod dispatch;
mod error;
mod event;
mod links;

use std::future::Future;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::time::Duration;

use glam::{DVec3, IVec3};
use strata_protocol::Welcome;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::{ChunkPos, Edit, CHUNK_VOLUME};
use tokio::runtime::Runtime;
use tokio::sync::mpsc;
use tokio::task::JoinSet;

use crate::client::{Client, ClientError, ClientOptions};
use crate::cluster::ClusterClient;
use crate::coords::to_fixed;
use crate::mesh::{mesh_at, ChunkMesh};
use crate::notice::Notice;
use crate::prediction::PredictionStats;
use crate::replica::ReplicaStats;
pub use dispatch::FOLLOW_EVERY;
use dispatch::{dispatch, dispatch_cluster, watch_close, Command};
pub use error::SessionError;
pub use event::Event;
use links::Links;
pub use links::MAX_MOVED_CHUNKS;

/// Edits and subscriptions queued for the connection thread, and edits
/// whose verdict the game has not polled yet: past it, calls say `Busy`.
pub const MAX_IN_FLIGHT: usize = 1024;

/// How a session keeps its view.
#[derive(Debug, Clone, Default)]
pub struct SessionOptions {
    /// Show the player's own edits at once, before the server's verdict,
    /// and reconcile (see [`crate::prediction`]).
    pub predict: bool,
    /// The server's structure templates, to predict `PlaceStructure`.
    pub structures: Arc<StructureLibrary>,
    /// `Hello::capabilities`: `CAP_SNAPSHOTS` (whole chunks, no generator
    /// needed), `CAP_OP_REPLAY` (edits replayed here instead of deltas).
    pub capabilities: u32,
}

/// A chunk's voxels as the player should see them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChunkData {
    pub pos: ChunkPos,
    /// The server's version of the chunk this view starts from.
    pub version: u64,
    /// Whether the player's pending predicted edits changed it.
    pub predicted: bool,
    /// One byte per voxel, index `x + 32 * (y + 32 * z)`; solid from 128.
    pub density: Box<[u8; CHUNK_VOLUME]>,
    /// Material ids, same layout.
    pub material: Box<[u8; CHUNK_VOLUME]>,
}

/// One connected player, driven from a game loop. Every method takes
/// `&self` and may be called from any thread.
#[derive(Debug)]
pub struct Session {
    links: Arc<Links>,
    commands: mpsc::Sender<Command>,
    events: Mutex<std_mpsc::Receiver<Event>>,
    /// Set once the connection has ended, with why.
    closed: Arc<Mutex<Option<ClientError>>>,
    /// Whether `Disconnected` was polled. Held while `poll` decides on it
    /// and while an edit, forget or resync is taken, so none is taken
    /// after it and nothing is polled after it.
    disconnect_reported: Mutex<bool>,
    /// Edits taken whose verdict event has not been polled.
    unpolled: AtomicUsize,
    next_ticket: AtomicU64,
    // Last, so it is dropped after the client it drives.
    runtime: SessionRuntime,
}

impl Session {
    /// Connects to `addr`, trusting only the server certificate
    /// `server_cert` (DER), and logs in with `token`. Blocks until the
    /// server's `Welcome` (at most [`crate::client::CONNECT_TIMEOUT`]).
    /// Must not be called from inside a tokio runtime.
    pub fn connect(
        addr: SocketAddr,
        server_cert: &[u8],
        token: &str,
        opts: SessionOptions,
    ) -> Result<Session, SessionError> {
        let runtime = runtime()?;
        let client = runtime.block_on(Client::connect_opts(
            addr,
            server_cert,
            token,
            client_options(opts),
        ))?;
        let client = Arc::new(client);
        let (commands, rx) = mpsc::channel(MAX_IN_FLIGHT);
        let (events_tx, events) = std_mpsc::channel();
        runtime.spawn(dispatch(client.clone(), rx, events_tx));
        Ok(Self::started(
            runtime,
            Arc::new(Links::one(client)),
            commands,
            events,
        ))
    }

    /// Connects to node `home` of a cluster (its nodes share `server_cert`
    /// and the token's secret), as [`Self::connect`], then follows the
    /// nodes the cluster names: each edit goes to the node that writes its
    /// region (a region's edits one at a time, in the order taken, other
    /// regions' meanwhile: a node that stopped answering holds up only its
    /// regions' edits),
    /// and each chunk is read from that node's replica. When a region's
    /// writer changes, its held chunks are reported changed.
    pub fn connect_cluster(
        home: SocketAddr,
        server_cert: &[u8],
        token: &str,
        opts: SessionOptions,
    ) -> Result<Session, SessionError> {
        let runtime = runtime()?;
        let cluster = runtime
            .block_on(ClusterClient::connect(
                home,
                server_cert,
                token,
                client_options(opts),
            ))
            .map_err(|e| match e {
                crate::cluster::ClusterError::Client(c) => c,
                // A setup failure (a bad address, too many nodes, a node
                // refusing the arrival): the connection never was.
                other => ClientError::Connect(other.to_string()),
            })?;
        let links = Arc::new(Links::cluster(cluster.view()));
        let (commands, rx) = mpsc::channel(MAX_IN_FLIGHT);
        let (events_tx, events) = std_mpsc::channel();
        runtime.spawn(dispatch_cluster(cluster, links.clone(), rx, events_tx));
        Ok(Self::started(runtime, links, commands, events))
    }

    fn started(
        runtime: Runtime,
        links: Arc<Links>,
        commands: mpsc::Sender<Command>,
        events: std_mpsc::Receiver<Event>,
    ) -> Session {
        let closed = Arc::default();
        runtime.spawn(watch_close(links.home.clone(), Arc::clone(&closed)));
        Session {
            links,
            commands,
            events: Mutex::new(events),
            closed,
            disconnect_reported: Mutex::new(false),
            unpolled: AtomicUsize::new(0),
            next_ticket: AtomicU64::new(1),
            runtime: SessionRuntime(Some(runtime)),
        }
    }

    /// The server's greeting: world seed, view radius, spawn and so on.
    pub fn welcome(&self) -> &Welcome {
        self.links.home.welcome()
    }

    /// Reports the player's feet position, in voxels (an unreliable
    /// datagram: send it every frame or so). Interest follows it.
    pub fn set_position(&self, feet: DVec3) -> Result<(), SessionError> {
        let pos = to_fixed(feet).ok_or(SessionError::BadPosition)?;
        let mut sent = Ok(());
        for (i, c) in self.links.all().iter().enumerate() {
            let r = c.send_position(pos);
            if i == 0 {
                sent = r;
            }
        }
        Ok(sent?)
    }

    /// Asks for the cube of chunks within `radius` of `center` (capped by
    /// the server's view radius). The whole cube must lie within view
    /// radius + hysteresis chunks of the player; positions then move it
    /// only when it would reach farther (to the feet, keeping its radius;
    /// on a cluster, farther than the view radius alone at the next
    /// position set, never an admin's: see
    /// [`crate::ClusterClient::subscribe`]). A centre outside the world is
    /// refused
    /// ([`crate::bounds::center_in_world`]).
    pub fn subscribe(&self, center: IVec3, radius: u8) -> Result<(), SessionError> {
        let center = ChunkPos::new(center.x, center.y, center.z);
        crate::client::check_center(center)?;
        self.queue_live(Command::Subscribe { center, radius })
    }

    /// Drops chunks the game no longer wants (chunk coordinates, at most
    /// `MAX_FORGET_CHUNKS`): they stop being held at once and the server
    /// stops sending their updates. [`Self::resync`], or a chunk leaving the
    /// view and coming back, brings one back.
    pub fn forget(&self, chunks: &[IVec3]) -> Result<(), SessionError> {
        let max = strata_protocol::limits::MAX_FORGET_CHUNKS;
        if chunks.len() > max {
            let chunks = chunks.len();
            return Err(ClientError::TooManyChunks { chunks, max }.into());
        }
        let chunks = chunks
            .iter()
            .map(|c| ChunkPos::new(c.x, c.y, c.z))
            .collect();
        self.queue_live(Command::Forget { chunks })
    }

    /// Asks the server to send a chunk again (one forgotten, or one whose
    /// copy looks wrong); it must be in the view.
    pub fn resync(&self, chunk: IVec3) -> Result<(), SessionError> {
        let pos = ChunkPos::new(chunk.x, chunk.y, chunk.z);
        self.queue_live(Command::Resync { pos })
    }

    /// Sends an edit (build one with [`crate::edits`]) and returns its
    /// ticket at once; its verdict comes from [`Self::poll`]. Edits reach
    /// the server in the order they were taken (on a cluster, those of one
    /// region; verdicts of different regions may come in another order).
    /// Once `Disconnected` was polled, refused with [`ClientError::Closed`].
    pub fn edit(&self, edit: Edit) -> Result<u64, SessionError> {
        // Held until the edit is counted: `poll` reports `Disconnected`
        // only with no edit unpolled, under this lock.
        let reported = self.reported();
        if *reported {
            return Err(after_disconnect());
        }
        if self.unpolled.fetch_add(1, Ordering::SeqCst) >= MAX_IN_FLIGHT {
            self.unpolled.fetch_sub(1, Ordering::SeqCst);
            return Err(SessionError::Busy);
        }
        let ticket = self.next_ticket.fetch_add(1, Ordering::Relaxed);
        self.queue(Command::Edit { ticket, edit })
            .inspect_err(|_| {
                self.unpolled.fetch_sub(1, Ordering::SeqCst);
            })?;
        Ok(ticket)
    }

    fn reported(&self) -> std::sync::MutexGuard<'_, bool> {
        self.disconnect_reported
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Queues `c` unless `Disconnected` was polled (then
    /// [`ClientError::Closed`]); the check and the queueing under the lock
    /// `poll` reports it under.
    fn queue_live(&self, c: Command) -> Result<(), SessionError> {
        let reported = self.reported();
        if *reported {
            return Err(after_disconnect());
        }
        self.queue(c)
    }

    fn queue(&self, c: Command) -> Result<(), SessionError> {
        self.commands.try_send(c).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => SessionError::Busy,
            mpsc::error::TrySendError::Closed(_) => {
                SessionError::Client(ClientError::Closed("session stopped".into()))
            }
        })
    }

    /// The next event, or `None` when nothing new happened. Never waits.
    /// After `Disconnected`, always `None`.
    pub fn poll(&self) -> Option<Event> {
        let mut reported = self.reported();
        if *reported {
            return None;
        }
        if let Ok(e) = self
            .events
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .try_recv()
        {
            self.unpolled.fetch_sub(1, Ordering::SeqCst);
            return Some(e);
        }
        match self.links.home.pop_notice() {
            Some(Notice::PositionRefused { seq, reason, at }) => {
                return Some(Event::PositionRefused { seq, reason, at });
            }
            Some(Notice::ViewLoaded { center, radius }) => {
                return Some(Event::ViewLoaded { center, radius })
            }
            None => {}
        }
        // Other nodes' refusals too (each checks its own regions' walls);
        // their views are the home node's to report.
        if self.links.is_cluster() {
            for c in self.links.all().iter().skip(1) {
                while let Some(n) = c.pop_notice() {
                    if let Notice::PositionRefused { seq, reason, at } = n {
                        return Some(Event::PositionRefused { seq, reason, at });
                    }
                }
            }
        }
        if let Some(pos) = self.links.pop_changed() {
            return Some(Event::ChunkChanged { pos });
        }
        // Disconnected comes last: after every edit's verdict or failure
        // (no edit is taken while the lock is held).
        if self.unpolled.load(Ordering::SeqCst) > 0 {
            return None;
        }
        let closed = self
            .closed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let why = closed.as_ref()?;
        *reported = true;
        Some(match why {
            ClientError::Refused { code, message } => Event::Disconnected {
                code: Some(*code),
                message: message.clone(),
            },
            other => Event::Disconnected {
                code: None,
                message: other.to_string(),
            },
        })
    }

    /// Whether the connection has ended (the `Disconnected` event may still
    /// be waiting behind others).
    pub fn is_closed(&self) -> bool {
        self.links.home.is_closed()
    }

    /// A held chunk's densities and materials, with the player's pending
    /// predicted edits applied when predicting; `None` when not held.
    pub fn chunk(&self, pos: ChunkPos) -> Option<ChunkData> {
        let (chunk, version, predicted) = self.links.for_chunk(pos).visible_chunk(pos)?;
        Some(ChunkData {
            pos,
            version,
            predicted,
            density: chunk.density_plane(),
            material: chunk.material_plane(),
        })
    }

    /// The mesh of a held chunk as the player sees it, at `lod` (0..=3),
    /// with transition cells on `transition_faces` (bits -X, +X, -Y, +Y,
    /// -Z, +Z: faces bordering a finer chunk; 0 at LOD 0). `None` when the
    /// chunk is not held.
    pub fn mesh(
        &self,
        pos: ChunkPos,
        lod: u8,
        transition_faces: u8,
    ) -> Result<Option<ChunkMesh>, SessionError> {
        Ok(mesh_at(pos, lod, transition_faces, |p| {
            self.links.for_chunk(p).predicted_chunk(p)
        })?)
    }

    /// Chunks held now (on a cluster, by the first node's connection:
    /// every connection holds the whole view).
    pub fn held_chunks(&self) -> usize {
        self.links.home.replica().len()
    }

    /// The replica's counters: chunks taken in, deltas applied, meshes
    /// checked against the server's hashes and mismatches (on a cluster,
    /// summed over the connections).
    pub fn stats(&self) -> ReplicaStats {
        let mut sum = ReplicaStats::default();
        for c in self.links.all() {
            sum += c.replica().stats;
        }
        sum
    }

    /// How predictions fared; `None` when not predicting (on a cluster,
    /// summed over the connections).
    pub fn prediction_stats(&self) -> Option<PredictionStats> {
        let mut sum: Option<PredictionStats> = None;
        for p in self.links.all().iter().filter_map(|c| c.prediction_stats()) {
            sum.get_or_insert_with(PredictionStats::default).add(&p);
        }
        sum
    }

    /// Closes the connections politely, all at once, and stops the thread
    /// (waiting at most two seconds in all). Dropping a session does the
    /// same without the polite close.
    pub fn close(self) {
        let closes = self.links.all().into_iter().map(|c| async move {
            c.shutdown().await;
        });
        if let Some(rt) = &self.runtime.0 {
            rt.block_on(all_within(POLITE_WAIT, closes));
        }
    }
}

/// The error of a call after `Disconnected` was polled.
fn after_disconnect() -> SessionError {
    SessionError::Client(ClientError::Closed("the session has disconnected".into()))
}

/// The session's runtime: dropped, it stops within [`STOP_WAIT`], where a
/// plain drop would wait for every blocking task (a name lookup stuck in
/// `getaddrinfo`, which no timeout interrupts) to end.
#[derive(Debug)]
struct SessionRuntime(Option<Runtime>);

impl Drop for SessionRuntime {
    fn drop(&mut self) {
        if let Some(rt) = self.0.take() {
            rt.shutdown_timeout(STOP_WAIT);
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        for c in self.links.all() {
            c.disconnect();
        }
    }
}

/// The longest [`Session::close`] waits: for the polite close, then for
/// the thread to stop.
const CLOSE_WAIT: Duration = Duration::from_secs(2);
/// The longest a session's runtime is waited for once its connections
/// are closed (blocking tasks still running are left behind).
const STOP_WAIT: Duration = Duration::from_millis(250);
/// The longest the polite close waits.
const POLITE_WAIT: Duration = CLOSE_WAIT.saturating_sub(STOP_WAIT);

/// Runs `tasks` concurrently, abandoning those still running after `limit`.
async fn all_within<F>(limit: Duration, tasks: impl IntoIterator<Item = F>)
where
    F: Future<Output = ()> + Send + 'static,
{
    let mut set: JoinSet<()> = tasks.into_iter().collect();
    let _ = tokio::time::timeout(limit, async { while set.join_next().await.is_some() {} }).await;
}

fn runtime() -> Result<Runtime, SessionError> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("strata-client")
        .enable_all()
        .build()
        .map_err(SessionError::Runtime)
}

fn client_options(opts: SessionOptions) -> ClientOptions {
    ClientOptions {
        predict: opts.predict,
        structures: opts.structures,
        track_changes: true,
        capabilities: opts.capabilities,
        ..ClientOptions::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn closes_run_at_once_under_one_bound() {
        let rt = runtime().unwrap();
        let start = Instant::now();
        // Three closes of 1 s each: 1 s together, not 3 s.
        let closes = (0..3).map(|_| tokio::time::sleep(Duration::from_secs(1)));
        rt.block_on(all_within(POLITE_WAIT, closes));
        let together = start.elapsed();
        assert!(
            together >= Duration::from_secs(1) && together < POLITE_WAIT,
            "{together:?}"
        );
        // Closes that never end are abandoned at the bound.
        let start = Instant::now();
        let stuck = (0..3).map(|_| std::future::pending::<()>());
        rt.block_on(all_within(POLITE_WAIT, stuck));
        let bounded = start.elapsed();
        assert!(
            bounded >= POLITE_WAIT && bounded < POLITE_WAIT + Duration::from_millis(500),
            "{bounded:?}"
        );
    }

    #[test]
    fn a_blocking_task_does_not_hold_the_runtime_past_its_stop_wait() {
        let rt = runtime().unwrap();
        let (started, running) = std_mpsc::channel();
        // As a name lookup stuck in getaddrinfo: no timeout interrupts it.
        rt.spawn_blocking(move || {
            let _ = started.send(());
            std::thread::sleep(Duration::from_secs(10));
        });
        running.recv().unwrap();
        let start = Instant::now();
        drop(SessionRuntime(Some(rt)));
        let stopped = start.elapsed();
        assert!(
            stopped < STOP_WAIT + Duration::from_millis(500),
            "{stopped:?}"
        );
    }
}
