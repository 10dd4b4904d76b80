//! `strata-bots`: many headless clients in one process, each a real QUIC
//! connection that walks, subscribes, edits by profile and keeps a
//! mesh-checked replica. At the end the bots stop editing, wait for the
//! world to go quiet, and compare every replica chunk with the server's.
//!
//! - [`profile`]: what each bot does; [`footing`]: where it stands and aims.
//! - [`driver`]: one bot's life (connect, walk, edit, reconnect, verify);
//!   `walker`: how it moves.
//! - [`stats`], [`summary`], [`progress`], [`ack_log`]: what a run reports.
//! - [`hostile`]: hostile players beside the bots (`--hostile N --attack
//!   KIND`), on bare sessions ([`raw_session`]).

pub mod ack_log;
mod driver;
pub mod duration;
pub mod footing;
pub mod hostile;
pub mod profile;
mod progress;
pub mod raw_session;
pub mod rng;
pub mod stats;
pub mod summary;
mod walker;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use strata_auth::{self as auth, Secret};
use strata_protocol::{ChunkVersion, Role as AuthRole};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::ChunkPos;
use thiserror::Error;
use tokio::sync::{watch, Semaphore};

use crate::pool::ChunkPool;
use crate::prediction::PredictionStats;
use ack_log::AckLog;
use driver::BotOutcome;
pub use hostile::{Attack, HostileConfig};
pub use profile::{Profile, Role};
use stats::Stats;
pub use summary::{HostileSummary, Summary};

/// Side of the square each bot calls home, in voxels.
pub const CELL: i32 = 24;
/// Bounds of `--stalled-window` (bytes).
pub const MIN_STALLED_WINDOW: u32 = 1024;
pub const MAX_STALLED_WINDOW: u32 = 64 << 20;
/// Default south-west corner of the bots' area: far from the protected spawn.
pub const DEFAULT_AREA_ORIGIN: (i32, i32) = (512, 512);
/// Lifetime of minted bot tokens.
pub const TOKEN_TTL: Duration = Duration::from_secs(24 * 3600);
/// Handshakes in flight at once.
pub const CONNECT_CONCURRENCY: usize = 32;
/// The world counts as quiet after this long without an update at any bot.
pub const QUIET_PERIOD: Duration = Duration::from_millis(750);
/// Longest wait for every bot to join and load its surroundings before the
/// edits start anyway.
pub const RAMP_TIMEOUT: Duration = Duration::from_secs(60);
/// Longest wait for quiet before checking anyway.
pub const QUIET_TIMEOUT: Duration = Duration::from_secs(30);
/// Default of [`BotsConfig::verify_timeout`].
pub const DEFAULT_VERIFY_TIMEOUT: Duration = Duration::from_secs(45);
/// Longest [`BotsConfig::verify_timeout`] (`--verify-timeout`).
pub const MAX_VERIFY_TIMEOUT: Duration = Duration::from_secs(3600);
/// How much longer than [`BotsConfig::verify_timeout`] the fleet waits
/// for every bot to report its end-of-run check.
pub const VERIFY_GRACE: Duration = Duration::from_secs(15);
/// Longest [`BotsConfig::link_delay`] (`--link-delay`).
pub const MAX_LINK_DELAY: Duration = Duration::from_secs(5);
/// Default of [`BotsConfig::silence_limit`].
pub const DEFAULT_SILENCE_LIMIT: Duration = Duration::from_secs(10);
/// Largest view radius a bot subscribes with.
pub const MAX_BOT_VIEW_RADIUS: u8 = 8;

/// Accepted edits remembered for broadcast-latency matching.
pub const MAX_TRACKED_EDITS: usize = 1 << 21;

#[derive(Debug, Error)]
pub enum BotsError {
    #[error("invalid setting: {0}")]
    Config(String),
    #[error("cannot create ack log {path}: {source}")]
    AckLog {
        path: String,
        source: std::io::Error,
    },
    #[error("cannot mint a token: {0}")]
    Token(String),
}

/// Where bots get their tokens.
#[derive(Debug, Clone)]
pub enum Tokens {
    /// One token for every bot: they share one player's rate limits.
    Shared(String),
    /// A token per bot (`<prefix>-<index>`), signed with the server's secret.
    Minted(Secret),
}

impl Tokens {
    /// The token of bot `bot` of a fleet whose players are `prefix-N`.
    pub fn token(&self, prefix: &str, bot: usize) -> Result<String, BotsError> {
        self.token_for(&format!("{prefix}-{bot}"))
    }

    /// The token of player `name` (the shared one with [`Tokens::Shared`]).
    pub fn token_for(&self, name: &str) -> Result<String, BotsError> {
        match self {
            Tokens::Shared(t) => Ok(t.clone()),
            Tokens::Minted(secret) => {
                auth::issue(secret, name, AuthRole::Player, TOKEN_TTL, auth::unix_now())
                    .map_err(|e| BotsError::Token(e.to_string()))
            }
        }
    }
}

/// Which replica chunks are compared with the server's at the end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VerifyMode {
    /// Every held chunk (full snapshots, version 0 included).
    All,
    /// Only chunks some edit changed (cheaper for big runs).
    Modified,
    /// No end-of-run comparison.
    Off,
}

impl std::str::FromStr for VerifyMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "all" => Ok(VerifyMode::All),
            "modified" => Ok(VerifyMode::Modified),
            "off" => Ok(VerifyMode::Off),
            _ => Err(format!("expected all, modified or off, not {s:?}")),
        }
    }
}

/// Everything a run needs.
#[derive(Debug, Clone)]
pub struct BotsConfig {
    pub server: SocketAddr,
    /// DER certificate the bots pin.
    pub cert_der: Vec<u8>,
    pub tokens: Tokens,
    pub bots: usize,
    /// How long the bots edit.
    pub duration: Duration,
    pub profile: Profile,
    /// Edits per second per bot (0: walk only).
    pub edit_rate: f64,
    /// Chunks around each bot it subscribes to (Chebyshev radius).
    pub view_radius: u8,
    pub verify: VerifyMode,
    pub seed: u64,
    /// The first `stalled` bots stop reading their updates once spawned.
    pub stalled: usize,
    /// Per-stream receive window (bytes) of each stalled bot's connection
    /// (`--stalled-window`: quinn's `stream_receive_window`, every stream,
    /// control too, not only updates; `None`: the client's own, 1.25 MB).
    /// Small, the server's queue for a stalled bot fills after kilobytes
    /// of updates instead of megabytes, so a short run reaches the
    /// server's backpressure (deltas dropped, chunks withdrawn).
    pub stalled_window: Option<u32>,
    /// Hold the edits until every bot has joined ([`Phase::Ramp`]); false
    /// lets each bot edit as soon as it stands, while others still join.
    pub ramp: bool,
    pub ack_log: Option<PathBuf>,
    pub progress: bool,
    pub area_origin: (i32, i32),
    /// Region side in chunks, for counting `region_crossings` (the server's
    /// `[sequencer] region_chunks`).
    pub region_chunks: u32,
    /// A server silent this long, despite pings, is taken for dead and the
    /// bot reconnects. QUIC's idle timeout is much longer, and a restarted
    /// server cannot reset the old connections (its reset key is new).
    pub silence_limit: Duration,
    /// Bots predict their own edits (client-side prediction).
    pub predict: bool,
    /// `Hello::capabilities` of every bot (`--thin`, `--op-replay`).
    pub capabilities: u32,
    /// On a cluster: a bot whose edit is refused `RegionElsewhere` for the
    /// region it stands in moves to the node named, arriving there with its
    /// last ticket (`--follow-owners`).
    pub follow_owners: bool,
    /// Bots play as `<player_prefix>-<index>` (with minted tokens): fleets
    /// on one cluster need different prefixes, or they log each other out.
    pub player_prefix: String,
    /// Every bot's sends leave this late (`--link-delay`): a simulated
    /// network delay that adds to the RTT the server measures. Zero: none.
    pub link_delay: Duration,
    /// Longest a bot's end-of-run check waits for the server's copies
    /// (`--verify-timeout`); what has not come by then counts as
    /// `chunks_unverified`. `--verify all` at a large view radius asks for
    /// thousands of chunks per bot.
    pub verify_timeout: Duration,
}

impl BotsConfig {
    /// Two bots of the mixed profile for 2 s against `server`, at 2 edits
    /// per second each, view radius 2, checking the chunks they modify;
    /// callers override what their run needs.
    pub fn new(server: SocketAddr, cert_der: Vec<u8>, tokens: Tokens) -> Self {
        Self {
            server,
            cert_der,
            tokens,
            bots: 2,
            duration: Duration::from_secs(2),
            profile: Profile::Mixed,
            edit_rate: 2.0,
            view_radius: 2,
            verify: VerifyMode::Modified,
            seed: 1,
            stalled: 0,
            stalled_window: None,
            ramp: true,
            ack_log: None,
            progress: false,
            area_origin: DEFAULT_AREA_ORIGIN,
            region_chunks: 8,
            silence_limit: DEFAULT_SILENCE_LIMIT,
            predict: false,
            capabilities: 0,
            follow_owners: false,
            player_prefix: "bot".into(),
            link_delay: Duration::ZERO,
            verify_timeout: DEFAULT_VERIFY_TIMEOUT,
        }
    }

    fn check(&self) -> Result<(), BotsError> {
        let bad = |m: &str| Err(BotsError::Config(m.to_string()));
        if self.bots == 0 {
            return bad("--bots must be at least 1");
        }
        if self.stalled > self.bots {
            return bad("--stalled cannot exceed --bots");
        }
        if self
            .stalled_window
            .is_some_and(|w| !(MIN_STALLED_WINDOW..=MAX_STALLED_WINDOW).contains(&w))
        {
            return bad("--stalled-window must be 1024..=67108864 bytes");
        }
        if !self.edit_rate.is_finite() || self.edit_rate < 0.0 {
            return bad("--edit-rate must be a number >= 0");
        }
        if !(1..=MAX_BOT_VIEW_RADIUS).contains(&self.view_radius) {
            return bad("--view-radius must be 1..=8");
        }
        if self.link_delay > MAX_LINK_DELAY {
            return bad("--link-delay must be at most 5s");
        }
        if self.verify_timeout.is_zero() || self.verify_timeout > MAX_VERIFY_TIMEOUT {
            return bad("--verify-timeout must be above 0 and at most 1h");
        }
        Ok(())
    }

    /// Side of the square area the bots share, in voxels.
    pub fn area_side(&self) -> i32 {
        (self.bots as f64).sqrt().ceil() as i32 * CELL
    }

    /// Centre of bot `i`'s home cell.
    pub fn home(&self, i: usize) -> (f64, f64) {
        let per_row = (self.bots as f64).sqrt().ceil() as usize;
        let (cx, cz) = ((i % per_row) as i32, (i / per_row) as i32);
        (
            (self.area_origin.0 + cx * CELL + CELL / 2) as f64,
            (self.area_origin.1 + cz * CELL + CELL / 2) as f64,
        )
    }
}

/// Phases of a run, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Phase {
    /// Join, find footing and load the surroundings; no edits yet, so the
    /// measured run is 'N players online', not a join storm.
    Ramp,
    /// Walk and edit.
    Run,
    /// Stop editing and moving; wait for the world to go quiet.
    Quiesce,
    /// Compare replicas with the server.
    Verify,
    /// Close.
    Done,
}

/// What the bots share.
#[derive(Debug)]
pub struct Fleet {
    pub cfg: BotsConfig,
    pub stats: Stats,
    pub pool: Arc<ChunkPool>,
    phase: watch::Sender<Phase>,
    ack_log: Option<AckLog>,
    connect_slots: Semaphore,
    /// Accepted edits: seq -> (sent at, author bot).
    sent: Mutex<HashMap<u64, (Instant, usize)>>,
    /// Highest acknowledged version of every chunk.
    acked: Mutex<HashMap<ChunkPos, u64>>,
    /// Edits awaiting a verdict right now.
    in_flight: AtomicUsize,
    /// When some bot last received an update (ms since the run's start).
    last_activity_ms: AtomicU64,
    /// Bots that finished their end-of-run check (or gave up).
    finished: AtomicUsize,
    /// Bots that joined and found footing during the ramp.
    ready: AtomicUsize,
    generator: OnceLock<Option<Generator>>,
    started: Instant,
}

impl Fleet {
    fn phase_name(&self) -> &'static str {
        match *self.phase.borrow() {
            Phase::Ramp => "joining",
            Phase::Run => "editing",
            Phase::Quiesce => "waiting for quiet",
            Phase::Verify => "verifying",
            Phase::Done => "done",
        }
    }

    fn touch(&self) {
        let ms = self.started.elapsed().as_millis() as u64;
        self.last_activity_ms.fetch_max(ms, Ordering::Relaxed);
    }

    fn quiet_for(&self) -> Duration {
        let last = Duration::from_millis(self.last_activity_ms.load(Ordering::Relaxed));
        self.started.elapsed().saturating_sub(last)
    }

    /// Surface height hint from the world's generator, when clients can run it.
    fn surface_hint(&self, welcome: &strata_protocol::Welcome, x: f64, z: f64) -> f64 {
        let g = self.generator.get_or_init(|| {
            let params: GenParams = toml::from_str(&welcome.generator_params).ok()?;
            Generator::fractal(params).ok()
        });
        g.as_ref()
            .map_or(0.0, |g| g.surface_height(x as i32, z as i32).floor())
    }

    fn accepted(&self, seq: u64, sent_at: Instant, bot: usize, changes: &[ChunkVersion]) {
        {
            let mut sent = self.sent.lock().expect("not poisoned");
            if sent.len() < MAX_TRACKED_EDITS {
                sent.insert(seq, (sent_at, bot));
            }
        }
        {
            let mut acked = self.acked.lock().expect("not poisoned");
            for c in changes {
                let v = acked.entry(c.pos).or_default();
                *v = (*v).max(c.version);
            }
        }
        if let Some(log) = &self.ack_log {
            if let Err(e) = log.write(seq, changes) {
                tracing::error!(error = %e, "ack log write failed");
            }
        }
    }
}

/// Runs the bots against a server and returns the summary.
pub async fn run(cfg: BotsConfig) -> Result<Summary, BotsError> {
    run_with(cfg, None).await
}

/// Like [`run`], with hostile players attacking during the edit phase
/// (from its start to its end; see [`hostile`]).
pub async fn run_with(
    cfg: BotsConfig,
    hostile: Option<HostileConfig>,
) -> Result<Summary, BotsError> {
    run_until(cfg, hostile, std::future::pending()).await
}

/// Like [`run_with`], the run ending early once `stop` resolves (the
/// binary's SIGTERM): during the ramp, no edits start; during the edits,
/// they end. Either way the bots then wait for quiet, check and report as
/// after the full `duration`. `stop` is dropped once the edits end.
pub async fn run_until(
    cfg: BotsConfig,
    hostile: Option<HostileConfig>,
    stop: impl std::future::Future<Output = ()>,
) -> Result<Summary, BotsError> {
    cfg.check()?;
    let hostile = match &hostile {
        Some(h) => Some(hostile::prepare(h, &cfg)?),
        None => None,
    };
    let ack_log = match &cfg.ack_log {
        Some(p) => Some(AckLog::create(p).map_err(|source| BotsError::AckLog {
            path: p.display().to_string(),
            source,
        })?),
        None => None,
    };
    // Fail early on a token problem rather than in every bot.
    cfg.tokens.token(&cfg.player_prefix, 0)?;
    let first = if cfg.ramp { Phase::Ramp } else { Phase::Run };
    let (phase, _) = watch::channel(first);
    let fleet = Arc::new(Fleet {
        cfg: cfg.clone(),
        stats: Stats::default(),
        pool: Arc::default(),
        phase,
        ack_log,
        connect_slots: Semaphore::new(CONNECT_CONCURRENCY),
        sent: Mutex::default(),
        acked: Mutex::default(),
        in_flight: AtomicUsize::new(0),
        last_activity_ms: AtomicU64::new(0),
        finished: AtomicUsize::new(0),
        ready: AtomicUsize::new(0),
        generator: OnceLock::new(),
        started: Instant::now(),
    });
    let progress = cfg
        .progress
        .then(|| progress::spawn(fleet.clone(), cfg.bots, cfg.duration));
    let bots: Vec<_> = (0..cfg.bots)
        .map(|i| tokio::spawn(driver::run_bot(fleet.clone(), i)))
        .collect();
    // One stop for the ramp and the edits: polled no more once resolved.
    let mut stop = Box::pin(stop);
    let mut stopped = false;
    // Edits start once every bot stands in the world and snapshots have
    // stopped arriving (or never, when told to stop meanwhile).
    let ramp_start = Instant::now();
    while cfg.ramp
        && (fleet.ready.load(Ordering::Relaxed) < cfg.bots || fleet.quiet_for() < QUIET_PERIOD)
        && ramp_start.elapsed() < RAMP_TIMEOUT
    {
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(50)) => {}
            _ = &mut stop => {
                tracing::info!("told to stop during the ramp: no edits");
                stopped = true;
                break;
            }
        }
    }
    let ramp = if cfg.ramp {
        ramp_start.elapsed()
    } else {
        Duration::ZERO
    };
    let ready_at_start = fleet.ready.load(Ordering::Relaxed);
    fleet.stats.ack.restart_timeline();
    fleet.stats.broadcast.restart_timeline();
    let edit_start = Instant::now();
    let hostiles = if stopped {
        None
    } else {
        fleet.phase.send_replace(Phase::Run);
        let hostiles = hostile.map(|h| h.start(edit_start + cfg.duration));
        tokio::select! {
            _ = tokio::time::sleep(cfg.duration) => {}
            _ = &mut stop => tracing::info!("told to stop: the edits end early"),
        }
        hostiles
    };
    // A stop after the edits is not listened for (the binary then exits).
    drop(stop);
    let edit_time = edit_start.elapsed();
    let hostile_summary = match hostiles {
        Some(h) => Some(h.finish().await),
        None => None,
    };

    fleet.phase.send_replace(Phase::Quiesce);
    fleet.touch();
    let quiet_start = Instant::now();
    let quiet = loop {
        if fleet.in_flight.load(Ordering::Relaxed) == 0 && fleet.quiet_for() >= QUIET_PERIOD {
            break true;
        }
        if quiet_start.elapsed() > QUIET_TIMEOUT {
            break false;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    };

    fleet.phase.send_replace(Phase::Verify);
    let verify_start = Instant::now();
    while fleet.finished.load(Ordering::Relaxed) < cfg.bots
        && verify_start.elapsed() < cfg.verify_timeout + VERIFY_GRACE
    {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    fleet.phase.send_replace(Phase::Done);
    let timings = (
        quiet_start.elapsed() - verify_start.elapsed(),
        verify_start.elapsed(),
    );
    let mut outcomes = Vec::with_capacity(bots.len());
    let mut failed = 0;
    for b in bots {
        match b.await {
            Ok(o) => outcomes.push(o),
            Err(e) => {
                // Its replica and counters are gone: the run cannot vouch
                // for it, so it counts (and the run is not consistent).
                failed += 1;
                tracing::error!(error = %e, "a bot task failed");
            }
        }
    }
    if let Some((bar, task)) = progress {
        task.abort();
        bar.finish_and_clear();
    }
    let mut summary = summarize(&fleet, &outcomes, edit_time, quiet);
    summary.bots_failed = failed;
    summary.ramp_s = ramp.as_secs_f64();
    summary.ready_at_start = ready_at_start;
    summary.quiet_wait_s = timings.0.as_secs_f64();
    summary.verify_s = timings.1.as_secs_f64();
    summary.hostile = hostile_summary;
    Ok(summary)
}

fn summarize(fleet: &Fleet, outcomes: &[BotOutcome], edit_time: Duration, quiet: bool) -> Summary {
    let s = &fleet.stats;
    let mut sum = Summary {
        bots: fleet.cfg.bots,
        profile: fleet.cfg.profile.name().to_string(),
        duration_s: fleet.cfg.duration.as_secs_f64(),
        stalled: fleet.cfg.stalled,
        reconnects: Stats::get(&s.reconnects),
        edits_sent: Stats::get(&s.edits_sent),
        edits_accepted: Stats::get(&s.edits_accepted),
        edits_rejected: s.rejected(),
        edits_unanswered: Stats::get(&s.edits_unanswered),
        edits_skipped: Stats::get(&s.edits_skipped),
        edit_slots_skipped: Stats::get(&s.edit_slots_skipped),
        region_crossings: Stats::get(&s.region_crossings),
        handoffs: Stats::get(&s.handoffs),
        positions_refused: s.positions_refused(),
        ack_latency_ms: s.ack.summary(),
        broadcast_latency_ms: s.broadcast.summary(),
        latency_by_second: summary::timeline(&s.ack, &s.broadcast),
        quiet,
        prediction: fleet.cfg.predict.then(PredictionStats::default),
        ..Default::default()
    };
    sum.edits_accepted_per_second = sum.edits_accepted as f64 / edit_time.as_secs_f64().max(1e-3);
    let acked = fleet.acked.lock().expect("not poisoned");
    let mut seen: HashMap<(ChunkPos, u64), u64> = HashMap::new();
    let mut delta_bytes = 0;
    for o in outcomes {
        sum.connected_at_end += o.connected_at_end as usize;
        sum.bytes_in += o.bytes_in;
        sum.bytes_out += o.bytes_out;
        let r = &o.replica;
        sum.deltas += r.deltas;
        delta_bytes += r.delta_payload_bytes;
        sum.snapshots += r.snapshots;
        sum.patched += r.patched;
        sum.resyncs += r.gaps + r.hash_mismatches + r.op_gaps + r.op_mismatches;
        sum.generated += r.generated;
        sum.op_chunks += r.op_chunks;
        sum.op_mismatches += r.op_mismatches;
        sum.meshes_checked += r.meshes_checked;
        sum.mesh_mismatches += r.mesh_mismatches;
        sum.order_violations += o.order_violations;
        if let Some(p) = sum.prediction.as_mut() {
            p.add(&o.prediction);
        }
        for (k, h) in &o.version_hashes {
            if *seen.entry(*k).or_insert(*h) != *h {
                sum.order_violations += 1;
            }
        }
        if o.stalled || fleet.cfg.verify == VerifyMode::Off {
            continue;
        }
        sum.chunks_verified += r.checks_ok + r.checks_failed;
        sum.replica_mismatches += r.checks_failed;
        sum.chunks_unverified += o.unverified;
        for (pos, v) in &o.final_versions {
            if acked.get(pos).is_some_and(|a| a > v) {
                sum.ack_missing += 1;
            }
        }
    }
    sum.mean_delta_bytes = delta_bytes as f64 / sum.deltas.max(1) as f64;
    sum
}
