//! Hostile players (`--hostile N --attack KIND`): cheats and floods sent
//! through the real protocol beside the honest bots, one function per
//! attack. They start with the edit phase, stop at its end, connect only
//! to the run's server, and count what the server let through, so a test
//! can assert that no cheat succeeded. Honest bots' statistics never see
//! them: hostiles keep their own counters ([`HostileSummary`]).
//!
//! Each hostile player has its own token (`hostile-<i>`, minted like the
//! bots'), its own home beside the bots' area and, for every attack, its
//! connections come from [`HostileConfig::bind`] (so a per-address limit
//! on the server meets the hostiles, not the honest bots).

use std::collections::BTreeMap;
use std::fmt;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use strata_protocol::reject_label;
use strata_protocol::{ErrorCode, RejectReason, ServerMessage, Welcome, WorldUpdate};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkPos, Edit, Fixed, FixedVec3, VoxelPos, CHUNK_SIZE};
use tokio::sync::{mpsc, Semaphore};
use tokio::task::{JoinHandle, JoinSet};
use tokio::time::{sleep, sleep_until, timeout, timeout_at};

use super::profile::BUILD_MATERIALS;
use super::raw_session::{close_name, OnControl, OnUpdate, RawSession};
use super::rng::Rng;
use super::summary::HostileSummary;
use super::{BotsConfig, BotsError, Tokens, CELL};
use crate::client::{ClientError, Verdict};
use crate::tls::client_config_pinned;

/// Default position datagrams per second per position-flood player.
pub const DEFAULT_DATAGRAM_RATE: u32 = 50_000;
/// Default edits per second per rejected-edits player.
pub const DEFAULT_EDIT_RATE: u32 = 1_000;
/// Largest `--hostile-rate`.
pub const MAX_RATE: u32 = 1_000_000;
/// Default sessions a token-share player opens with its one token.
pub const DEFAULT_SESSIONS: usize = 100;
/// Default connections a handshake-flood player holds at once.
pub const DEFAULT_CONNECTIONS: usize = 300;
/// Largest `--hostile-sessions` and `--hostile-connections`.
pub const MAX_CONNECTIONS: usize = 10_000;
/// Largest `--hostile`.
pub const MAX_PLAYERS: usize = 256;
/// The reach teleport measures against by default (the server's default
/// `[validation] reach`, voxels from the eye).
pub const DEFAULT_REACH: f64 = 10.0;
/// Added to the reach before an accepted edit counts as beyond it.
pub const REACH_SLACK: f64 = 2.0;
/// The server's default interest hysteresis, in chunks (not in `Welcome`).
pub const HYSTERESIS: i32 = 2;
/// How long a handshake-flood connection is held without a Hello.
pub const HOLD: Duration = Duration::from_secs(5);
/// QUIC handshakes in flight at once per handshake-flood or token-share player.
pub const HANDSHAKES_IN_FLIGHT: usize = 32;
/// How far teleport and token-share jump, in voxels.
pub const FAR_JUMP: i32 = 4096;
/// How far (in chunks) far-subscribe's first centre is from home.
pub const FAR_CHUNKS: i32 = 150;
/// Pause between far-subscribe's requests, and between reconnects.
pub const PAUSE: Duration = Duration::from_millis(250);
/// Full-chunk requests far-subscribe sends per pause.
pub const SNAPSHOTS_PER_PAUSE: i32 = 4;
/// Voxels between the bots' area and the first hostile home.
pub const HOSTILE_GAP: i32 = 256;
/// Voxels between two hostile players' homes.
pub const HOSTILE_SPACING: i32 = 64;
/// token-share counts sessions welcomed at least this long ago...
pub const SETTLE: Duration = Duration::from_millis(500);
/// ...sampled this often.
pub const SAMPLE_EVERY: Duration = Duration::from_millis(100);
/// How long the run waits for hostiles to stop after the deadline.
pub const FINISH_GRACE: Duration = Duration::from_secs(5);
/// How long an edit waits for its verdict.
pub const VERDICT_TIMEOUT: Duration = Duration::from_secs(5);
/// Tries per placed edit (a position not yet validated, a busy server).
pub const PLACE_TRIES: u32 = 10;

/// The `--attack` choices. Every attack also counts `reconnects` (or its
/// own opens) and fills [`HostileSummary`]'s `rejected` and
/// `closed_by_server` maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Attack {
    /// Position datagrams at up to `rate` per second, each up to a million
    /// voxels from home. `datagrams_queued` (accepted by quinn, which drops
    /// the oldest unsent ones when its buffer is full), `datagrams_sent`
    /// (datagram frames on the wire), `datagrams_failed`.
    PositionFlood,
    /// Position datagrams at up to `rate` per second, its feet flipping a
    /// quarter voxel either side of a chunk border (each move legal for
    /// speed, and no `Subscribe`, so positions move its view): every
    /// crossing a server handles may re-centre its view. The same counters
    /// as `PositionFlood`.
    BorderFlip,
    /// Explosions of radius 64 far away, at up to `rate` per second, as fast
    /// as the control stream takes them; a kicked player reconnects.
    /// `edits_sent`, `edits_rejected`, `edits_accepted` (a cheat),
    /// `kicks` (closed with `Kicked`), `first_kick_ms` (from the attack's
    /// start), `rejected_before_first_kick`.
    RejectedEdits,
    /// A map hack: stands at home, subscribes 150+ chunks away and asks for
    /// far chunks in full. `subscribes_sent`, `snapshot_requests_sent`,
    /// `chunk_records` (Generated, Snapshot, Patched and Delta records),
    /// `chunks_outside_interest` (records of chunks more than the Welcome's
    /// view radius + [`HYSTERESIS`] + 1 from the reported position: a
    /// cheat), `refusals` (`Error` and `RequestRefused` answers).
    FarSubscribe,
    /// Edit at home, reconnect [`FAR_JUMP`] voxels away, edit there, and
    /// back. `jumps`, `edits_sent`, `edits_accepted`,
    /// `edits_accepted_beyond_reach` (farther than `reach` +
    /// [`REACH_SLACK`] from the eye the server last validated: a cheat).
    Teleport,
    /// `connections` QUIC connections at once that finish TLS and never say
    /// Hello, each held [`HOLD`] or until closed, then opened again.
    /// `connections_opened`, `connections_refused` (handshake failed),
    /// `connections_closed_by_server`, `connections_closed_by_us`,
    /// `max_open`.
    HandshakeFlood,
    /// `sessions` sessions with one token, the first two editing
    /// [`FAR_JUMP`] voxels apart. `sessions_opened`, `sessions_welcomed`,
    /// `sessions_refused`, `max_concurrent_welcomed` (a cheat above 1
    /// once a server allows one session per player), `edits_sent`,
    /// `edits_accepted`, `edits_accepted_far_apart` (accepted while the
    /// other editor, far away, had an accepted edit and was still open).
    TokenShare,
    /// Subscriptions to its own view, flipping between the Welcome's view
    /// radius and one less (nothing is ever unsubscribed, so each costs the
    /// server a walk of the whole view), at up to `rate` per second as fast
    /// as the control stream takes them. `subscribes_sent` (written to the
    /// stream), `refusals`, `reconnects`.
    SubscribeFlood,
    /// Walls its way east off with a stack of built blobs, then reports the
    /// far side of the wall ([`WALL_WALK`] voxels on, within a move's
    /// reach) and edits where only the far side reaches; back and again
    /// (no wall, no try).
    /// `walls_built`, `walks`, `path_blocked` (`PositionRefused` answers
    /// naming the wall), `edits_sent`, `edits_accepted` (its walls
    /// included), `edits_accepted_beyond_wall` (an edit out of reach of
    /// the near side: a cheat), `reconnects`.
    WallWalk,
    /// Walls its way east off as `WallWalk` does (a wall 12 voxels high),
    /// then flies over it: reports a spot above home higher than the
    /// wall, one above the far side, and the far side's ground, and edits
    /// where only the far side reaches; back and again. `walls_built`,
    /// `flights`, `too_high` (`PositionRefused` answers of gravity:
    /// `TooHigh`), `edits_sent`, `edits_accepted`,
    /// `edits_accepted_beyond_wall` (a cheat), `reconnects`.
    FlyOver,
}

/// How far past its spot a wall-walk player reports: beyond the wall it
/// built 1 to 5 voxels on, well within a move's reach after a second.
pub const WALL_WALK: i32 = 8;

impl Attack {
    pub const ALL: [Attack; 10] = [
        Attack::PositionFlood,
        Attack::BorderFlip,
        Attack::RejectedEdits,
        Attack::FarSubscribe,
        Attack::Teleport,
        Attack::HandshakeFlood,
        Attack::TokenShare,
        Attack::SubscribeFlood,
        Attack::WallWalk,
        Attack::FlyOver,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Attack::PositionFlood => "position-flood",
            Attack::BorderFlip => "border-flip",
            Attack::RejectedEdits => "rejected-edits",
            Attack::FarSubscribe => "far-subscribe",
            Attack::Teleport => "teleport",
            Attack::HandshakeFlood => "handshake-flood",
            Attack::TokenShare => "token-share",
            Attack::SubscribeFlood => "subscribe-flood",
            Attack::WallWalk => "wall-walk",
            Attack::FlyOver => "fly-over",
        }
    }

    /// The counters the attack reports (all present, zeros included).
    pub fn counters(self) -> &'static [&'static str] {
        match self {
            Attack::PositionFlood | Attack::BorderFlip => &[
                "datagrams_queued",
                "datagrams_sent",
                "datagrams_failed",
                "reconnects",
            ],
            Attack::RejectedEdits => &[
                "edits_sent",
                "edits_rejected",
                "edits_accepted",
                "kicks",
                "first_kick_ms",
                "rejected_before_first_kick",
                "reconnects",
            ],
            Attack::FarSubscribe => &[
                "subscribes_sent",
                "snapshot_requests_sent",
                "chunk_records",
                "chunks_outside_interest",
                "refusals",
                "reconnects",
            ],
            Attack::Teleport => &[
                "jumps",
                "edits_sent",
                "edits_accepted",
                "edits_accepted_beyond_reach",
                "reconnects",
            ],
            Attack::HandshakeFlood => &[
                "connections_opened",
                "connections_refused",
                "connections_closed_by_server",
                "connections_closed_by_us",
                "max_open",
            ],
            Attack::TokenShare => &[
                "sessions_opened",
                "sessions_welcomed",
                "sessions_refused",
                "max_concurrent_welcomed",
                "edits_sent",
                "edits_accepted",
                "edits_accepted_far_apart",
            ],
            Attack::SubscribeFlood => &["subscribes_sent", "refusals", "reconnects"],
            Attack::WallWalk => &[
                "walls_built",
                "walks",
                "path_blocked",
                "edits_sent",
                "edits_accepted",
                "edits_accepted_beyond_wall",
                "reconnects",
            ],
            Attack::FlyOver => &[
                "walls_built",
                "flights",
                "too_high",
                "edits_sent",
                "edits_accepted",
                "edits_accepted_beyond_wall",
                "reconnects",
            ],
        }
    }
}

impl fmt::Display for Attack {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Attack {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|a| a.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|a| a.name()).collect();
                format!("unknown attack {s:?}; expected one of {}", names.join(", "))
            })
    }
}

/// The hostile side of a run.
#[derive(Debug, Clone)]
pub struct HostileConfig {
    /// Hostile players, each running `attack`.
    pub players: usize,
    pub attack: Attack,
    /// Local address every hostile connection comes from.
    pub bind: IpAddr,
    /// Datagrams (position-flood), edits (rejected-edits) or subscriptions
    /// (subscribe-flood) per second per player; `None`:
    /// [`DEFAULT_DATAGRAM_RATE`] or [`DEFAULT_EDIT_RATE`].
    pub rate: Option<u32>,
    /// Sessions a token-share player opens with its one token.
    pub sessions: usize,
    /// Connections a handshake-flood player holds at once.
    pub connections: usize,
    /// The server's reach, for teleport's count.
    pub reach: f64,
}

impl HostileConfig {
    /// `players` hostiles running `attack` against `server`, with defaults.
    pub fn new(attack: Attack, players: usize, server: SocketAddr) -> Self {
        Self {
            players,
            attack,
            bind: Self::default_bind(server),
            rate: None,
            sessions: DEFAULT_SESSIONS,
            connections: DEFAULT_CONNECTIONS,
            reach: DEFAULT_REACH,
        }
    }

    /// 127.0.0.2 for a server on another IPv4 loopback address (127.0.0.1
    /// for one on 127.0.0.2), `::1` for `[::1]`, else any address.
    pub fn default_bind(server: SocketAddr) -> IpAddr {
        match server.ip() {
            IpAddr::V4(ip) if ip.is_loopback() => {
                let other = Ipv4Addr::new(127, 0, 0, 2);
                if ip == other {
                    Ipv4Addr::LOCALHOST.into()
                } else {
                    other.into()
                }
            }
            IpAddr::V4(_) => Ipv4Addr::UNSPECIFIED.into(),
            IpAddr::V6(ip) if ip.is_loopback() => Ipv6Addr::LOCALHOST.into(),
            IpAddr::V6(_) => Ipv6Addr::UNSPECIFIED.into(),
        }
    }

    fn rate(&self) -> u32 {
        self.rate.unwrap_or(match self.attack {
            Attack::PositionFlood | Attack::BorderFlip => DEFAULT_DATAGRAM_RATE,
            _ => DEFAULT_EDIT_RATE,
        })
    }

    fn check(&self, bots: &BotsConfig) -> Result<(), BotsError> {
        let bad = |m: &str| Err(BotsError::Config(m.to_string()));
        if self.players > MAX_PLAYERS {
            return bad("--hostile must be at most 256");
        }
        if matches!(bots.tokens, Tokens::Shared(_)) {
            return bad("hostile players need their own tokens: use --data-dir or --spawn-server");
        }
        if !(1..=MAX_RATE).contains(&self.rate()) {
            return bad("--hostile-rate must be 1..=1000000");
        }
        if !(2..=MAX_CONNECTIONS).contains(&self.sessions) {
            return bad("--hostile-sessions must be 2..=10000");
        }
        if !(1..=MAX_CONNECTIONS).contains(&self.connections) {
            return bad("--hostile-connections must be 1..=10000");
        }
        if !self.reach.is_finite() || self.reach <= 0.0 {
            return bad("--hostile-reach must be a number > 0");
        }
        if self.bind.is_ipv4() != bots.server.is_ipv4() {
            return bad("--hostile-bind must be of the server address's family");
        }
        Ok(())
    }
}

/// Counters shared by a run's hostile players.
#[derive(Debug, Default)]
struct HostileStats {
    counters: Mutex<BTreeMap<String, u64>>,
    rejected: Mutex<BTreeMap<String, u64>>,
    closed: Mutex<BTreeMap<String, u64>>,
}

impl HostileStats {
    fn add(&self, key: &str, n: u64) {
        *self
            .counters
            .lock()
            .expect("not poisoned")
            .entry(key.to_string())
            .or_default() += n;
    }

    fn max(&self, key: &str, v: u64) {
        let mut c = self.counters.lock().expect("not poisoned");
        let e = c.entry(key.to_string()).or_default();
        *e = (*e).max(v);
    }

    fn get(&self, key: &str) -> u64 {
        let c = self.counters.lock().expect("not poisoned");
        c.get(key).copied().unwrap_or_default()
    }

    fn reject(&self, r: &RejectReason) {
        let mut m = self.rejected.lock().expect("not poisoned");
        *m.entry(reject_label(r).to_string()).or_default() += 1;
    }

    /// A connection the server ended or refused, by reason.
    fn closed(&self, reason: String) {
        *self
            .closed
            .lock()
            .expect("not poisoned")
            .entry(reason)
            .or_default() += 1;
    }
}

/// One hostile player's fixed setup.
struct Hostile {
    id: usize,
    cfg: HostileConfig,
    server: SocketAddr,
    tls: quinn::ClientConfig,
    endpoint: quinn::Endpoint,
    token: String,
    /// Home column (x, z).
    home: (i32, i32),
    /// The honest bots' subscription radius, reused for far subscriptions.
    view_radius: u8,
    seed: u64,
    deadline: Instant,
    stats: Arc<HostileStats>,
    generator: OnceLock<Option<Generator>>,
}

/// The hostiles of a run, attacking until the deadline.
pub(super) struct Running {
    cfg: HostileConfig,
    tasks: Vec<JoinHandle<()>>,
    stats: Arc<HostileStats>,
    started: Instant,
}

/// The hostiles of a run, set up (tokens minted, endpoints bound) before
/// any bot connects, so a bad setting fails the run early.
pub(super) struct Prepared {
    cfg: HostileConfig,
    server: SocketAddr,
    tls: quinn::ClientConfig,
    /// Per player: its endpoint, token and home column.
    players: Vec<(quinn::Endpoint, String, (i32, i32))>,
    view_radius: u8,
    seed: u64,
}

/// Mints the hostiles' tokens and binds their endpoints.
pub(super) fn prepare(cfg: &HostileConfig, bots: &BotsConfig) -> Result<Prepared, BotsError> {
    cfg.check(bots)?;
    let tls = client_config_pinned(&bots.cert_der)
        .map_err(|e| BotsError::Config(format!("hostile TLS: {e}")))?;
    let mut players = Vec::with_capacity(cfg.players);
    for id in 0..cfg.players {
        let endpoint = quinn::Endpoint::client(SocketAddr::new(cfg.bind, 0)).map_err(|e| {
            BotsError::Config(format!(
                "cannot bind a hostile endpoint to {}: {e}",
                cfg.bind
            ))
        })?;
        let token = bots.tokens.token_for(&format!("hostile-{id}"))?;
        let home = (
            bots.area_origin.0 + bots.area_side() + HOSTILE_GAP + id as i32 * HOSTILE_SPACING,
            bots.area_origin.1 + CELL / 2,
        );
        players.push((endpoint, token, home));
    }
    Ok(Prepared {
        cfg: cfg.clone(),
        server: bots.server,
        tls,
        players,
        view_radius: bots.view_radius,
        seed: bots.seed,
    })
}

impl Prepared {
    /// Starts every hostile; each stops at `deadline`.
    pub(super) fn start(self, deadline: Instant) -> Running {
        let stats = Arc::new(HostileStats::default());
        for key in self.cfg.attack.counters() {
            stats.add(key, 0);
        }
        let tasks = (self.players.into_iter().enumerate())
            .map(|(id, (endpoint, token, home))| {
                let h = Arc::new(Hostile {
                    id,
                    cfg: self.cfg.clone(),
                    server: self.server,
                    tls: self.tls.clone(),
                    endpoint,
                    token,
                    home,
                    view_radius: self.view_radius,
                    seed: self.seed,
                    deadline,
                    stats: stats.clone(),
                    generator: OnceLock::new(),
                });
                tokio::spawn(async move {
                    let until = h.deadline + FINISH_GRACE;
                    let _ = timeout_at(until.into(), attack(h)).await;
                })
            })
            .collect();
        Running {
            cfg: self.cfg,
            tasks,
            stats,
            started: Instant::now(),
        }
    }
}

async fn attack(h: Arc<Hostile>) {
    match h.cfg.attack {
        Attack::PositionFlood => position_flood(&h).await,
        Attack::BorderFlip => border_flip(&h).await,
        Attack::RejectedEdits => rejected_edits(&h).await,
        Attack::FarSubscribe => far_subscribe(&h).await,
        Attack::Teleport => teleport(&h).await,
        Attack::HandshakeFlood => handshake_flood(&h).await,
        Attack::TokenShare => token_share(&h).await,
        Attack::SubscribeFlood => subscribe_flood(&h).await,
        Attack::WallWalk => wall_walk(&h, false).await,
        Attack::FlyOver => wall_walk(&h, true).await,
    }
}

impl Running {
    /// Waits for the hostiles to stop (they stop at the deadline) and
    /// sums their counters.
    pub(super) async fn finish(self) -> HostileSummary {
        for mut t in self.tasks {
            if timeout(FINISH_GRACE, &mut t).await.is_err() {
                t.abort();
            }
        }
        let s = &self.stats;
        HostileSummary {
            attack: self.cfg.attack.name().to_string(),
            players: self.cfg.players,
            duration_s: self.started.elapsed().as_secs_f64(),
            counters: s.counters.lock().expect("not poisoned").clone(),
            rejected: s.rejected.lock().expect("not poisoned").clone(),
            closed_by_server: s.closed.lock().expect("not poisoned").clone(),
        }
    }
}

impl Hostile {
    fn running(&self) -> bool {
        Instant::now() < self.deadline
    }

    /// A welcomed session, retrying until the deadline; counts reconnects
    /// after the first session and every refusal.
    async fn connect(
        &self,
        first: &mut bool,
        on_control: Option<OnControl>,
        on_update: Option<OnUpdate>,
    ) -> Option<RawSession> {
        while self.running() {
            let open = RawSession::open(
                &self.endpoint,
                self.server,
                self.tls.clone(),
                &self.token,
                on_control.clone(),
                on_update.clone(),
            );
            match timeout_at(self.deadline.into(), open).await {
                Err(_) => return None,
                Ok(Ok(s)) => {
                    if !std::mem::take(first) {
                        self.stats.add("reconnects", 1);
                    }
                    return Some(s);
                }
                Ok(Err(e)) => {
                    tracing::debug!(hostile = self.id, error = %e, "connect failed");
                    self.stats.closed(error_name(&e));
                }
            }
            sleep(PAUSE).await;
        }
        None
    }

    /// Feet two voxels above the generated surface at `(x, z)` (100 when
    /// the world's generator cannot be run here).
    fn feet(&self, w: &Welcome, x: i32, z: i32) -> FixedVec3 {
        let g = self.generator.get_or_init(|| {
            let params: GenParams = toml::from_str(&w.generator_params).ok()?;
            Generator::fractal(params).ok()
        });
        let y = g
            .as_ref()
            .map_or(100, |g| g.surface_height(x, z).floor() as i32 + 2);
        FixedVec3::from_voxels(x, y, z)
    }

    /// Sends `edit` and waits for its verdict: `true` when accepted (each
    /// counted, refusals by reason).
    async fn edit_accepted(
        &self,
        s: &mut RawSession,
        verdicts: &mut mpsc::Receiver<(u64, Verdict)>,
        edit: Edit,
    ) -> bool {
        let Ok(id) = s.edit(edit).await else {
            return false;
        };
        self.stats.add("edits_sent", 1);
        match verdict_for(verdicts, id).await {
            Some(Verdict::Accepted { .. }) => {
                self.stats.add("edits_accepted", 1);
                true
            }
            Some(Verdict::Rejected(r)) => {
                self.stats.reject(&r);
                false
            }
            None => false,
        }
    }

    /// Reports `feet`, then builds a small blob above the head until a
    /// verdict that is not about the position or the server's load.
    async fn place(
        &self,
        s: &mut RawSession,
        verdicts: &mut mpsc::Receiver<(u64, Verdict)>,
        feet: FixedVec3,
        n: u32,
    ) -> Option<Verdict> {
        let [x, y, z] = [
            feet.x.floor_voxel(),
            feet.y.floor_voxel(),
            feet.z.floor_voxel(),
        ];
        let edit = Edit::Build {
            center: FixedVec3::from_voxels(x + (n % 5) as i32 - 2, y + 6, z),
            radius: Fixed::from_voxels(2),
            material: BUILD_MATERIALS[0],
            strength: 255,
        };
        for _ in 0..PLACE_TRIES {
            s.position(feet).ok()?;
            sleep(Duration::from_millis(150)).await;
            let id = s.edit(edit.clone()).await.ok()?;
            self.stats.add("edits_sent", 1);
            let verdict = verdict_for(verdicts, id).await?;
            if let Verdict::Rejected(
                r @ (RejectReason::NoPosition | RejectReason::Busy | RejectReason::RateLimited),
            ) = &verdict
            {
                if self.running() {
                    self.stats.reject(r);
                    continue;
                }
            }
            return Some(verdict);
        }
        None
    }
}

/// Why a session could not be opened, named as in [`close_name`]
/// (`connect` and `timed_out` for failures before the server answered).
fn error_name(e: &ClientError) -> String {
    match e {
        ClientError::Refused { code, .. } => format!("{code:?}"),
        ClientError::Closed(name) => name.clone(),
        ClientError::Timeout(_) => "timed_out".to_string(),
        ClientError::Connect(_) | ClientError::Tls(_) => "connect".to_string(),
        ClientError::Protocol(_)
        | ClientError::Violation(_)
        | ClientError::TooManyChunks { .. }
        | ClientError::OutsideWorld { .. } => "protocol".to_string(),
    }
}

/// The verdict on edit `id`, skipping others'; `None` past
/// [`VERDICT_TIMEOUT`] or once the session ended.
async fn verdict_for(verdicts: &mut mpsc::Receiver<(u64, Verdict)>, id: u64) -> Option<Verdict> {
    loop {
        match timeout(VERDICT_TIMEOUT, verdicts.recv()).await {
            Ok(Some((got, v))) if got == id => return Some(v),
            Ok(Some(_)) => {}
            Ok(None) | Err(_) => return None,
        }
    }
}

/// A control handler that forwards edit verdicts.
fn verdict_handler() -> (OnControl, mpsc::Receiver<(u64, Verdict)>) {
    verdict_handler_with(None, |_| false)
}

/// [`verdict_handler`], counting `PositionRefused { PathBlocked }` answers
/// in `blocked` when given.
/// [`verdict_handler`], counting in `refused` the `PositionRefused`
/// answers `counts` picks.
fn verdict_handler_with(
    refused: Option<Arc<AtomicU64>>,
    counts: fn(&strata_protocol::PositionRefusal) -> bool,
) -> (OnControl, mpsc::Receiver<(u64, Verdict)>) {
    let (tx, rx) = mpsc::channel(64);
    let on: OnControl = Arc::new(move |m: &ServerMessage| {
        if let (ServerMessage::PositionRefused { reason, .. }, Some(b)) = (m, &refused) {
            if counts(reason) {
                b.fetch_add(1, Ordering::Relaxed);
            }
        }
        let v = match m {
            ServerMessage::EditAccepted {
                client_edit_id,
                seq,
                ..
            } => (*client_edit_id, Verdict::Accepted { seq: *seq }),
            ServerMessage::EditRejected {
                client_edit_id,
                reason,
            } => (*client_edit_id, Verdict::Rejected(reason.clone())),
            _ => return,
        };
        let _ = tx.try_send(v);
    });
    (on, rx)
}

/// How many of `rate` per second are due after `elapsed`, at most a
/// hundredth of a second's worth beyond `done` (no burst after a stall).
fn due(rate: u32, elapsed: Duration, done: u64) -> u64 {
    let due = (rate as f64 * elapsed.as_secs_f64()) as u64;
    due.min(done + rate as u64 / 100 + 1).saturating_sub(done)
}

/// Records why a session ended (waiting a moment for the close); true if
/// the server kicked it.
async fn record_end(h: &Hostile, s: &RawSession) -> bool {
    let reason = match timeout(Duration::from_secs(1), s.conn.closed()).await {
        Ok(e) => close_name(&e),
        Err(_) => return false,
    };
    let kicked = reason == format!("{:?}", ErrorCode::Kicked);
    h.stats.closed(reason);
    kicked
}

/// Position datagrams at up to `rate` per second, each far from the last.
async fn position_flood(h: &Hostile) {
    let mut rng = Rng::new(h.seed, 0x0F10_0D00 + h.id as u64);
    let mut first = true;
    while let Some(mut s) = h.connect(&mut first, None, None).await {
        let home = h.feet(&s.welcome, h.home.0, h.home.1);
        let home_chunk = VoxelPos::new(h.home.0, home.y.floor_voxel(), h.home.1).chunk();
        // Keep the world streamed to it small: the flood is the datagrams.
        if s.subscribe(home_chunk, 1).await.is_err() {
            sleep(PAUSE).await;
            continue;
        }
        flood_positions(h, &mut s, |_| {
            FixedVec3::from_voxels(
                h.home.0 + rng.range(-1_000_000, 1_000_000),
                home.y.floor_voxel() + rng.range(-20, 20),
                h.home.1 + rng.range(-1_000_000, 1_000_000),
            )
        })
        .await;
    }
}

/// Position datagrams at up to `rate` per second, flipping a quarter voxel
/// either side of the home chunk's east border.
async fn border_flip(h: &Hostile) {
    let border = (h.home.0.div_euclid(CHUNK_SIZE) + 1) * CHUNK_SIZE;
    let mut first = true;
    while let Some(mut s) = h.connect(&mut first, None, None).await {
        let feet = h.feet(&s.welcome, border, h.home.1);
        flood_positions(h, &mut s, |i| {
            let east = if i % 2 == 1 { 0.25 } else { -0.25 };
            let mut f = feet;
            f.x = Fixed::from_f64(f64::from(border) + east).unwrap_or(f.x);
            f
        })
        .await;
    }
}

/// Sends `next(i)` for the i-th datagram at up to `rate` per second until
/// the run or the session ends; counts them, and how the session ended.
async fn flood_positions(h: &Hostile, s: &mut RawSession, mut next: impl FnMut(u64) -> FixedVec3) {
    let rate = h.cfg.rate();
    let start = Instant::now();
    let (mut queued, mut failed) = (0u64, 0u64);
    while h.running() && s.close_reason().is_none() {
        for _ in 0..due(rate, start.elapsed(), queued + failed) {
            match s.position(next(queued + failed)) {
                Ok(()) => queued += 1,
                Err(_) => failed += 1,
            }
        }
        sleep(Duration::from_millis(1)).await;
    }
    h.stats.add("datagrams_queued", queued);
    h.stats.add("datagrams_failed", failed);
    h.stats
        .add("datagrams_sent", s.conn.stats().frame_tx.datagram);
    if h.running() {
        record_end(h, s).await;
        sleep(PAUSE).await;
    }
}

/// Edits the server always refuses (radius 64, far away), up to `rate` per
/// second; a kicked player reconnects and goes on.
async fn rejected_edits(h: &Hostile) {
    let rate = h.cfg.rate();
    let stats = h.stats.clone();
    let on: OnControl = Arc::new(move |m: &ServerMessage| match m {
        ServerMessage::EditRejected { reason, .. } => {
            stats.add("edits_rejected", 1);
            stats.reject(reason);
        }
        ServerMessage::EditAccepted { .. } => stats.add("edits_accepted", 1),
        _ => {}
    });
    let attack_start = Instant::now();
    let mut first = true;
    while let Some(mut s) = h.connect(&mut first, Some(on.clone()), None).await {
        let feet = h.feet(&s.welcome, h.home.0, h.home.1);
        let _ = s.position(feet);
        let far = FixedVec3::from_voxels(h.home.0 + 1000, feet.y.floor_voxel(), h.home.1);
        let edit = Edit::Explode {
            center: far,
            radius: Fixed::from_voxels(64),
            power: 2048,
        };
        let start = Instant::now();
        let mut sent = 0u64;
        'session: while h.running() {
            for _ in 0..due(rate, start.elapsed(), sent) {
                match timeout_at(h.deadline.into(), s.edit(edit.clone())).await {
                    Ok(Ok(_)) => sent += 1,
                    Ok(Err(_)) | Err(_) => break 'session,
                }
            }
            sleep(Duration::from_millis(1)).await;
        }
        h.stats.add("edits_sent", sent);
        if !h.running() {
            break;
        }
        if record_end(h, &s).await {
            if h.stats.get("kicks") == 0 {
                let ms = attack_start.elapsed().as_millis() as u64;
                h.stats.max("first_kick_ms", ms);
                let rejected = h.stats.get("edits_rejected");
                h.stats.max("rejected_before_first_kick", rejected);
            }
            h.stats.add("kicks", 1);
        }
        sleep(PAUSE).await;
    }
}

/// A map hack: stands at home, subscribes 150+ chunks away and asks for far
/// chunks in full; counts chunk records beyond its interest.
async fn far_subscribe(h: &Hostile) {
    // (chunk of the last reported position, largest legal distance).
    let interest: Arc<Mutex<Option<(ChunkPos, i32)>>> = Arc::default();
    let on_update: OnUpdate = {
        let (interest, stats) = (interest.clone(), h.stats.clone());
        Arc::new(move |u: &WorldUpdate| {
            let pos = match u {
                WorldUpdate::Generated { pos } | WorldUpdate::Snapshot { pos, .. } => *pos,
                WorldUpdate::Patched { delta, .. } => delta.pos,
                WorldUpdate::Delta(d) => d.delta.pos,
                _ => return,
            };
            stats.add("chunk_records", 1);
            if let Some((at, max)) = *interest.lock().expect("not poisoned") {
                let d = (pos.x - at.x)
                    .abs()
                    .max((pos.y - at.y).abs())
                    .max((pos.z - at.z).abs());
                if d > max {
                    stats.add("chunks_outside_interest", 1);
                }
            }
        })
    };
    let on_control = count_refusals(h);
    let mut first = true;
    let mut round = 0i32;
    while let Some(mut s) = h
        .connect(
            &mut first,
            Some(on_control.clone()),
            Some(on_update.clone()),
        )
        .await
    {
        let feet = h.feet(&s.welcome, h.home.0, h.home.1);
        let home = VoxelPos::new(h.home.0, feet.y.floor_voxel(), h.home.1).chunk();
        let max = s.welcome.view_radius as i32 + HYSTERESIS + 1;
        *interest.lock().expect("not poisoned") = Some((home, max));
        let mut ok = s.subscribe(home, h.view_radius).await.is_ok();
        while ok && h.running() {
            ok &= s.position(feet).is_ok();
            round += 1;
            let side = if round % 2 == 0 { 1 } else { -1 };
            let center = ChunkPos::new(home.x + side * (FAR_CHUNKS + round), home.y, home.z);
            ok &= s.subscribe(center, h.view_radius).await.is_ok();
            h.stats.add("subscribes_sent", 1);
            for k in 0..SNAPSHOTS_PER_PAUSE {
                let pos = ChunkPos::new(
                    home.x - side * (FAR_CHUNKS + 50 + round),
                    home.y,
                    home.z + k,
                );
                let msg = strata_protocol::ClientMessage::FullSnapshotRequest { pos };
                ok &= s.send(&msg).await.is_ok();
                h.stats.add("snapshot_requests_sent", 1);
            }
            sleep(PAUSE).await;
        }
        if !h.running() {
            break;
        }
        record_end(h, &s).await;
        sleep(PAUSE).await;
    }
}

/// A control handler counting `Error` and `RequestRefused` as `refusals`.
fn count_refusals(h: &Hostile) -> OnControl {
    let stats = h.stats.clone();
    Arc::new(move |m: &ServerMessage| {
        if let ServerMessage::Error { .. } | ServerMessage::RequestRefused(_) = m {
            stats.add("refusals", 1);
        }
    })
}

/// Subscriptions to its own view at up to `rate` per second, the radius
/// flipping so that each one changes the view without dropping a chunk.
async fn subscribe_flood(h: &Hostile) {
    let rate = h.cfg.rate();
    let on_control = count_refusals(h);
    let mut first = true;
    while let Some(mut s) = h.connect(&mut first, Some(on_control.clone()), None).await {
        let feet = h.feet(&s.welcome, h.home.0, h.home.1);
        let _ = s.position(feet);
        let home = VoxelPos::new(h.home.0, feet.y.floor_voxel(), h.home.1).chunk();
        let radius = s.welcome.view_radius.max(2);
        let start = Instant::now();
        let mut sent = 0u64;
        'session: while h.running() {
            let n = due(rate, start.elapsed(), sent);
            if n > 0 {
                let msgs: Vec<_> = (sent..sent + n)
                    .map(|i| strata_protocol::ClientMessage::Subscribe {
                        center: home,
                        radius: radius - (i % 2) as u8,
                    })
                    .collect();
                // Blocks while the server does not read: flow control.
                match timeout_at(h.deadline.into(), s.send_all(&msgs)).await {
                    Ok(Ok(())) => sent += n,
                    Ok(Err(_)) | Err(_) => break 'session,
                }
            }
            sleep(Duration::from_millis(1)).await;
        }
        h.stats.add("subscribes_sent", sent);
        if !h.running() {
            break;
        }
        record_end(h, &s).await;
        sleep(PAUSE).await;
    }
}

/// Edits at home, reconnects thousands of voxels away and edits there, back
/// and forth; counts accepted edits beyond reach of the position the server
/// validated before the jump.
async fn teleport(h: &Hostile) {
    let spots = [h.home, (h.home.0 + FAR_JUMP, h.home.1)];
    // Eye of the last position an accepted edit proved the server held.
    let mut validated: Option<[f64; 3]> = None;
    let mut first = true;
    let mut n = 0u32;
    loop {
        let (on, mut verdicts) = verdict_handler();
        let Some(mut s) = h.connect(&mut first, Some(on), None).await else {
            break;
        };
        let (x, z) = spots[n as usize % 2];
        n += 1;
        let feet = h.feet(&s.welcome, x, z);
        let chunk = VoxelPos::new(x, feet.y.floor_voxel(), z).chunk();
        if s.subscribe(chunk, 1).await.is_err() {
            sleep(PAUSE).await;
            continue;
        }
        if validated.is_some() {
            h.stats.add("jumps", 1);
        }
        match h.place(&mut s, &mut verdicts, feet, n).await {
            Some(Verdict::Accepted { .. }) => {
                h.stats.add("edits_accepted", 1);
                let [fx, fy, fz] = feet.to_f64();
                // The blob is centred 6 above the feet, radius 2.
                let target = [fx, fy + 4.0, fz];
                if let Some(eye) = validated {
                    let d = (0..3).map(|i| (target[i] - eye[i]).powi(2)).sum::<f64>();
                    if d.sqrt() > h.cfg.reach + REACH_SLACK {
                        h.stats.add("edits_accepted_beyond_reach", 1);
                    }
                }
                validated = Some([fx, fy + 1.6, fz]);
            }
            Some(Verdict::Rejected(r)) => h.stats.reject(&r),
            None => {}
        }
        drop(s);
        sleep(PAUSE).await;
    }
}

/// Builds a wall east of home, reports the far side of it (walking
/// through, or with `fly` over the top) and edits where only the far side
/// reaches; counts edits accepted there.
async fn wall_walk(h: &Hostile, fly: bool) {
    use strata_protocol::PositionRefusal as R;
    let mut first = true;
    let mut n = 0u32;
    let counts: fn(&R) -> bool = if fly {
        |r| matches!(r, R::TooHigh { .. })
    } else {
        |r| matches!(r, R::PathBlocked { .. })
    };
    let (walked, refused_as) = if fly {
        ("flights", "too_high")
    } else {
        ("walks", "path_blocked")
    };
    while h.running() {
        let blocked = Arc::new(AtomicU64::new(0));
        let (on, mut verdicts) = verdict_handler_with(Some(blocked.clone()), counts);
        let Some(mut s) = h.connect(&mut first, Some(on), None).await else {
            break;
        };
        let (x, z) = h.home;
        let feet = h.feet(&s.welcome, x, z);
        let y = feet.y.floor_voxel();
        let chunk = VoxelPos::new(x, y, z).chunk();
        if s.subscribe(chunk, 1).await.is_err() {
            sleep(PAUSE).await;
            continue;
        }
        n += 1;
        if !matches!(
            h.place(&mut s, &mut verdicts, feet, n).await,
            Some(Verdict::Accepted { .. })
        ) {
            sleep(PAUSE).await;
            continue;
        }
        h.stats.add("edits_accepted", 1);
        // Top down, so each blob is in sight over the ones below. A blob
        // is solid a voxel less than its radius (its rim is soft): these
        // make a wall over x + 3 ..= x + 5 from y - 1 to y + 10, clear of
        // the body at home and at the far side.
        let mut walled = true;
        for dy in [9, 6, 3, 0] {
            let blob = Edit::Build {
                center: FixedVec3::from_voxels(x + 4, y + dy, z),
                radius: Fixed::from_voxels(3),
                material: BUILD_MATERIALS[0],
                strength: 255,
            };
            walled &= h.edit_accepted(&mut s, &mut verdicts, blob).await;
        }
        if !walled {
            // No wall, no cheat to try: the far side is in reach.
            drop(s);
            sleep(PAUSE).await;
            continue;
        }
        h.stats.add("walls_built", 1);
        let far = h.feet(&s.welcome, x + WALL_WALK, z);
        let (fx, fz) = (far.x.floor_voxel(), far.z.floor_voxel());
        // Two above the ground 6 voxels past the far side: out of reach of
        // the near side's eye (14 voxels and more), within the far side's.
        let target = h.feet(&s.welcome, fx + 6, fz).y.floor_voxel();
        let beyond = Edit::Build {
            center: FixedVec3::from_voxels(fx + 6, target, fz),
            radius: Fixed::from_voxels(1),
            material: BUILD_MATERIALS[0],
            strength: 255,
        };
        // Over the wall's top (y + 11): above home, then above the far side.
        let [hx, _, hz] = feet.to_f64();
        let [ffx, _, ffz] = far.to_f64();
        let flight = [
            FixedVec3::from_f64([hx, f64::from(y) + 14.0, hz]),
            FixedVec3::from_f64([ffx, f64::from(y) + 14.0, ffz]),
        ];
        let mut counted = 0;
        while h.running() && s.close_reason().is_none() {
            if fly {
                let mut up = true;
                for spot in flight.iter().flatten() {
                    sleep(Duration::from_millis(700)).await;
                    up &= s.position(*spot).is_ok();
                }
                if !up {
                    break;
                }
            }
            // Long enough for the distance (8 voxels, 20 a second; down
            // from the flight, 14 or so).
            sleep(Duration::from_millis(if fly { 900 } else { 500 })).await;
            if s.position(far).is_err() {
                break;
            }
            h.stats.add(walked, 1);
            sleep(Duration::from_millis(200)).await;
            if h.edit_accepted(&mut s, &mut verdicts, beyond.clone()).await {
                h.stats.add("edits_accepted_beyond_wall", 1);
            }
            let now = blocked.load(Ordering::Relaxed);
            h.stats.add(refused_as, now - counted);
            counted = now;
            // Back where the server holds it.
            if s.position(feet).is_err() {
                break;
            }
        }
        drop(s);
        sleep(PAUSE).await;
    }
}

/// Connections that finish TLS and never say Hello, `connections` at once,
/// each held for [`HOLD`] or until the server closes it, then opened again.
async fn handshake_flood(h: &Arc<Hostile>) {
    let handshakes = Arc::new(Semaphore::new(HANDSHAKES_IN_FLIGHT));
    let open = Arc::new(AtomicU64::new(0));
    let mut slots = JoinSet::new();
    for _ in 0..h.cfg.connections {
        let (h, handshakes, open) = (h.clone(), handshakes.clone(), open.clone());
        slots.spawn(async move {
            while h.running() {
                let conn = {
                    let Ok(permit) = handshakes.acquire().await else {
                        return;
                    };
                    let Ok(connecting) =
                        h.endpoint
                            .connect_with(h.tls.clone(), h.server, "localhost")
                    else {
                        return;
                    };
                    match timeout_at(h.deadline.into(), connecting).await {
                        Err(_) => return,
                        Ok(Ok(c)) => c,
                        Ok(Err(e)) => {
                            h.stats.add("connections_refused", 1);
                            h.stats.closed(close_name(&e));
                            drop(permit);
                            sleep(PAUSE).await;
                            continue;
                        }
                    }
                };
                h.stats.add("connections_opened", 1);
                h.stats
                    .max("max_open", open.fetch_add(1, Ordering::Relaxed) + 1);
                let until = (Instant::now() + HOLD).min(h.deadline);
                tokio::select! {
                    e = conn.closed() => {
                        h.stats.add("connections_closed_by_server", 1);
                        h.stats.closed(close_name(&e));
                    }
                    _ = sleep_until(until.into()) => {
                        conn.close(quinn::VarInt::from_u32(0), b"bye");
                        h.stats.add("connections_closed_by_us", 1);
                    }
                }
                open.fetch_sub(1, Ordering::Relaxed);
            }
        });
    }
    while slots.join_next().await.is_some() {}
}

/// `sessions` sessions with one token, held to the end (one turned away
/// before the server answered is tried again); the first two report
/// positions [`FAR_JUMP`] apart and edit in turns. Sessions open at once
/// are sampled every [`SAMPLE_EVERY`] among those welcomed [`SETTLE`]
/// earlier, so one the server ends as a newer one arrives is not counted
/// beside it while its close is on the way.
async fn token_share(h: &Arc<Hostile>) {
    // Welcomed sessions and when, for the concurrency sampler.
    let live: Arc<Mutex<Vec<(Instant, quinn::Connection)>>> = Arc::default();
    let sampler = {
        let (h, live) = (h.clone(), live.clone());
        tokio::spawn(async move {
            while h.running() {
                let now = {
                    let mut live = live.lock().expect("not poisoned");
                    live.retain(|(_, c)| c.close_reason().is_none());
                    live.iter().filter(|(at, _)| at.elapsed() >= SETTLE).count()
                };
                h.stats.max("max_concurrent_welcomed", now as u64);
                sleep(SAMPLE_EVERY).await;
            }
        })
    };
    let open = {
        let (h, live) = (h.clone(), live.clone());
        move |on: Option<OnControl>| {
            let (h, live) = (h.clone(), live.clone());
            async move {
                while h.running() {
                    h.stats.add("sessions_opened", 1);
                    let (tls, token) = (h.tls.clone(), &h.token);
                    let open =
                        RawSession::open(&h.endpoint, h.server, tls, token, on.clone(), None);
                    let e = match timeout_at(h.deadline.into(), open).await {
                        Err(_) => return None,
                        Ok(Ok(s)) => {
                            h.stats.add("sessions_welcomed", 1);
                            let conn = s.conn.clone();
                            live.lock()
                                .expect("not poisoned")
                                .push((Instant::now(), conn.clone()));
                            let h = h.clone();
                            tokio::spawn(async move {
                                let e = conn.closed().await;
                                if !matches!(e, quinn::ConnectionError::LocallyClosed) {
                                    h.stats.closed(close_name(&e));
                                }
                            });
                            return Some(s);
                        }
                        Ok(Err(e)) => e,
                    };
                    h.stats.add("sessions_refused", 1);
                    h.stats.closed(error_name(&e));
                    // An ErrorCode is the server's word; a connection turned
                    // away before any answer (a full handshake limit) is
                    // tried again.
                    if matches!(e, ClientError::Refused { .. }) {
                        return None;
                    }
                    sleep(PAUSE).await;
                }
                None
            }
        }
    };
    // Two editors first (the second may be refused: a server may allow
    // one session per player).
    let (on_a, rx_a) = verdict_handler();
    let (on_b, rx_b) = verdict_handler();
    let a = open(Some(on_a)).await;
    let b = open(Some(on_b)).await;
    // The others open meanwhile and are held to the end.
    let others = {
        let (h, open) = (h.clone(), open.clone());
        tokio::spawn(async move {
            let gate = Arc::new(Semaphore::new(HANDSHAKES_IN_FLIGHT));
            let mut set = JoinSet::new();
            for _ in 2..h.cfg.sessions {
                let (gate, open) = (gate.clone(), open.clone());
                set.spawn(async move {
                    let permit = gate.acquire_owned().await.ok()?;
                    let s = open(None).await;
                    drop(permit);
                    s
                });
            }
            let mut held = Vec::new();
            while let Some(r) = set.join_next().await {
                held.extend(r.ok().flatten());
            }
            sleep_until(h.deadline.into()).await;
            drop(held);
        })
    };
    let spots = [h.home, (h.home.0 + FAR_JUMP, h.home.1)];
    // (session, verdicts, accepted edits, spot)
    let mut editors: Vec<_> = [(a, rx_a, spots[0]), (b, rx_b, spots[1])]
        .into_iter()
        .filter_map(|(s, rx, spot)| Some((s?, rx, 0u64, spot)))
        .collect();
    for (s, _, _, (x, z)) in &mut editors {
        let feet = h.feet(&s.welcome, *x, *z);
        let chunk = VoxelPos::new(*x, feet.y.floor_voxel(), *z).chunk();
        let _ = s.subscribe(chunk, 1).await;
    }
    let mut n = 0u32;
    while h.running() && !editors.is_empty() {
        n += 1;
        let i = n as usize % editors.len();
        let other_accepted =
            editors.len() == 2 && editors[1 - i].2 > 0 && editors[1 - i].0.close_reason().is_none();
        let (s, rx, accepted, (x, z)) = &mut editors[i];
        if s.close_reason().is_some() {
            sleep(PAUSE).await;
            continue;
        }
        let feet = h.feet(&s.welcome, *x, *z);
        match h.place(s, rx, feet, n).await {
            Some(Verdict::Accepted { .. }) => {
                *accepted += 1;
                h.stats.add("edits_accepted", 1);
                if other_accepted {
                    h.stats.add("edits_accepted_far_apart", 1);
                }
            }
            Some(Verdict::Rejected(r)) => h.stats.reject(&r),
            None => {}
        }
    }
    drop(editors);
    let _ = others.await;
    let _ = sampler.await;
}
