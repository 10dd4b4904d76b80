//! The web console: a live view of the running world for operators, on an
//! HTTP listener of its own (`[console] listen`, off by default).
//!
//! Every request but the page and its assets needs an admin-role bearer
//! token (`auth.rs`). The console only reads what the server already
//! keeps: the store (tiles, 3-D scenes and the edit log, off the engine
//! thread), the metrics registry (charts) and, while someone watches, the
//! engine's player list once per sample. Admin actions go through the
//! admin protocol's own request handler (`actions.rs`).
//!
//! Nothing here runs inside a tick: with no console connected the hub task
//! sleeps and the engine is never asked anything (`events.rs`).

mod actions;
mod assets;
mod auth;
mod conn_limit;
pub use conn_limit::{ConnMark, ConnState, Deadlines, LimitedListener};
mod events;
mod live_world;
mod query;
mod regions;
pub use regions::DEFAULT_REGIONS_PER_REQUEST;
mod routes;
mod scene;
mod snapshot_job;
mod stats;
mod tiles;
mod versions;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use metrics_exporter_prometheus::PrometheusHandle;
use serde::{Deserialize, Serialize};
use strata_terrain::gen::Generator;

use crate::net::session::SessionContext;
use crate::store::ChunkStore;

/// Default watchers (live event streams) at once.
pub const DEFAULT_MAX_WATCHERS: usize = 8;
/// Default HTTP connections at once.
pub const DEFAULT_MAX_CONNECTIONS: usize = 64;
/// Default milliseconds a connection may stay silent both ways.
pub const DEFAULT_IDLE_TIMEOUT_MS: u64 = 60_000;
/// Shortest idle timeout (event streams send a keep-alive every half of it).
pub const MIN_IDLE_TIMEOUT_MS: u64 = 1_000;
/// Longest pause between an event stream's keep-alive comments.
pub const MAX_KEEP_ALIVE: std::time::Duration = std::time::Duration::from_secs(15);
pub const MAX_IDLE_TIMEOUT_MS: u64 = 3_600_000;
/// Default time from a request's first byte to its answer's first byte.
/// A client that trickles a request (a byte now and then, never idle) is
/// closed after this, so it cannot hold a connection slot.
pub const DEFAULT_REQUEST_TIMEOUT_MS: u64 = 30_000;
/// Longest a console connection may stay silent before a request on it
/// passed the token check (then `idle_timeout_ms` holds). When every
/// connection slot is taken, a new connection also closes the oldest
/// such one (`conn_limit.rs`).
pub const UNADMITTED_IDLE: std::time::Duration = std::time::Duration::from_secs(5);
/// Range of `request_timeout_ms`.
pub const MIN_REQUEST_TIMEOUT_MS: u64 = 100;
pub const MAX_REQUEST_TIMEOUT_MS: u64 = 600_000;
/// Default map tiles kept rendered.
pub const DEFAULT_TILE_CACHE: usize = 1024;
/// Default largest request body (admin actions are small JSON).
pub const DEFAULT_MAX_BODY_BYTES: usize = 4096;
/// Default tile or scene renders at once.
pub const DEFAULT_MAX_RENDERS: usize = 2;
/// Default threads the console renders on (`[console] render_threads`).
pub const DEFAULT_RENDER_THREADS: usize = 1;
/// Fewest chunks a 3-D view cap may allow: one chunk with its border.
pub const MIN_SCENE_CHUNKS: u64 = 27;
/// Default chunks one 3-D view may read: an 8 x 8 x 8 box with its
/// one-chunk border.
pub const DEFAULT_SCENE_MAX_CHUNKS: u64 = 1000;
/// Default milliseconds between samples sent to watchers.
pub const DEFAULT_SAMPLE_MS: u64 = 500;
/// Default edits one sample reports at most (the rest are counted).
pub const DEFAULT_EDITS_PER_SAMPLE: usize = 256;
/// Default chunk columns one sample names as changed at most; past it the
/// sample names none and says `"lagged": true` (the page redraws every
/// tile), as after a missed sample.
pub const DEFAULT_COLUMNS_PER_SAMPLE: usize = 4096;
/// Default console snapshots kept in `snapshot_dir` (older ones are
/// removed once a new one is written).
pub const DEFAULT_KEEP_SNAPSHOTS: usize = 8;
/// Caps on the limits above.
pub const MAX_CONSOLE_LIMIT: usize = 65_536;
pub const MAX_SCENE_CHUNKS: u64 = 16_384;
pub const MIN_SAMPLE_MS: u64 = 100;
pub const MAX_SAMPLE_MS: u64 = 60_000;
/// Default samples buffered per watcher before a slow one misses some
/// (`[console] event_queue`; 16 are 8 s at the default period, and older
/// samples are stale anyway).
pub const DEFAULT_EVENT_QUEUE: usize = 16;
/// Largest `[console] event_queue`.
pub const MAX_EVENT_QUEUE: usize = 1024;
/// Chunk columns along a map tile's side (128 voxels, one pixel each).
pub const TILE_COLUMNS: i32 = 4;
/// Largest tile coordinate asked for (keeps voxel coordinates in i32).
pub const MAX_TILE_COORD: i32 = 1 << 20;
/// Voxels between height contours on the map tiles.
pub const TILE_CONTOUR_INTERVAL: u32 = 8;

/// `[console]` in the config.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ConsoleConfig {
    /// TCP address of the console; absent means no console.
    pub listen: Option<SocketAddr>,
    /// Live event streams at once; more are answered 503.
    pub max_watchers: usize,
    /// HTTP connections at once; more wait to be accepted.
    pub max_connections: usize,
    /// Milliseconds a connection may stay silent both ways before it is
    /// closed (an open event stream is never silent: it gets a keep-alive
    /// every half of this at least). Keep it above the longest render.
    pub idle_timeout_ms: u64,
    /// Milliseconds from a request's first byte to the first byte of its
    /// answer; a connection still sending or waiting past this is closed
    /// (a trickled request cannot hold a slot). Keep it above the longest
    /// render.
    pub request_timeout_ms: u64,
    /// Map tiles kept rendered (oldest dropped first).
    pub tile_cache: usize,
    /// Largest request body in bytes; larger ones are answered 413.
    pub max_body_bytes: usize,
    /// Tile and 3-D scene renders at once; more are answered 503.
    pub max_renders: usize,
    /// Threads the renders run on, a pool of the console's own (named
    /// `strata-render-N`): a render's parallel work never takes the cores
    /// of every thread the engine ticks on.
    pub render_threads: usize,
    /// Chunks one 3-D scene request may read: the box it meshes with the
    /// one-chunk border around it its meshes need.
    pub scene_max_chunks: u64,
    /// Milliseconds between samples (players, edits, charts) to watchers.
    pub sample_ms: u64,
    /// Edits one sample lists at most.
    pub edits_per_sample: usize,
    /// Samples buffered for each watcher; a watcher further behind misses
    /// samples (and is told so).
    pub event_queue: usize,
    /// Regions one `/api/regions` request may ask about.
    pub regions_per_request: usize,
    /// Changed chunk columns one sample names at most (see
    /// [`DEFAULT_COLUMNS_PER_SAMPLE`]).
    pub columns_per_sample: usize,
    /// Where snapshots started from the console are written (default:
    /// `snapshots/` in the data dir).
    pub snapshot_dir: Option<PathBuf>,
    /// Console snapshots kept there: once one is written, the oldest
    /// beyond this many are removed, so repeated snapshots cannot fill
    /// the disk.
    pub keep_snapshots: usize,
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        Self {
            listen: None,
            max_watchers: DEFAULT_MAX_WATCHERS,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            idle_timeout_ms: DEFAULT_IDLE_TIMEOUT_MS,
            request_timeout_ms: DEFAULT_REQUEST_TIMEOUT_MS,
            tile_cache: DEFAULT_TILE_CACHE,
            max_body_bytes: DEFAULT_MAX_BODY_BYTES,
            max_renders: DEFAULT_MAX_RENDERS,
            render_threads: DEFAULT_RENDER_THREADS,
            scene_max_chunks: DEFAULT_SCENE_MAX_CHUNKS,
            sample_ms: DEFAULT_SAMPLE_MS,
            edits_per_sample: DEFAULT_EDITS_PER_SAMPLE,
            event_queue: DEFAULT_EVENT_QUEUE,
            regions_per_request: DEFAULT_REGIONS_PER_REQUEST,
            columns_per_sample: DEFAULT_COLUMNS_PER_SAMPLE,
            snapshot_dir: None,
            keep_snapshots: DEFAULT_KEEP_SNAPSHOTS,
        }
    }
}

impl ConsoleConfig {
    /// How often an event stream sends a keep-alive comment.
    pub fn keep_alive(&self) -> std::time::Duration {
        MAX_KEEP_ALIVE.min(std::time::Duration::from_millis(self.idle_timeout_ms / 2))
    }

    /// Range checks: `(field, value, min, max)` for each limit.
    pub fn limits(&self) -> [(&'static str, u64, u64, u64); 15] {
        let cap = MAX_CONSOLE_LIMIT as u64;
        [
            ("console.max_watchers", self.max_watchers as u64, 1, cap),
            (
                "console.max_connections",
                self.max_connections as u64,
                1,
                cap,
            ),
            ("console.tile_cache", self.tile_cache as u64, 1, cap),
            (
                "console.max_body_bytes",
                self.max_body_bytes as u64,
                256,
                1 << 20,
            ),
            ("console.max_renders", self.max_renders as u64, 1, 64),
            ("console.render_threads", self.render_threads as u64, 1, 64),
            (
                "console.event_queue",
                self.event_queue as u64,
                1,
                MAX_EVENT_QUEUE as u64,
            ),
            (
                "console.regions_per_request",
                self.regions_per_request as u64,
                1,
                cap,
            ),
            (
                "console.keep_snapshots",
                self.keep_snapshots as u64,
                1,
                1_000,
            ),
            (
                "console.scene_max_chunks",
                self.scene_max_chunks,
                MIN_SCENE_CHUNKS,
                MAX_SCENE_CHUNKS,
            ),
            (
                "console.sample_ms",
                self.sample_ms,
                MIN_SAMPLE_MS,
                MAX_SAMPLE_MS,
            ),
            (
                "console.idle_timeout_ms",
                self.idle_timeout_ms,
                MIN_IDLE_TIMEOUT_MS,
                MAX_IDLE_TIMEOUT_MS,
            ),
            (
                "console.request_timeout_ms",
                self.request_timeout_ms,
                MIN_REQUEST_TIMEOUT_MS,
                MAX_REQUEST_TIMEOUT_MS,
            ),
            (
                "console.edits_per_sample",
                self.edits_per_sample as u64,
                1,
                cap,
            ),
            (
                "console.columns_per_sample",
                self.columns_per_sample as u64,
                1,
                cap,
            ),
        ]
    }
}

/// What the console reads and acts through, shared by every request.
pub struct Console {
    cfg: ConsoleConfig,
    ctx: Arc<SessionContext>,
    world: live_world::LiveWorld,
    metrics: PrometheusHandle,
    tiles: tiles::TileCache,
    versions: versions::VersionIndex,
    hub: events::Hub,
    renders: Arc<tokio::sync::Semaphore>,
    /// Where renders run (`render_threads`).
    render_pool: Arc<rayon::ThreadPool>,
    /// Held by the tile request whose work catches the version index up:
    /// one at a time, the others wait here, not on a blocking thread.
    catch_ups: Arc<tokio::sync::Mutex<()>>,
    snapshots: snapshot_job::SnapshotJobs,
    /// `[sequencer] region_chunks`.
    region_chunks: u32,
    /// `[cluster] node_id`, on a cluster node.
    node_id: Option<String>,
}

impl std::fmt::Debug for Console {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Console")
            .field("cfg", &self.cfg)
            .finish_non_exhaustive()
    }
}

/// What a running server hands the console.
#[derive(Debug)]
pub struct ConsoleParts {
    pub ctx: Arc<SessionContext>,
    pub store: Arc<dyn ChunkStore>,
    pub generator: Arc<Generator>,
    pub metrics: PrometheusHandle,
    pub data_dir: PathBuf,
    /// `[sequencer] region_chunks`: the map's region overlay.
    pub region_chunks: u32,
    /// `[cluster] node_id`, on a cluster node.
    pub node_id: Option<String>,
}

/// A console that is serving; dropping it does not stop it, [`Self::stop`] does.
#[derive(Debug)]
pub struct RunningConsole {
    pub addr: SocketAddr,
    server: tokio::task::JoinHandle<()>,
    hub: tokio::task::JoinHandle<()>,
    console: Arc<Console>,
}

impl RunningConsole {
    /// Stops serving and ends every event stream (their connections'
    /// tasks outlive the listener's: closing the queues ends them).
    pub fn stop(self) {
        self.server.abort();
        self.hub.abort();
        self.console.hub.close();
    }
}

/// Binds `[console] listen` (failing early if taken) and starts serving.
pub async fn start(cfg: ConsoleConfig, parts: ConsoleParts) -> anyhow::Result<RunningConsole> {
    let Some(listen) = cfg.listen else {
        anyhow::bail!("the console has no listen address");
    };
    let listener = tokio::net::TcpListener::bind(listen).await?;
    let addr = listener.local_addr()?;
    let snapshot_dir = cfg
        .snapshot_dir
        .clone()
        .unwrap_or_else(|| parts.data_dir.join("snapshots"));
    let console = Arc::new(Console {
        world: live_world::LiveWorld::new(parts.store.clone(), parts.generator),
        tiles: tiles::TileCache::new(cfg.tile_cache),
        versions: versions::VersionIndex::default(),
        hub: events::Hub::new(),
        renders: Arc::new(tokio::sync::Semaphore::new(cfg.max_renders)),
        render_pool: Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(cfg.render_threads)
                .thread_name(|i| format!("strata-render-{i}"))
                .build()?,
        ),
        catch_ups: Arc::new(tokio::sync::Mutex::new(())),
        snapshots: snapshot_job::SnapshotJobs::new(snapshot_dir, cfg.keep_snapshots),
        metrics: parts.metrics,
        ctx: parts.ctx,
        region_chunks: parts.region_chunks,
        node_id: parts.node_id,
        cfg,
    });
    let hub = tokio::spawn(events::run_hub(console.clone()));
    let limited = conn_limit::LimitedListener::new(
        listener,
        console.cfg.max_connections,
        conn_limit::Deadlines {
            idle: std::time::Duration::from_millis(console.cfg.idle_timeout_ms),
            request: std::time::Duration::from_millis(console.cfg.request_timeout_ms),
            unadmitted: Some(UNADMITTED_IDLE),
        },
    );
    let app = routes::router(console.clone())
        .into_make_service_with_connect_info::<conn_limit::ConnMark>();
    let server = tokio::spawn(async move {
        if let Err(e) = axum::serve(limited, app).await {
            tracing::error!(error = %e, "console listener failed");
        }
    });
    tracing::info!(%addr, "console listening");
    if !addr.ip().is_loopback() {
        // Plain HTTP: admin tokens cross the network readable.
        tracing::warn!(
            %addr,
            "the console listens beyond this machine over plain HTTP: admin tokens can be read on the way; bind it to 127.0.0.1 behind a TLS proxy (OPERATIONS.md)"
        );
    }
    Ok(RunningConsole {
        addr,
        server,
        hub,
        console,
    })
}
