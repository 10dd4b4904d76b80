//! A headless Strata client over real QUIC: handshake, edits with their
//! verdicts, position datagrams, and a replica kept current in the
//! background.

use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::Bytes;
use strata_protocol::io::FramedReader;
use strata_protocol::limits::MAX_FORGET_CHUNKS;
use strata_protocol::{
    encode, encode_frame, ChunkVersion, ClientMessage, Direction, EditRequest, ErrorCode,
    FrameBuffer, Hello, PositionUpdate, Refusal, RejectReason, ServerMessage, Welcome, WorldUpdate,
    CAP_SNAPSHOTS, PROTOCOL_VERSION,
};
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Edit, FixedVec3, Voxel, VoxelPos};
use thiserror::Error;
use tokio::sync::{mpsc, oneshot, Notify};
use tokio::task::JoinHandle;
use tracing::debug;

use crate::bounds::{center_in_world, ChunkLimits, Violation, MAX_CENTER_CHUNK};
use crate::changes::ChangedChunks;
use crate::notice::{Notice, Notices};
use crate::pool::ChunkPool;
use crate::prediction::{Prediction, PredictionStats, Touched, MAX_PENDING_PREDICTIONS};
use crate::replica::{Replica, Request};
use crate::tls::{client_config_pinned, TlsError};

/// How long `connect` waits for the handshake and `Welcome`.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(10);
/// How long `edit` waits for its verdict.
pub const EDIT_TIMEOUT: Duration = Duration::from_secs(30);
/// Frames the client may queue on its control stream.
pub const CONTROL_QUEUE: usize = 256;
/// Longest a request (an edit, a subscription, a resync...) waits for room
/// in the control queue: a server that stops reading it (no stream credit)
/// fails the request with [`ClientError::Timeout`] instead of holding the
/// caller, and the request is not sent.
pub const SEND_TIMEOUT: Duration = Duration::from_secs(5);
/// Delta arrival records kept for latency reports, when recording
/// ([`ClientOptions::record_arrivals`]).
pub const MAX_ARRIVALS: usize = 1 << 20;
/// `RequestRefused` answers a client keeps.
pub const MAX_REFUSALS_KEPT: usize = 1024;

#[derive(Debug, Error)]
pub enum ClientError {
    #[error(transparent)]
    Tls(#[from] TlsError),
    #[error("cannot connect: {0}")]
    Connect(String),
    #[error("server refused: {code:?}: {message}")]
    Refused { code: ErrorCode, message: String },
    #[error("protocol violation: {0}")]
    Protocol(String),
    /// The server broke the protocol in its updates; the client ended the
    /// connection.
    #[error("protocol violation: {0}")]
    Violation(#[from] Violation),
    #[error("connection closed: {0}")]
    Closed(String),
    #[error("timed out waiting for {0}")]
    Timeout(&'static str),
    #[error("cannot forget {chunks} chunks at once; at most {max}")]
    TooManyChunks { chunks: usize, max: usize },
    #[error("cannot centre a view on chunk {center:?}: outside the world (within ±{max})")]
    OutsideWorld { center: ChunkPos, max: i32 },
}

/// The server's answer to an edit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    Accepted { seq: u64 },
    Rejected(RejectReason),
}

/// An accepted edit: its sequence number and the chunk versions it made
/// durable (empty for a rejected edit).
pub type Acked = (Verdict, Vec<ChunkVersion>);

/// How a client keeps its replica.
#[derive(Debug, Clone, Default)]
pub struct ClientOptions {
    /// Shared with other clients of this process.
    pub pool: Arc<ChunkPool>,
    /// Record every version (and hash) each chunk passes through from the
    /// first update on.
    pub record_history: bool,
    /// Apply our own edits to a predicted view at once and reconcile it
    /// with the server's verdicts and deltas (see [`crate::prediction`]).
    pub predict: bool,
    /// The server's structure templates, to predict `PlaceStructure` edits
    /// (empty: those are sent unpredicted).
    pub structures: Arc<StructureLibrary>,
    /// Queue every chunk whose visible copy (replica, or predicted view)
    /// changes, for [`Client::pop_changed`].
    pub track_changes: bool,
    /// `Hello::capabilities` (`strata_protocol::capabilities`):
    /// `CAP_SNAPSHOTS` makes a thin client (whole chunks, never
    /// regenerated), `CAP_OP_REPLAY` replays edits instead of taking deltas.
    pub capabilities: u32,
    /// Hold every datagram this client sends this long before it leaves
    /// (a simulated link delay: the RTT grows by it; zero: none). For load
    /// tests at a real network's RTT on loopback; see [`crate::link_delay`].
    pub link_delay: Duration,
    /// How fast a cluster client may reach out to nodes it is not
    /// connected to (see [`crate::cluster::JoinRate`]).
    pub join_rate: crate::cluster::JoinRate,
    /// Record when each delta (or op) arrives, for [`Client::take_arrivals`]
    /// (load tests' latency reports), from the first update on. Off, the
    /// first `take_arrivals` starts recording: nothing is kept for a
    /// caller that never takes them.
    pub record_arrivals: bool,
}

/// An edit on its way to the server, from [`Client::submit`].
#[derive(Debug)]
pub struct SentEdit {
    /// The `client_edit_id` it was sent with.
    pub id: u64,
    verdict: oneshot::Receiver<Acked>,
}

/// When a delta of edit `seq` reached this client.
#[derive(Debug, Clone, Copy)]
pub struct Arrival {
    pub seq: u64,
    pub pos: ChunkPos,
    pub at: Instant,
}

#[derive(Debug, Default)]
struct Shared {
    pending: Mutex<HashMap<u64, oneshot::Sender<Acked>>>,
    /// Set to stop reading the updates stream (a frozen client).
    stalled: AtomicBool,
    /// Set to hold received updates unapplied until resumed.
    paused: AtomicBool,
    resumed: Notify,
    /// The predicted view, when predicting (lock the replica first).
    prediction: Option<Mutex<Prediction>>,
    error: Mutex<Option<(ErrorCode, String)>>,
    /// How the server broke the protocol, when the client ended the
    /// connection for it.
    violation: Mutex<Option<Violation>>,
    /// Whether delta arrivals are recorded.
    recording_arrivals: AtomicBool,
    arrivals: Mutex<Vec<Arrival>>,
    bytes_in: AtomicU64,
    /// When the server was last heard from (ms since the Unix epoch).
    heard_ms: AtomicU64,
    /// `RequestRefused` answers received.
    refusals: Mutex<Vec<Refusal>>,
    /// Chunks changed since the game last asked, when tracking.
    changed: Option<Mutex<ChangedChunks>>,
    /// Refused positions and loaded views, for the game to take.
    notices: Mutex<Notices>,
    /// The last `InterestComplete`: (centre, radius).
    view_loaded: Mutex<Option<(ChunkPos, u8)>>,
    /// The last `RegionOwners` (cluster nodes only).
    owners: Mutex<Option<crate::cluster::RegionOwners>>,
    /// Where an accepted `Arrive` placed the player.
    arrived: Mutex<Option<FixedVec3>>,
}

impl Shared {
    fn heard(&self) {
        self.heard_ms.store(unix_ms(), Ordering::Relaxed);
    }

    /// Returns once updates are not paused.
    async fn unpaused(&self) {
        while self.paused.load(Ordering::SeqCst) {
            let resumed = self.resumed.notified();
            tokio::pin!(resumed);
            resumed.as_mut().enable();
            if !self.paused.load(Ordering::SeqCst) {
                break;
            }
            resumed.await;
        }
    }

    fn prediction(&self) -> Option<std::sync::MutexGuard<'_, Prediction>> {
        self.prediction
            .as_ref()
            .map(|p| p.lock().unwrap_or_else(std::sync::PoisonError::into_inner))
    }

    /// Runs `f` on the prediction and the replica, when predicting.
    fn with_prediction(&self, replica: &Mutex<Replica>, f: impl FnOnce(&mut Prediction, &Replica)) {
        if self.prediction.is_some() {
            let r = replica
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if let Some(mut p) = self.prediction() {
                self.reshape_prediction(&mut p, |p| f(p, &r));
            }
        }
    }

    /// Runs `f` on the prediction; when tracking changes, every chunk
    /// predicted before or after may look different now.
    fn reshape_prediction(&self, p: &mut Prediction, f: impl FnOnce(&mut Prediction)) {
        let Some(changed) = &self.changed else {
            return f(p);
        };
        let before: Vec<ChunkPos> = p.predicted_chunks().collect();
        f(p);
        let mut c = changed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        for pos in before.into_iter().chain(p.predicted_chunks()) {
            c.mark(pos);
        }
    }

    fn notice(&self, n: Notice) {
        if let Notice::ViewLoaded { center, radius } = n {
            *self
                .view_loaded
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner) = Some((center, radius));
        }
        self.notices
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .push(n);
    }

    fn mark_changed(&self, pos: ChunkPos) {
        if let Some(c) = &self.changed {
            c.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .mark(pos);
        }
    }

    /// Applies `update` to the replica and keeps the prediction and the
    /// change queue in step; returns what to ask the server for, or how the
    /// update broke the replica's limits (then nothing changed).
    fn apply(
        &self,
        replica: &Mutex<Replica>,
        update: WorldUpdate,
    ) -> Result<Option<Request>, Violation> {
        let tick_end = matches!(update, WorldUpdate::TickEnd { .. });
        let mut r = replica
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let request = self.apply_held(&mut r, update)?;
        if tick_end {
            // The tick's meshes are checked with the replica free: the
            // game reads and meshes chunks meanwhile.
            let mut checks = r.take_mesh_checks();
            drop(r);
            if !checks.is_empty() {
                checks.run();
                replica
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .finish_mesh_checks(checks);
            }
        }
        Ok(request)
    }

    /// [`Self::apply`] on the replica `r` its caller holds locked (no
    /// mesh checks run).
    fn apply_held(
        &self,
        r: &mut Replica,
        update: WorldUpdate,
    ) -> Result<Option<Request>, Violation> {
        let touched: Vec<Touched> = match &update {
            // Each chunk an op lists, as if its delta had come.
            WorldUpdate::Op(op) => op
                .chunks
                .iter()
                .map(|c| Touched::Delta {
                    pos: c.pos,
                    seq: op.seq,
                    to_version: c.version,
                })
                .collect(),
            u => Touched::of(u).into_iter().collect(),
        };
        // Only a chunk held before or after changed what the game sees:
        // deltas and withdrawals naming others (a gap, a chunk never sent)
        // queue no event, so the queue holds only chunks once held.
        let held_before: Vec<bool> = touched.iter().map(|t| r.get(t.pos()).is_some()).collect();
        let request = r.try_apply(update)?;
        for (t, before) in touched.into_iter().zip(held_before) {
            if before || r.get(t.pos()).is_some() {
                self.mark_changed(t.pos());
            }
            if let Some(mut p) = self.prediction() {
                self.reshape_prediction(&mut p, |p| p.after_update(t, r));
            }
        }
        Ok(request)
    }

    /// The game dropped `chunks` (`Forget`): each leaves the replica (and
    /// the prediction) as a withdrawal would, and one that was held is
    /// marked dropped, so its deltas and whole copies still on their way
    /// are ignored, not answered with a resync, until the server's
    /// withdrawal ([`Replica::drop_chunk`]). Under one lock: the server's
    /// own withdrawal, applied between, would be spent before the mark.
    fn forget_chunks(&self, replica: &Mutex<Replica>, chunks: &[ChunkPos]) {
        let mut r = replica
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        for &pos in chunks {
            let held = r.get(pos).is_some();
            // An unsubscribe is never past the limits.
            let _ = self.apply_held(&mut r, WorldUpdate::Unsubscribed { pos });
            if held {
                r.mark_dropped(pos);
            }
        }
    }

    fn violation(&self) -> Option<Violation> {
        self.violation
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Ends the connection for `v` (the first violation is kept).
    fn violated(&self, conn: &quinn::Connection, v: Violation) {
        debug!(violation = %v, "server broke the protocol");
        self.violation
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get_or_insert(v);
        conn.close(quinn::VarInt::from_u32(0), b"protocol violation");
    }
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// One connected session.
#[derive(Debug)]
pub struct Client {
    endpoint: quinn::Endpoint,
    conn: quinn::Connection,
    welcome: Welcome,
    control: mpsc::Sender<Bytes>,
    shared: Arc<Shared>,
    replica: Arc<Mutex<Replica>>,
    next_edit: AtomicU64,
    next_position: AtomicU32,
    /// The last position [`Self::send_position`] sent.
    last_position: Mutex<Option<FixedVec3>>,
    bytes_out: AtomicU64,
    tasks: Vec<JoinHandle<()>>,
}

fn closed_error(e: &quinn::ConnectionError) -> ClientError {
    if let quinn::ConnectionError::ApplicationClosed(a) = e {
        if let Some(code) = ErrorCode::from_close_code(a.error_code.into_inner()) {
            return ClientError::Refused {
                code,
                message: String::from_utf8_lossy(&a.reason).into_owned(),
            };
        }
    }
    ClientError::Closed(e.to_string())
}

/// Opens the control stream, sends `Hello` and waits for `Welcome`;
/// `closed` names a connection the server ended instead.
pub async fn say_hello(
    conn: &quinn::Connection,
    token: &str,
    protocol_version: u32,
    capabilities: u32,
    closed: impl Fn(quinn::ConnectionError) -> ClientError,
) -> Result<(quinn::SendStream, FramedReader<quinn::RecvStream>, Welcome), ClientError> {
    let (mut send, recv) = conn.open_bi().await.map_err(&closed)?;
    let hello = ClientMessage::Hello(Hello {
        protocol_version,
        token: token.to_string(),
        capabilities,
    });
    let frame = encode_frame(&hello, Direction::ClientToServer)
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
    send.write_all(&frame)
        .await
        .map_err(|e| ClientError::Closed(e.to_string()))?;
    let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient));
    match reader.next::<ServerMessage>().await {
        Ok(Some(ServerMessage::Welcome(w))) => Ok((send, reader, w)),
        Ok(Some(ServerMessage::Error { code, message })) => {
            Err(ClientError::Refused { code, message })
        }
        Ok(Some(other)) => Err(ClientError::Protocol(format!(
            "expected Welcome, got {other:?}"
        ))),
        Ok(None) | Err(_) => Err(closed(conn.closed().await)),
    }
}

impl Client {
    /// Connects to `addr`, trusting only `server_cert` (DER), and logs in.
    pub async fn connect(
        addr: SocketAddr,
        server_cert: &[u8],
        token: &str,
    ) -> Result<Client, ClientError> {
        Self::connect_with(
            addr,
            client_config_pinned(server_cert)?,
            token,
            PROTOCOL_VERSION,
        )
        .await
    }

    /// Like [`Self::connect`], with replica options.
    pub async fn connect_opts(
        addr: SocketAddr,
        server_cert: &[u8],
        token: &str,
        opts: ClientOptions,
    ) -> Result<Client, ClientError> {
        let config = client_config_pinned(server_cert)?;
        Self::open(addr, config, token, PROTOCOL_VERSION, opts).await
    }

    /// Connects with any client config and protocol version (for tests).
    pub async fn connect_with(
        addr: SocketAddr,
        config: quinn::ClientConfig,
        token: &str,
        protocol_version: u32,
    ) -> Result<Client, ClientError> {
        Self::open(
            addr,
            config,
            token,
            protocol_version,
            ClientOptions::default(),
        )
        .await
    }

    async fn open(
        addr: SocketAddr,
        config: quinn::ClientConfig,
        token: &str,
        protocol_version: u32,
        opts: ClientOptions,
    ) -> Result<Client, ClientError> {
        let endpoint = client_endpoint_delayed(addr, opts.link_delay)?;
        let handshake = async {
            let conn = endpoint
                .connect_with(config, addr, "localhost")
                .map_err(|e| ClientError::Connect(e.to_string()))?
                .await
                .map_err(|e| closed_error(&e))?;
            let (send, reader, w) =
                say_hello(&conn, token, protocol_version, opts.capabilities, |e| {
                    closed_error(&e)
                })
                .await?;
            Ok::<_, ClientError>((conn, send, reader, w))
        };
        let (conn, send, reader, welcome) = tokio::time::timeout(CONNECT_TIMEOUT, handshake)
            .await
            .map_err(|_| ClientError::Timeout("Welcome"))??;
        // A thin client never regenerates: it takes whole chunks only.
        let thin = strata_protocol::capabilities::has(opts.capabilities, CAP_SNAPSHOTS);
        let generator = if thin { None } else { generator_from(&welcome) };
        let mut replica = Replica::with_pool(generator, opts.pool);
        replica.limit(ChunkLimits::from_welcome(&welcome));
        // Checked by the updates reader outside the replica's lock
        // (`Shared::apply`): readers of the replica never wait for them.
        replica.defer_mesh_checks();
        if opts.record_history {
            replica.record_history();
        }
        let replica = Arc::new(Mutex::new(replica));
        let prediction = opts.predict.then(|| {
            Mutex::new(Prediction::new(
                opts.structures.clone(),
                MAX_PENDING_PREDICTIONS,
            ))
        });
        let shared = Arc::new(Shared {
            prediction,
            changed: opts.track_changes.then(Mutex::default),
            recording_arrivals: AtomicBool::new(opts.record_arrivals),
            ..Shared::default()
        });
        shared.heard();
        let (control, control_rx) = mpsc::channel(CONTROL_QUEUE);
        let tasks = vec![
            tokio::spawn(write_control(send, control_rx)),
            tokio::spawn(read_control(
                reader,
                (conn.clone(), shared.clone()),
                replica.clone(),
            )),
            tokio::spawn(read_updates(
                conn.clone(),
                (replica.clone(), shared.clone()),
                control.clone(),
                strata_protocol::capabilities::has(
                    opts.capabilities,
                    strata_protocol::capabilities::CAP_OP_REPLAY,
                ),
            )),
        ];
        Ok(Client {
            endpoint,
            conn,
            welcome,
            control,
            shared,
            replica,
            next_edit: AtomicU64::new(1),
            next_position: AtomicU32::new(1),
            last_position: Mutex::new(None),
            bytes_out: AtomicU64::new(0),
            tasks,
        })
    }

    pub fn welcome(&self) -> &Welcome {
        &self.welcome
    }

    async fn send(&self, msg: &ClientMessage) -> Result<(), ClientError> {
        let frame = encode_frame(msg, Direction::ClientToServer)
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        let len = frame.len() as u64;
        // A send cut short by the deadline queues nothing.
        match tokio::time::timeout(SEND_TIMEOUT, self.control.send(Bytes::from(frame))).await {
            Ok(Ok(())) => {
                self.bytes_out.fetch_add(len, Ordering::Relaxed);
                Ok(())
            }
            Ok(Err(_)) => Err(self.gone()),
            Err(_) => Err(ClientError::Timeout("room on the control stream")),
        }
    }

    fn gone(&self) -> ClientError {
        if let Some(v) = self.shared.violation() {
            return ClientError::Violation(v);
        }
        match self
            .shared
            .error
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
        {
            Some((code, message)) => ClientError::Refused { code, message },
            None => self
                .conn
                .close_reason()
                .map_or(ClientError::Closed("control stream ended".into()), |e| {
                    closed_error(&e)
                }),
        }
    }

    /// Sends an edit and waits for the server's verdict.
    pub async fn edit(&self, edit: Edit) -> Result<Verdict, ClientError> {
        Ok(self.edit_acked(edit).await?.0)
    }

    /// Sends an edit and waits for the verdict and, if accepted, the chunk
    /// versions it made durable.
    pub async fn edit_acked(&self, edit: Edit) -> Result<Acked, ClientError> {
        let sent = self.submit(edit).await?;
        self.verdict(sent).await
    }

    /// Sends an edit (predicting it, when predicting) without waiting for
    /// its verdict: edits submitted one after another reach the server in
    /// that order. Pass the result to [`Self::verdict`].
    pub async fn submit(&self, edit: Edit) -> Result<SentEdit, ClientError> {
        let id = self.next_edit.fetch_add(1, Ordering::Relaxed);
        self.shared.with_prediction(&self.replica, |p, r| {
            p.predict(id, edit.clone(), r);
        });
        let (tx, rx) = oneshot::channel();
        self.shared
            .pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .insert(id, tx);
        let sent = self
            .send(&ClientMessage::Edit(EditRequest {
                client_edit_id: id,
                edit,
            }))
            .await;
        match sent {
            Ok(()) => Ok(SentEdit { id, verdict: rx }),
            Err(e) => {
                self.shared
                    .pending
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner)
                    .remove(&id);
                self.abandon_prediction(id);
                Err(e)
            }
        }
    }

    /// Waits for the verdict of a submitted edit and, if accepted, the
    /// chunk versions it made durable.
    pub async fn verdict(&self, sent: SentEdit) -> Result<Acked, ClientError> {
        // A verdict, or the connection's end: an edit sent as the server
        // closes may register after the reader has given up on its waiters.
        let verdict = async {
            tokio::select! {
                v = sent.verdict => v.map_err(|_| self.gone()),
                e = self.conn.closed() => Err(closed_error(&e)),
            }
        };
        let result = match tokio::time::timeout(EDIT_TIMEOUT, verdict).await {
            Ok(v) => v,
            Err(_) => Err(ClientError::Timeout("edit verdict")),
        };
        if result.is_err() {
            self.abandon_prediction(sent.id);
        }
        result
    }

    /// No verdict will come for edit `id`: drop its prediction.
    fn abandon_prediction(&self, id: u64) {
        self.shared
            .with_prediction(&self.replica, |p, r| p.abandon(id, r));
    }

    /// Reports the player's feet position (unreliable datagram).
    pub fn send_position(&self, pos: FixedVec3) -> Result<(), ClientError> {
        let seq = self.next_position.fetch_add(1, Ordering::Relaxed);
        let bytes = encode(&PositionUpdate { seq, pos }, Direction::ClientToServer)
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        *self
            .last_position
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(pos);
        self.bytes_out
            .fetch_add(bytes.len() as u64, Ordering::Relaxed);
        self.conn
            .send_datagram(Bytes::from(bytes))
            .map_err(|e| ClientError::Closed(e.to_string()))
    }

    /// The last position [`Self::send_position`] sent (accepted or not).
    pub fn last_position(&self) -> Option<FixedVec3> {
        *self
            .last_position
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Asks for the chunks within `radius` of `center`. A centre outside
    /// the world ([`crate::bounds::center_in_world`]) is refused here: no
    /// position can bring a view there, and its chunks would be a
    /// protocol violation.
    pub async fn subscribe(&self, center: ChunkPos, radius: u8) -> Result<(), ClientError> {
        check_center(center)?;
        self.send(&ClientMessage::Subscribe { center, radius })
            .await
    }

    /// Asks for a fresh snapshot of one chunk (taken in even if the chunk
    /// was forgotten).
    pub async fn resync(&self, pos: ChunkPos) -> Result<(), ClientError> {
        {
            let mut r = self.replica();
            r.undrop(pos);
            r.expect_resync(pos);
        }
        self.send(&ClientMessage::ResyncRequest { pos }).await
    }

    /// Drops chunks the client no longer wants: they leave the replica at
    /// once, and the server stops sending their updates (chunks outside
    /// the view are ignored there). A [`Self::resync`], or the chunk
    /// leaving the view and coming back, brings one back. At most
    /// [`MAX_FORGET_CHUNKS`] at once.
    pub async fn forget(&self, chunks: &[ChunkPos]) -> Result<(), ClientError> {
        if chunks.len() > MAX_FORGET_CHUNKS {
            return Err(ClientError::TooManyChunks {
                chunks: chunks.len(),
                max: MAX_FORGET_CHUNKS,
            });
        }
        // Dropped first: deltas arriving meanwhile are ignored, not resynced.
        self.shared.forget_chunks(&self.replica, chunks);
        self.send(&ClientMessage::Forget {
            chunks: chunks.to_vec(),
        })
        .await
    }

    /// Asks for a chunk's full data, even at version 0 (taken in even if
    /// the chunk was forgotten).
    pub async fn full_snapshot(&self, pos: ChunkPos) -> Result<(), ClientError> {
        self.replica().undrop(pos);
        self.send(&ClientMessage::FullSnapshotRequest { pos }).await
    }

    pub async fn ping(&self, nonce: u64) -> Result<(), ClientError> {
        self.send(&ClientMessage::Ping { nonce }).await
    }

    /// Sends raw bytes on the control stream (malformed-input tests).
    pub async fn send_raw(&self, bytes: Vec<u8>) -> Result<(), ClientError> {
        self.control
            .send(Bytes::from(bytes))
            .await
            .map_err(|_| self.gone())
    }

    /// The replica, locked. Keep the guard short: updates wait on it.
    pub fn replica(&self) -> std::sync::MutexGuard<'_, Replica> {
        self.replica
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Stops reading the updates stream for good, as a frozen client
    /// would; the control stream (verdicts) keeps working.
    pub fn stop_reading_updates(&self) {
        self.shared.stalled.store(true, Ordering::Relaxed);
    }

    /// Holds updates unapplied (a lagging client) until
    /// [`Self::resume_updates`]; verdicts keep arriving.
    pub fn pause_updates(&self) {
        self.shared.paused.store(true, Ordering::SeqCst);
    }

    pub fn resume_updates(&self) {
        self.shared.paused.store(false, Ordering::SeqCst);
        self.shared.resumed.notify_waiters();
    }

    /// A chunk as the player should see it: with this client's pending
    /// predicted edits when predicting, else the replica's.
    pub fn predicted_chunk(&self, pos: ChunkPos) -> Option<Arc<Chunk>> {
        let r = self.replica();
        match self.shared.prediction() {
            Some(p) => p.chunk(pos, &r),
            None => r.get(pos).map(|h| h.chunk.clone()),
        }
    }

    /// [`Self::predicted_chunk`] with the replica's version of it and
    /// whether pending predicted edits changed it, read at one instant.
    pub fn visible_chunk(&self, pos: ChunkPos) -> Option<(Arc<Chunk>, u64, bool)> {
        let r = self.replica();
        let version = r.get(pos)?.version;
        let predicted = self.shared.prediction().and_then(|p| {
            let chunk = p.chunk(pos, &r)?;
            p.predicted_chunks().any(|c| c == pos).then_some(chunk)
        });
        match predicted {
            Some(chunk) => Some((chunk, version, true)),
            None => Some((r.get(pos)?.chunk.clone(), version, false)),
        }
    }

    /// One voxel of [`Self::predicted_chunk`].
    pub fn predicted_voxel(&self, p: VoxelPos) -> Option<Voxel> {
        let (x, y, z) = p.local();
        self.predicted_chunk(p.chunk()).map(|c| c.get(x, y, z))
    }

    /// The chunk whose visible copy changed first since the last call,
    /// when tracking changes ([`ClientOptions::track_changes`]).
    pub fn pop_changed(&self) -> Option<ChunkPos> {
        let changed = self.shared.changed.as_ref()?;
        changed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop()
    }

    /// Chunks whose predicted copy differs from the replica's.
    pub fn predicted_chunks(&self) -> Vec<ChunkPos> {
        self.shared
            .prediction()
            .map_or(Vec::new(), |p| p.predicted_chunks().collect())
    }

    /// How the predictions fared; `None` when not predicting.
    pub fn prediction_stats(&self) -> Option<PredictionStats> {
        self.shared.prediction().map(|p| p.stats())
    }

    /// The error the server sent before closing, if any.
    pub fn server_error(&self) -> Option<(ErrorCode, String)> {
        self.shared
            .error
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Takes the recorded delta arrivals (at most [`MAX_ARRIVALS`] between
    /// calls). Unless [`ClientOptions::record_arrivals`] started recording
    /// at connect, the first call starts it (and returns nothing).
    pub fn take_arrivals(&self) -> Vec<Arrival> {
        self.shared
            .recording_arrivals
            .store(true, Ordering::Relaxed);
        std::mem::take(
            &mut *self
                .shared
                .arrivals
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        )
    }

    pub fn bytes_in(&self) -> u64 {
        self.shared.bytes_in.load(Ordering::Relaxed)
    }

    pub fn bytes_out(&self) -> u64 {
        self.bytes_out.load(Ordering::Relaxed)
    }

    /// How long since the server last sent anything (any control message
    /// or update). With regular pings, a long silence means a dead server
    /// whose connection QUIC has not timed out yet.
    pub fn silent_for(&self) -> Duration {
        let heard = self.shared.heard_ms.load(Ordering::Relaxed);
        Duration::from_millis(unix_ms().saturating_sub(heard))
    }

    /// Closes the connection at once, without waiting for the peer.
    pub fn disconnect(&self) {
        self.conn.close(quinn::VarInt::from_u32(0), b"bye");
    }

    /// Closes the connection at once, without waiting for the peer.
    pub fn abandon(self) {
        self.conn.close(quinn::VarInt::from_u32(0), b"abandoned");
        for t in self.tasks {
            t.abort();
        }
    }

    /// The server's `RequestRefused` answers so far (the first
    /// [`MAX_REFUSALS_KEPT`]).
    pub fn refusals(&self) -> Vec<Refusal> {
        self.shared
            .refusals
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// The oldest notice not taken yet (refused positions, loaded views).
    pub fn pop_notice(&self) -> Option<Notice> {
        self.shared
            .notices
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop()
    }

    /// The last view the server said was wholly sent: (centre, radius).
    pub fn view_loaded(&self) -> Option<(ChunkPos, u8)> {
        *self
            .shared
            .view_loaded
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The last `RegionOwners` this node sent (cluster nodes only).
    pub fn region_owners(&self) -> Option<crate::cluster::RegionOwners> {
        self.shared
            .owners
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    /// Where an accepted [`Self::arrive`] placed the player.
    pub fn arrived(&self) -> Option<FixedVec3> {
        *self
            .shared
            .arrived
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Continues the player from another node's ticket
    /// (`ClientMessage::Arrive`); see [`Self::arrived`] and
    /// [`Self::refusals`] for the answer.
    pub async fn arrive(&self, ticket: strata_protocol::Ticket) -> Result<(), ClientError> {
        self.send(&ClientMessage::Arrive(ticket)).await
    }

    /// [`Self::arrive`], then waits up to `limit` for the answer: the
    /// position arrived at, or `None` when refused, closed or too slow.
    pub async fn arrive_within(
        &self,
        ticket: strata_protocol::Ticket,
        limit: Duration,
    ) -> Result<Option<FixedVec3>, ClientError> {
        self.arrive(ticket).await?;
        let deadline = Instant::now() + limit;
        loop {
            if let Some(feet) = self.arrived() {
                return Ok(Some(feet));
            }
            if Instant::now() > deadline || !self.refusals().is_empty() || self.is_closed() {
                return Ok(None);
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }

    /// True once the connection has ended.
    pub fn is_closed(&self) -> bool {
        self.conn.close_reason().is_some()
    }

    /// Waits for the connection to end and returns why.
    /// A close whose frame was lost (a stateless reset, a timeout) still
    /// reports the Error the server sent first on the control stream.
    /// A connection the client ended because the server broke the
    /// protocol reports [`ClientError::Violation`].
    pub async fn closed(&self) -> ClientError {
        let closed = self.conn.closed().await;
        if let Some(v) = self.shared.violation() {
            return ClientError::Violation(v);
        }
        match closed_error(&closed) {
            ClientError::Closed(why) => match self.server_error() {
                Some((code, message)) => ClientError::Refused { code, message },
                None => ClientError::Closed(why),
            },
            refused => refused,
        }
    }

    /// Closes the connection politely and waits briefly for it to finish.
    pub async fn close(self) {
        self.shutdown().await;
        for t in self.tasks {
            t.abort();
        }
    }

    /// Like [`Self::close`] for a shared client; its tasks end with the
    /// connection.
    pub async fn shutdown(&self) {
        self.conn.close(quinn::VarInt::from_u32(0), b"bye");
        let _ = tokio::time::timeout(Duration::from_secs(2), self.endpoint.wait_idle()).await;
    }
}

/// A client endpoint (one UDP socket, on loopback for a loopback server)
/// for reaching `server`.
pub fn client_endpoint(server: SocketAddr) -> Result<quinn::Endpoint, ClientError> {
    client_endpoint_delayed(server, Duration::ZERO)
}

/// Like [`client_endpoint`], with every send held `link_delay` first
/// (zero: a plain socket).
pub fn client_endpoint_delayed(
    server: SocketAddr,
    link_delay: Duration,
) -> Result<quinn::Endpoint, ClientError> {
    let ip: IpAddr = match (server.is_ipv6(), server.ip().is_loopback()) {
        (false, true) => Ipv4Addr::LOCALHOST.into(),
        (false, false) => Ipv4Addr::UNSPECIFIED.into(),
        (true, true) => Ipv6Addr::LOCALHOST.into(),
        (true, false) => Ipv6Addr::UNSPECIFIED.into(),
    };
    let bind = SocketAddr::new(ip, 0);
    let failed = |e: std::io::Error| ClientError::Connect(e.to_string());
    if link_delay.is_zero() {
        return quinn::Endpoint::client(bind).map_err(failed);
    }
    let runtime: Arc<dyn quinn::Runtime> = Arc::new(quinn::TokioRuntime);
    let socket = runtime.wrap_udp_socket(std::net::UdpSocket::bind(bind).map_err(failed)?);
    let socket = crate::link_delay::delayed(socket.map_err(failed)?, link_delay);
    quinn::Endpoint::new_with_abstract_socket(
        quinn::EndpointConfig::default(),
        None,
        socket,
        runtime,
    )
    .map_err(failed)
}

/// Refuses a view centre outside the world.
pub(crate) fn check_center(center: ChunkPos) -> Result<(), ClientError> {
    if center_in_world(center) {
        return Ok(());
    }
    Err(ClientError::OutsideWorld {
        center,
        max: MAX_CENTER_CHUNK,
    })
}

/// A generator from the Welcome's parameters, if the client can run it.
fn generator_from(w: &Welcome) -> Option<Arc<dyn ChunkGenerator>> {
    let params: GenParams = toml::from_str(&w.generator_params).ok()?;
    if params.seed != w.world_seed || w.generator_version != strata_terrain::gen::GENERATOR_VERSION
    {
        return None;
    }
    let g = Generator::fractal(params).ok()?;
    Some(Arc::new(g))
}

async fn write_control(mut send: quinn::SendStream, mut rx: mpsc::Receiver<Bytes>) {
    while let Some(frame) = rx.recv().await {
        if send.write_all(&frame).await.is_err() {
            return;
        }
    }
    let _ = send.finish();
}

async fn read_control(
    mut reader: FramedReader<quinn::RecvStream>,
    (conn, shared): (quinn::Connection, Arc<Shared>),
    replica: Arc<Mutex<Replica>>,
) {
    loop {
        let msg = reader.next::<ServerMessage>().await;
        if let Ok(Some(_)) = &msg {
            shared.heard();
        }
        match msg {
            // More than any edit writes: the connection ends rather than
            // the game being handed the list.
            Ok(Some(ServerMessage::EditAccepted { changes, .. }))
                if changes.len() > strata_protocol::limits::MAX_EDIT_CHANGES =>
            {
                let (chunks, max) = (changes.len(), strata_protocol::limits::MAX_EDIT_CHANGES);
                shared.violated(&conn, Violation::EditChangesTooMany { chunks, max });
                break;
            }
            Ok(Some(ServerMessage::EditAccepted {
                client_edit_id,
                seq,
                changes,
            })) => resolve(
                &shared,
                &replica,
                client_edit_id,
                (Verdict::Accepted { seq }, changes),
            ),
            Ok(Some(ServerMessage::EditRejected {
                client_edit_id,
                reason,
            })) => resolve(
                &shared,
                &replica,
                client_edit_id,
                (Verdict::Rejected(reason), Vec::new()),
            ),
            Ok(Some(ServerMessage::Error { code, message })) => {
                *shared
                    .error
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner) = Some((code, message));
            }
            Ok(Some(ServerMessage::RequestRefused(r))) => {
                let mut all = shared
                    .refusals
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                if all.len() < MAX_REFUSALS_KEPT {
                    all.push(r);
                }
            }
            Ok(Some(ServerMessage::PositionRefused { seq, reason, at })) => {
                shared.notice(Notice::PositionRefused { seq, reason, at });
            }
            Ok(Some(ServerMessage::RegionOwners {
                region_chunks,
                regions,
                ticket,
                node,
            })) if regions.len() <= strata_protocol::limits::MAX_REGION_OWNERS
                && node.len() <= strata_protocol::limits::MAX_NODE_ID_BYTES =>
            {
                let mut o = shared
                    .owners
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
                let serial = o.as_ref().map_or(1, |o| o.serial + 1);
                *o = Some(crate::cluster::RegionOwners {
                    serial,
                    region_chunks,
                    regions,
                    ticket,
                    node,
                });
            }
            Ok(Some(ServerMessage::RegionOwners { regions, .. })) => {
                // Past the protocol's cap: not kept (nor cloned per follow).
                debug!(regions = regions.len(), "server broke the RegionOwners cap");
            }
            Ok(Some(ServerMessage::Arrived { feet })) => {
                *shared
                    .arrived
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(feet);
            }
            Ok(Some(ServerMessage::Pong { .. } | ServerMessage::Welcome(_))) => {}
            Ok(None) | Err(_) => break,
        }
    }
    // Anyone still waiting learns the connection is gone.
    shared
        .pending
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .clear();
}

/// Reconciles the prediction (before the caller sees the verdict) and
/// hands the verdict to the waiting `edit`.
fn resolve(shared: &Shared, replica: &Mutex<Replica>, id: u64, v: Acked) {
    shared.with_prediction(replica, |p, r| p.verdict(id, &v.0, &v.1, r));
    if let Some(tx) = shared
        .pending
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .remove(&id)
    {
        let _ = tx.send(v);
    }
}

/// Accepts the server's updates stream (QUIC opens it with its first
/// frame) and applies every update to the replica.
async fn read_updates(
    conn: quinn::Connection,
    (replica, shared): (Arc<Mutex<Replica>>, Arc<Shared>),
    control: mpsc::Sender<Bytes>,
    replay_ops: bool,
) {
    let Ok(recv) = conn.accept_uni().await else {
        return;
    };
    let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient));
    loop {
        if shared.stalled.load(Ordering::Relaxed) {
            // Hold the stream unread until the connection is dropped.
            std::future::pending::<()>().await;
        }
        let update = match reader.next::<WorldUpdate>().await {
            Ok(Some(u)) => u,
            Ok(None) => break,
            Err(e) => {
                debug!(error = %e, "updates stream failed");
                break;
            }
        };
        // Ops only for a client that asked for them (`CAP_OP_REPLAY`):
        // each costs a replay of the edit, which no server may impose.
        if matches!(update, WorldUpdate::Op(_)) && !replay_ops {
            shared.violated(&conn, Violation::UnaskedOp);
            break;
        }
        shared.heard();
        shared.unpaused().await;
        let arrived: Vec<(u64, ChunkPos)> = match &update {
            WorldUpdate::Delta(d) => vec![(d.seq, d.delta.pos)],
            WorldUpdate::Op(op) => op.chunks.iter().map(|c| (op.seq, c.pos)).collect(),
            _ => Vec::new(),
        };
        if !arrived.is_empty() && shared.recording_arrivals.load(Ordering::Relaxed) {
            let mut a = shared
                .arrivals
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            for (seq, pos) in arrived {
                if a.len() < MAX_ARRIVALS {
                    a.push(Arrival {
                        seq,
                        pos,
                        at: Instant::now(),
                    });
                }
            }
        }
        shared
            .bytes_in
            .store(reader.bytes_read(), Ordering::Relaxed);
        if let WorldUpdate::UnsubscribedMany { chunks } = update {
            // Past the protocol's cap the server is broken or hostile: the
            // connection ends rather than the client doing its bidding.
            let max = strata_protocol::limits::MAX_UNSUBSCRIBED_PER_UPDATE;
            if chunks.len() > max {
                let chunks = chunks.len();
                shared.violated(&conn, Violation::UnsubscribeTooLarge { chunks, max });
                break;
            }
            for pos in chunks {
                // An unsubscribe is never past the limits.
                let _ = shared.apply(&replica, WorldUpdate::Unsubscribed { pos });
            }
            continue;
        }
        if let WorldUpdate::InterestComplete { center, radius } = update {
            shared.notice(Notice::ViewLoaded { center, radius });
            continue;
        }
        // A chunk outside the world, or past what any view covers: the
        // server would have the client generate and hold chunks without
        // end. The connection ends instead.
        let request = match shared.apply(&replica, update) {
            Ok(r) => r,
            Err(v) => {
                shared.violated(&conn, v);
                break;
            }
        };
        let msgs = match request {
            Some(Request::Resync(pos)) => vec![ClientMessage::ResyncRequest { pos }],
            Some(Request::FullSnapshot(pos)) => vec![ClientMessage::FullSnapshotRequest { pos }],
            Some(Request::ResyncMany(chunks)) => chunks
                .into_iter()
                .map(|pos| ClientMessage::ResyncRequest { pos })
                .collect(),
            None => continue,
        };
        for msg in msgs {
            if let Ok(frame) = encode_frame(&msg, Direction::ClientToServer) {
                if control.send(Bytes::from(frame)).await.is_err() {
                    return;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_protocol::DeltaUpdate;
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::material::ids;
    use strata_terrain::world::FlatGenerator;
    use strata_terrain::{Chunk, Voxel};

    /// Only chunks held before or after an update are reported changed:
    /// a delta for a chunk never sent (a gap) and withdrawals of chunks
    /// never held queue nothing.
    #[test]
    fn only_chunks_held_are_reported_changed() {
        let shared = Shared {
            changed: Some(Mutex::default()),
            ..Shared::default()
        };
        let flat = Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        });
        let replica = Mutex::new(Replica::new(Some(flat)));
        let changed = || {
            let mut q = shared.changed.as_ref().unwrap().lock().unwrap();
            std::iter::from_fn(|| q.pop()).collect::<Vec<_>>()
        };
        let (held, never) = (ChunkPos::new(0, 0, 0), ChunkPos::new(5, 0, 0));
        let air = Chunk::uniform(Voxel::AIR);
        let delta =
            ChunkDelta::encode(never, 0, 1, &air, &Chunk::uniform(Voxel::solid(1))).unwrap();
        let gap = WorldUpdate::Delta(DeltaUpdate {
            delta,
            mesh_hash: 0,
            seq: 1,
        });
        assert_eq!(
            shared.apply(&replica, gap),
            Ok(Some(Request::Resync(never)))
        );
        // (The updates reader splits an `UnsubscribedMany` into these.)
        let gone = WorldUpdate::Unsubscribed { pos: never };
        assert_eq!(shared.apply(&replica, gone), Ok(None));
        assert_eq!(changed(), vec![]);
        let sent = WorldUpdate::Generated { pos: held };
        assert_eq!(shared.apply(&replica, sent), Ok(None));
        assert_eq!(changed(), vec![held]);
        let withdrawn = WorldUpdate::Unsubscribed { pos: held };
        assert_eq!(shared.apply(&replica, withdrawn), Ok(None));
        assert_eq!(changed(), vec![held]);
    }

    /// A chunk the game forgets while its deltas are on their way: they
    /// are ignored, not answered with a resync (which would bring it
    /// back), until the server's withdrawal.
    #[test]
    fn a_forgotten_chunks_late_delta_asks_for_nothing() {
        let shared = Shared::default();
        let flat = Arc::new(FlatGenerator {
            ground: Voxel::solid(ids::STONE),
        });
        let replica = Mutex::new(Replica::new(Some(flat.clone())));
        let pos = ChunkPos::new(2, 5, 0);
        assert_eq!(
            shared.apply(&replica, WorldUpdate::Generated { pos }),
            Ok(None)
        );
        shared.forget_chunks(&replica, &[pos]);
        assert!(replica.lock().unwrap().get(pos).is_none());
        let air = Chunk::uniform(Voxel::AIR);
        let delta = ChunkDelta::encode(pos, 0, 1, &air, &Chunk::uniform(Voxel::solid(1))).unwrap();
        let late = WorldUpdate::Delta(DeltaUpdate {
            delta,
            mesh_hash: 0,
            seq: 1,
        });
        assert_eq!(shared.apply(&replica, late), Ok(None));
        assert_eq!(replica.lock().unwrap().stats.gaps, 0);
        // The withdrawal ends it: sent again, it is taken in.
        let gone = WorldUpdate::Unsubscribed { pos };
        assert_eq!(shared.apply(&replica, gone), Ok(None));
        assert_eq!(
            shared.apply(&replica, WorldUpdate::Generated { pos }),
            Ok(None)
        );
        assert!(replica.lock().unwrap().get(pos).is_some());
    }

    #[tokio::test]
    async fn endpoints_bind_loopback_only_for_a_loopback_server() {
        let local = |server: &str| {
            let e = client_endpoint(server.parse().unwrap()).unwrap();
            e.local_addr().unwrap().ip()
        };
        assert!(local("127.0.0.1:4433").is_loopback());
        assert!(local("[::1]:4433").is_loopback());
        // Nothing is sent: binding is enough to see the socket's address.
        assert!(local("192.0.2.7:4433").is_unspecified());
    }
}
