//! Server configuration: a TOML file where every field is optional.
//!
//! With no file at all the defaults run a local server, so `strata-server`
//! needs no arguments. `deploy/strata.toml` lists every option with its
//! default. An unknown key or section anywhere is an error naming it and its
//! line, so a typo cannot silently fall back to a default. Values are
//! range-checked by [`ServerConfig::validate`], whose errors name the
//! offending field.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

use rustls::pki_types::ServerName;
use serde::{Deserialize, Serialize};
use strata_protocol::limits::{FRAME_HEADER, MAX_CLIENT_FRAME, MAX_DATAGRAM, MAX_SERVER_FRAME};
use thiserror::Error;

use crate::auth::{HumanDuration, MAX_TOKEN_TTL};
use crate::engine::{
    EngineConfig, MAX_COMMAND_QUEUE, MAX_PREMESH_RADIUS, MAX_PREMESH_THREADS, MAX_TICK_MS,
    MIN_RESIDENT_CHUNKS,
};
use crate::heightmap::HeightmapSection;
use crate::interest::{InterestConfig, MAX_HYSTERESIS, MAX_VIEW_RADIUS};
use crate::sequencer::SequencerConfig;
use crate::store::{
    StoreConfig, MAX_FLUSH_EVERY_MS, MAX_SEGMENT_SIZE_BYTES, MIN_CACHE_CAPACITY_BYTES,
    MIN_SEGMENT_SIZE_BYTES,
};
use crate::validate::ValidationConfig;
use strata_terrain::gen::GenParams;

/// Default QUIC listen address: loopback only, so a fresh server is private.
pub const DEFAULT_LISTEN: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 4433);
/// Default data directory, relative to the working directory.
pub const DEFAULT_DATA_DIR: &str = "strata-data";
/// Default and cap of authenticated player sessions at once (and the cap
/// of every other connection limit).
pub const DEFAULT_MAX_CONNECTIONS: u32 = 256;
pub const MAX_CONNECTIONS_CAP: u32 = 65_536;
/// Default admin sessions at once, kept apart from the players'.
pub const DEFAULT_MAX_ADMIN_CONNECTIONS: u32 = 8;
/// Default connections in their handshake (TLS and Hello) at once.
pub const DEFAULT_MAX_HANDSHAKES: u32 = 128;
/// Default handshakes in progress from one IP address.
pub const DEFAULT_MAX_HANDSHAKES_PER_ADDRESS: u32 = 16;
/// Default handshakes in progress from which a connection from an address
/// QUIC has not validated is first sent a Retry.
pub const DEFAULT_RETRY_ABOVE_HANDSHAKES: u32 = 32;
/// Default time from a connection's first packet to its verified Hello.
pub const DEFAULT_HANDSHAKE_TIMEOUT_MS: u64 = 5_000;
/// Longest allowed handshake time.
pub const MAX_HANDSHAKE_TIMEOUT_MS: u64 = 60_000;
/// Most `[server] net_threads`.
pub const MAX_NET_THREADS: usize = 256;

/// Cap on `tls.extra_names`.
pub const MAX_EXTRA_NAMES: usize = 32;
/// GSO is on by default (quinn's default); some virtual NICs reject it.
pub const DEFAULT_SEGMENTATION_OFFLOAD: bool = true;

/// Per-stream receive window: deliberately low, a client only sends small
/// control frames, and it bounds per-connection buffered input.
pub const DEFAULT_STREAM_RECEIVE_WINDOW: u32 = 256 * 1024;
/// Whole-connection receive window.
pub const DEFAULT_CONNECTION_RECEIVE_WINDOW: u32 = 1024 * 1024;
/// Smallest stream window: one maximal client frame must fit.
pub const MIN_STREAM_RECEIVE_WINDOW: u32 = (MAX_CLIENT_FRAME + FRAME_HEADER) as u32;
/// Cap on either receive window.
pub const MAX_RECEIVE_WINDOW: u32 = 64 * 1024 * 1024;
/// Unacknowledged bytes the server may have in flight per connection.
pub const DEFAULT_SEND_WINDOW: u64 = 4 * 1024 * 1024;
/// Smallest send window: one maximal server frame must fit.
pub const MIN_SEND_WINDOW: u64 = (MAX_SERVER_FRAME + FRAME_HEADER) as u64;
pub const MAX_SEND_WINDOW: u64 = 256 * 1024 * 1024;
/// Client-initiated unidirectional streams allowed at once. The protocol
/// uses none, and the server never reads one: each a client opened would
/// hold unread data up to the connection's receive window.
pub const DEFAULT_MAX_UNI_STREAMS: u32 = 0;
pub const MAX_UNI_STREAMS_CAP: u32 = 64;
/// Client-initiated bidirectional streams: exactly the control stream.
/// A protocol fact, hence not configurable.
pub const CONTROL_BIDI_STREAMS: u32 = 1;
pub const DEFAULT_IDLE_TIMEOUT_MS: u64 = 30_000;
pub const MIN_IDLE_TIMEOUT_MS: u64 = 1_000;
pub const MAX_IDLE_TIMEOUT_MS: u64 = 600_000;
pub const DEFAULT_KEEP_ALIVE_MS: u64 = 5_000;
pub const MIN_KEEP_ALIVE_MS: u64 = 100;
/// Incoming datagram bytes buffered per connection before drops.
pub const DEFAULT_DATAGRAM_RECEIVE_BUFFER: usize = 64 * 1024;
/// Outgoing datagram bytes buffered per connection before the oldest drop.
pub const DEFAULT_DATAGRAM_SEND_BUFFER: usize = 256 * 1024;
pub const MAX_DATAGRAM_BUFFER: usize = 16 * 1024 * 1024;
/// Frames queued per connection writer before the session is dropped as
/// too slow.
pub const DEFAULT_WRITER_QUEUE: usize = 256;
pub const MAX_WRITER_QUEUE: usize = 65_536;
/// Bytes a connection's writer may hold queued (each stream's; frames
/// taken and not yet written count): a client that stops reading pins at
/// most this much besides QUIC's send window, however large the frames.
/// 32 streamed batches of the default send budget.
pub const DEFAULT_WRITER_QUEUE_BYTES: usize = 8 * 1024 * 1024;
/// Bounds of `[net] writer_queue_bytes`.
pub const MIN_WRITER_QUEUE_BYTES: usize = 64 * 1024;
pub const MAX_WRITER_QUEUE_BYTES: usize = 1 << 30;
/// Frames queued on a connection's control stream (acknowledgements,
/// refusals, replies) before the session is dropped as not reading them.
pub const DEFAULT_CONTROL_WRITER_QUEUE: usize = 1024;
/// Bytes of world data sent per connection per tick.
pub const DEFAULT_SEND_BUDGET_BYTES_PER_TICK: usize = 256 * 1024;
pub const MIN_SEND_BUDGET_BYTES_PER_TICK: usize = 1024;
pub const MAX_SEND_BUDGET_BYTES_PER_TICK: usize = 64 * 1024 * 1024;

/// Longest ACK delay the server asks clients for (ACK_FREQUENCY); 0 asks
/// nothing and clients keep QUIC's 25 ms. quinn never asks for more than
/// the connection's RTT (or 25 ms, whichever is more).
pub const DEFAULT_ACK_DELAY_MAX_MS: u64 = 0;
pub const MAX_ACK_DELAY_MAX_MS: u64 = 1_000;
/// Ack-eliciting packets a client may take in before it must acknowledge
/// (QUIC's own behaviour is 1: every second packet). Sent only with
/// `ack_delay_max_ms`.
pub const DEFAULT_ACK_ELICITING_THRESHOLD: u32 = 1;
pub const MAX_ACK_ELICITING_THRESHOLD: u32 = 64;

/// Shortest time between two writes of one session's updates; 0 sends
/// each tick's updates at once.
pub const DEFAULT_SEND_INTERVAL_MS: u64 = 0;
pub const MAX_SEND_INTERVAL_MS: u64 = 1_000;

/// Longest lifetime `strata-admin token issue` may grant by default.
pub const DEFAULT_TOKEN_MAX_TTL: Duration = Duration::from_secs(30 * 24 * 3600);

/// Why a configuration could not be loaded.
#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Bad TOML, a wrong type, or an unknown key or section; `line` is
    /// 1-based, `None` when the error has no position.
    #[error("cannot parse config {}: {message}", location(.path, .line))]
    Parse {
        path: PathBuf,
        line: Option<usize>,
        message: String,
    },
    #[error("config field `{field}` is invalid: {reason}")]
    Invalid { field: &'static str, reason: String },
}

/// The whole server configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServerConfig {
    pub server: ServerSection,
    pub tls: TlsSection,
    pub net: NetSection,
    pub auth: AuthSection,
    pub metrics: MetricsSection,
    pub console: crate::console::ConsoleConfig,
    pub world: WorldSection,
    pub sequencer: SequencerConfig,
    pub validation: ValidationConfig,
    pub interest: InterestConfig,
    pub engine: EngineConfig,
    pub store: StoreConfig,
    /// Present: this node is one of a cluster on PostgreSQL (leases and
    /// fenced commits). Absent: a single node.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cluster: Option<crate::cluster::ClusterConfig>,
}

/// `[server]`: where to listen and keep data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServerSection {
    /// UDP address for QUIC.
    pub listen: SocketAddr,
    /// World database, certificate and auth secret live here.
    pub data_dir: PathBuf,
    /// Authenticated player sessions at once; more are refused
    /// (`TooManyConnections`, "server is full").
    pub max_connections: u32,
    /// Authenticated admin sessions at once, beside the players' (so
    /// operators always get in).
    pub max_admin_connections: u32,
    /// Connections in their handshake (TLS, then a Hello with a valid
    /// token) at once; more are refused before TLS.
    pub max_handshakes: u32,
    /// Handshakes in progress from one IP address at once (an IPv6 /64
    /// counts as one address).
    pub max_handshakes_per_address: u32,
    /// From this many handshakes in progress on, a connection whose source
    /// address QUIC has not validated gets a Retry first and takes no slot
    /// until it comes back with the token: spoofed sources never do, so
    /// they cannot fill the handshake slots. 0: always.
    pub retry_above_handshakes: u32,
    /// Milliseconds from a connection's first packet to its verified Hello.
    pub handshake_timeout_ms: u64,
    /// Threads of the async runtime that runs QUIC, the sessions and the
    /// metrics and console servers; 0 means one per available core
    /// (tokio's default, or `TOKIO_WORKER_THREADS`). Read by the
    /// `strata-server` binary when it starts.
    pub net_threads: usize,
}

impl ServerSection {
    /// The runtime's worker threads, if set (`None`: tokio's default).
    pub fn net_threads(&self) -> Option<usize> {
        (self.net_threads > 0).then_some(self.net_threads)
    }

    /// The connection limits for [`crate::net::admission`].
    /// `sessions_per_player` is `[engine]`'s.
    pub fn admission(&self, sessions_per_player: usize) -> crate::net::admission::Limits {
        crate::net::admission::Limits {
            sessions: self.max_connections,
            admin_sessions: self.max_admin_connections,
            sessions_per_player,
            handshakes: self.max_handshakes,
            handshakes_per_address: self.max_handshakes_per_address,
            retry_above: self.retry_above_handshakes,
            handshake_timeout: std::time::Duration::from_millis(self.handshake_timeout_ms),
            evictable_after: std::time::Duration::from_millis(self.handshake_timeout_ms / 2),
        }
    }
}

/// `[tls]`: the self-signed certificate and UDP offload.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TlsSection {
    /// DNS names or IPs added to the certificate's subject alternative names
    /// (localhost, 127.0.0.1 and ::1 are always present). Only used when the
    /// certificate is generated, on the first start (to re-issue it, see
    /// "Certificates" in deploy/OPERATIONS.md).
    pub extra_names: Vec<String>,
    /// Generic segmentation offload for UDP sends; turn off if sends fail on
    /// a virtual NIC.
    pub enable_segmentation_offload: bool,
}

/// `[net]`: QUIC transport limits and per-connection send queues.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetSection {
    pub stream_receive_window: u32,
    pub connection_receive_window: u32,
    pub send_window: u64,
    pub max_uni_streams: u32,
    pub idle_timeout_ms: u64,
    pub keep_alive_ms: u64,
    pub datagram_receive_buffer: usize,
    pub datagram_send_buffer: usize,
    pub writer_queue: usize,
    /// See [`DEFAULT_WRITER_QUEUE_BYTES`].
    pub writer_queue_bytes: usize,
    /// See [`DEFAULT_CONTROL_WRITER_QUEUE`].
    pub control_writer_queue: usize,
    pub send_budget_bytes_per_tick: usize,
    /// Ask clients to acknowledge at most this late (ms; 0: ask nothing).
    pub ack_delay_max_ms: u64,
    /// With `ack_delay_max_ms`: packets a client may take in unacknowledged.
    pub ack_eliciting_threshold: u32,
    /// Shortest time between two writes of one session's updates (ms; 0:
    /// each tick's updates leave at once).
    pub send_interval_ms: u64,
}

/// `[auth]`: token policy.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AuthSection {
    /// Longest `--ttl` that `strata-admin token issue` accepts ("30d").
    pub token_max_ttl: HumanDuration,
}

/// `[metrics]`: optional Prometheus endpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MetricsSection {
    /// TCP address for `/metrics`; absent means no endpoint.
    pub listen: Option<SocketAddr>,
    /// Connections the endpoint holds at once; more wait to be accepted
    /// ([`crate::metrics::DEFAULT_MAX_CONNECTIONS`]).
    pub max_connections: usize,
}

impl Default for MetricsSection {
    fn default() -> Self {
        Self {
            listen: None,
            max_connections: crate::metrics::DEFAULT_MAX_CONNECTIONS,
        }
    }
}

/// `[world]`: which world to serve. `[world.generator]` holds every
/// generation parameter (seed, vertical bounds, hills, caves, layers); the
/// world's vertical bounds for edits are the generator's `min_y..=max_y`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WorldSection {
    /// Directory of structure templates (`<id>.strs` / `<id>-<name>.strs`).
    pub structures_dir: Option<PathBuf>,
    pub generator: GenParams,
    /// A height image instead of the fractal hills.
    pub heightmap: Option<HeightmapSection>,
}

impl Default for ServerSection {
    fn default() -> Self {
        ServerSection {
            listen: DEFAULT_LISTEN,
            data_dir: PathBuf::from(DEFAULT_DATA_DIR),
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_admin_connections: DEFAULT_MAX_ADMIN_CONNECTIONS,
            max_handshakes: DEFAULT_MAX_HANDSHAKES,
            max_handshakes_per_address: DEFAULT_MAX_HANDSHAKES_PER_ADDRESS,
            retry_above_handshakes: DEFAULT_RETRY_ABOVE_HANDSHAKES,
            handshake_timeout_ms: DEFAULT_HANDSHAKE_TIMEOUT_MS,
            net_threads: 0,
        }
    }
}

impl Default for TlsSection {
    fn default() -> Self {
        TlsSection {
            extra_names: Vec::new(),
            enable_segmentation_offload: DEFAULT_SEGMENTATION_OFFLOAD,
        }
    }
}

impl Default for NetSection {
    fn default() -> Self {
        NetSection {
            stream_receive_window: DEFAULT_STREAM_RECEIVE_WINDOW,
            connection_receive_window: DEFAULT_CONNECTION_RECEIVE_WINDOW,
            send_window: DEFAULT_SEND_WINDOW,
            max_uni_streams: DEFAULT_MAX_UNI_STREAMS,
            idle_timeout_ms: DEFAULT_IDLE_TIMEOUT_MS,
            keep_alive_ms: DEFAULT_KEEP_ALIVE_MS,
            datagram_receive_buffer: DEFAULT_DATAGRAM_RECEIVE_BUFFER,
            datagram_send_buffer: DEFAULT_DATAGRAM_SEND_BUFFER,
            writer_queue: DEFAULT_WRITER_QUEUE,
            writer_queue_bytes: DEFAULT_WRITER_QUEUE_BYTES,
            control_writer_queue: DEFAULT_CONTROL_WRITER_QUEUE,
            send_budget_bytes_per_tick: DEFAULT_SEND_BUDGET_BYTES_PER_TICK,
            ack_delay_max_ms: DEFAULT_ACK_DELAY_MAX_MS,
            ack_eliciting_threshold: DEFAULT_ACK_ELICITING_THRESHOLD,
            send_interval_ms: DEFAULT_SEND_INTERVAL_MS,
        }
    }
}

impl NetSection {
    pub fn idle_timeout(&self) -> Duration {
        Duration::from_millis(self.idle_timeout_ms)
    }
    pub fn keep_alive(&self) -> Duration {
        Duration::from_millis(self.keep_alive_ms)
    }
    pub fn send_interval(&self) -> Duration {
        Duration::from_millis(self.send_interval_ms)
    }
    /// The ACK delay to ask clients for; `None`: ask nothing.
    pub fn ack_delay_max(&self) -> Option<Duration> {
        (self.ack_delay_max_ms > 0).then(|| Duration::from_millis(self.ack_delay_max_ms))
    }
}

impl Default for AuthSection {
    fn default() -> Self {
        AuthSection {
            token_max_ttl: HumanDuration(DEFAULT_TOKEN_MAX_TTL),
        }
    }
}

impl ServerConfig {
    /// Loads and validates `path`, or returns the defaults when `path` is
    /// `None`.
    pub fn load(path: Option<&Path>) -> Result<ServerConfig, ConfigError> {
        let Some(path) = path else {
            return Ok(ServerConfig::default());
        };
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_owned(),
            source,
        })?;
        ServerConfig::from_toml_str(&text).map_err(|e| match e {
            ConfigError::Parse { line, message, .. } => ConfigError::Parse {
                path: path.to_owned(),
                line,
                message,
            },
            other => other,
        })
    }

    /// Parses and validates TOML text (errors carry an empty path).
    pub fn from_toml_str(text: &str) -> Result<ServerConfig, ConfigError> {
        let config: ServerConfig = toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: PathBuf::new(),
            line: e.span().map(|s| line_of(text, s.start)),
            message: e.message().to_owned(),
        })?;
        config.validate()?;
        Ok(config)
    }

    /// Command-line flags win over the file.
    pub fn apply_overrides(&mut self, data_dir: Option<PathBuf>, listen: Option<SocketAddr>) {
        if let Some(dir) = data_dir {
            self.server.data_dir = dir;
        }
        if let Some(addr) = listen {
            self.server.listen = addr;
        }
    }

    /// Checks every value's range; the error names the first bad field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let s = &self.server;
        range(
            "server.max_connections",
            s.max_connections,
            1,
            MAX_CONNECTIONS_CAP,
        )?;
        for (field, value) in [
            ("server.max_admin_connections", s.max_admin_connections),
            ("server.max_handshakes", s.max_handshakes),
            (
                "server.max_handshakes_per_address",
                s.max_handshakes_per_address,
            ),
        ] {
            range(field, value, 1, MAX_CONNECTIONS_CAP)?;
        }
        range(
            "server.retry_above_handshakes",
            s.retry_above_handshakes,
            0,
            MAX_CONNECTIONS_CAP,
        )?;
        range(
            "server.handshake_timeout_ms",
            s.handshake_timeout_ms,
            100,
            MAX_HANDSHAKE_TIMEOUT_MS,
        )?;
        range("server.net_threads", s.net_threads, 0, MAX_NET_THREADS)?;
        if s.data_dir.as_os_str().is_empty() {
            return Err(invalid("server.data_dir", "must not be empty"));
        }

        let t = &self.tls;
        if t.extra_names.len() > MAX_EXTRA_NAMES {
            return Err(invalid(
                "tls.extra_names",
                format!("at most {MAX_EXTRA_NAMES} names"),
            ));
        }
        for name in &t.extra_names {
            if ServerName::try_from(name.as_str()).is_err() {
                return Err(invalid(
                    "tls.extra_names",
                    format!("{name:?} is neither a DNS name nor an IP address"),
                ));
            }
        }

        let n = &self.net;
        range(
            "net.stream_receive_window",
            n.stream_receive_window,
            MIN_STREAM_RECEIVE_WINDOW,
            MAX_RECEIVE_WINDOW,
        )?;
        range(
            "net.connection_receive_window",
            n.connection_receive_window,
            n.stream_receive_window,
            MAX_RECEIVE_WINDOW,
        )
        .map_err(|_| {
            invalid(
                "net.connection_receive_window",
                format!(
                    "must be between net.stream_receive_window ({}) and {MAX_RECEIVE_WINDOW}",
                    n.stream_receive_window
                ),
            )
        })?;
        range(
            "net.send_window",
            n.send_window,
            MIN_SEND_WINDOW,
            MAX_SEND_WINDOW,
        )?;
        range(
            "net.max_uni_streams",
            n.max_uni_streams,
            0,
            MAX_UNI_STREAMS_CAP,
        )?;
        range(
            "net.idle_timeout_ms",
            n.idle_timeout_ms,
            MIN_IDLE_TIMEOUT_MS,
            MAX_IDLE_TIMEOUT_MS,
        )?;
        if n.keep_alive_ms < MIN_KEEP_ALIVE_MS || n.keep_alive_ms >= n.idle_timeout_ms {
            return Err(invalid(
                "net.keep_alive_ms",
                format!(
                    "must be at least {MIN_KEEP_ALIVE_MS} and below net.idle_timeout_ms ({})",
                    n.idle_timeout_ms
                ),
            ));
        }
        range(
            "net.datagram_receive_buffer",
            n.datagram_receive_buffer,
            MAX_DATAGRAM,
            MAX_DATAGRAM_BUFFER,
        )?;
        range(
            "net.datagram_send_buffer",
            n.datagram_send_buffer,
            MAX_DATAGRAM,
            MAX_DATAGRAM_BUFFER,
        )?;
        range("net.writer_queue", n.writer_queue, 1, MAX_WRITER_QUEUE)?;
        range(
            "net.writer_queue_bytes",
            n.writer_queue_bytes,
            MIN_WRITER_QUEUE_BYTES,
            MAX_WRITER_QUEUE_BYTES,
        )?;
        range(
            "net.control_writer_queue",
            n.control_writer_queue,
            1,
            MAX_WRITER_QUEUE,
        )?;
        range(
            "net.send_budget_bytes_per_tick",
            n.send_budget_bytes_per_tick,
            MIN_SEND_BUDGET_BYTES_PER_TICK,
            MAX_SEND_BUDGET_BYTES_PER_TICK,
        )?;
        range(
            "net.ack_delay_max_ms",
            n.ack_delay_max_ms,
            0,
            MAX_ACK_DELAY_MAX_MS,
        )?;
        range(
            "net.send_interval_ms",
            n.send_interval_ms,
            0,
            MAX_SEND_INTERVAL_MS,
        )?;
        range(
            "net.ack_eliciting_threshold",
            n.ack_eliciting_threshold,
            0,
            MAX_ACK_ELICITING_THRESHOLD,
        )?;

        if self.auth.token_max_ttl.0 > MAX_TOKEN_TTL {
            return Err(invalid(
                "auth.token_max_ttl",
                format!("must be at most {}", HumanDuration(MAX_TOKEN_TTL)),
            ));
        }

        for (field, value, min, max) in self.console.limits() {
            range(field, value, min, max)?;
        }

        self.world
            .generator
            .validate()
            .map_err(|e| invalid("world.generator", e.to_string()))?;
        range(
            "metrics.max_connections",
            self.metrics.max_connections,
            1,
            crate::metrics::MAX_CONNECTIONS,
        )?;
        let requests = self.validation.request_rate;
        let max = crate::validate::config::MAX_REQUEST_RATE;
        range(
            "validation.request_rate.capacity",
            requests.capacity,
            1,
            max,
        )?;
        range(
            "validation.request_rate.per_second",
            requests.per_second,
            1,
            max,
        )?;
        let positions = self.validation.position_rate;
        range(
            "validation.position_rate.capacity",
            positions.capacity,
            1,
            max,
        )?;
        range(
            "validation.position_rate.per_second",
            positions.per_second,
            1,
            max,
        )?;
        // The player buckets may refill at 0 (only the burst) and be as
        // large as u64 (the bucket saturates), but a capacity of 0 would
        // refuse every edit as rate-limited.
        let v = &self.validation;
        for (field, bucket) in [
            ("validation.edit_rate.capacity", v.edit_rate),
            ("validation.volume_rate.capacity", v.volume_rate),
            ("validation.reject_rate.capacity", v.reject_rate),
            ("validation.placement_rate.capacity", v.placement_rate),
            ("validation.join_rate.capacity", v.join_rate),
        ] {
            range(field, bucket.capacity, 1, u64::MAX)?;
        }
        for (key, weight) in v.volume_weight.fields() {
            range(
                key,
                weight,
                1,
                crate::validate::volume_weight::MAX_VOLUME_WEIGHT,
            )?;
        }
        range(
            "interest.hysteresis",
            self.interest.hysteresis,
            0,
            MAX_HYSTERESIS,
        )?;
        range(
            "interest.view_radius",
            self.interest.view_radius,
            1,
            MAX_VIEW_RADIUS,
        )?;
        range("engine.tick_ms", self.engine.tick_ms, 1, MAX_TICK_MS)?;
        range(
            "engine.stream_us",
            self.engine.stream_us,
            1,
            crate::engine::MAX_STREAM_US,
        )?;
        range(
            "engine.command_queue",
            self.engine.command_queue,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        range(
            "engine.session_commands",
            self.engine.session_commands,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        range(
            "engine.control_queue",
            self.engine.control_queue,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        range(
            "engine.sessions_per_player",
            self.engine.sessions_per_player,
            1,
            MAX_CONNECTIONS_CAP as usize,
        )?;
        range(
            "engine.premesh_radius",
            self.engine.premesh_radius,
            0,
            MAX_PREMESH_RADIUS,
        )?;
        range(
            "engine.premesh_threads",
            self.engine.premesh_threads,
            1,
            MAX_PREMESH_THREADS,
        )?;
        range(
            "engine.premesh_inflight",
            self.engine.premesh_inflight,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        for (name, value) in [
            ("engine.premesh_backlog", self.engine.premesh_backlog),
            (
                "engine.premesh_generated_chunks",
                self.engine.premesh_generated_chunks,
            ),
            ("engine.patch_base_chunks", self.engine.patch_base_chunks),
            (
                "engine.snapshot_cache_entries",
                self.engine.snapshot_cache_entries,
            ),
            (
                "engine.full_frame_cache_entries",
                self.engine.full_frame_cache_entries,
            ),
        ] {
            range(name, value, 1, crate::engine::MAX_ENGINE_CACHE)?;
        }
        range(
            "engine.snapshot_preimages",
            self.engine.snapshot_preimages,
            1,
            crate::engine::snapshot::MAX_SNAPSHOT_PREIMAGES,
        )?;
        let (fewest, most) = crate::engine::snapshot::SNAPSHOT_PREIMAGE_BYTES_RANGE;
        range(
            "engine.snapshot_preimage_bytes",
            self.engine.snapshot_preimage_bytes,
            fewest,
            most,
        )?;
        range(
            "engine.resident_chunks",
            self.engine.resident_chunks,
            MIN_RESIDENT_CHUNKS,
            usize::MAX,
        )?;
        range(
            "store.cache_capacity_bytes",
            self.store.cache_capacity_bytes,
            MIN_CACHE_CAPACITY_BYTES,
            u64::MAX,
        )?;
        range(
            "store.flush_every_ms",
            self.store.flush_every_ms,
            0,
            MAX_FLUSH_EVERY_MS,
        )?;
        range(
            "store.checkpoint_ms",
            self.store.checkpoint_ms,
            0,
            crate::store::MAX_CHECKPOINT_MS,
        )?;
        range(
            "store.checkpoint_chunks",
            self.store.checkpoint_chunks,
            1,
            crate::store::MAX_CHECKPOINT_CHUNKS,
        )?;
        range(
            "store.checkpoint_slice_chunks",
            self.store.checkpoint_slice_chunks,
            1,
            crate::store::MAX_CHECKPOINT_CHUNKS,
        )?;
        range(
            "store.segment_size_bytes",
            self.store.segment_size_bytes,
            MIN_SEGMENT_SIZE_BYTES,
            MAX_SEGMENT_SIZE_BYTES,
        )?;
        if !self.store.segment_size_bytes.is_power_of_two() {
            return Err(invalid(
                "store.segment_size_bytes",
                "must be a power of two",
            ));
        }
        self.validate_postgres()?;
        if let Some(c) = &self.cluster {
            c.check()
                .map_err(|(field, reason)| invalid(field, reason))?;
            if self.store.backend != crate::store::StoreBackend::Postgres {
                return Err(invalid(
                    "cluster.node_id",
                    "a cluster needs [store] backend = \"postgres\"",
                ));
            }
        }
        range(
            "sequencer.queue_capacity",
            self.sequencer.queue_capacity,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        range(
            "sequencer.max_edits_per_tick",
            self.sequencer.max_edits_per_tick,
            1,
            MAX_COMMAND_QUEUE,
        )?;
        range(
            "sequencer.collision_cache_capacity",
            self.sequencer.collision_cache_capacity,
            crate::collision::MIN_COLLISION_CACHE_CAPACITY,
            crate::collision::MAX_COLLISION_CACHE_CAPACITY,
        )?;
        range(
            "sequencer.region_chunks",
            self.sequencer.region_chunks,
            1,
            crate::sequencer::regions::MAX_REGION_CHUNKS,
        )?;
        let v = &self.validation;
        use crate::validate::config as vc;
        for (field, value, max) in [
            ("validation.reach", v.reach, vc::MAX_REACH),
            (
                "validation.los_tolerance",
                v.los_tolerance,
                vc::MAX_LOS_TOLERANCE,
            ),
            ("validation.eye_height", v.eye_height, vc::MAX_EYE_HEIGHT),
            ("validation.max_speed", v.max_speed, vc::MAX_SPEED_LIMIT),
            (
                "validation.speed_slack_factor",
                v.speed_slack_factor,
                vc::MAX_SPEED_SLACK_FACTOR,
            ),
            (
                "validation.speed_slack_voxels",
                v.speed_slack_voxels,
                vc::MAX_SPEED_LIMIT,
            ),
        ] {
            range(field, value, 0.0, max)?;
        }
        range(
            "validation.max_move_ms",
            v.max_move_ms,
            1,
            vc::MAX_MAX_MOVE_MS,
        )?;
        let longest = v.longest_move();
        if longest > crate::validate::position::MAX_SWEPT_MOVE {
            return Err(invalid(
                "validation.max_move_ms",
                format!(
                    "with max_speed, speed_slack_factor and speed_slack_voxels it allows \
                     moves of {longest:.0} voxels, more than the {} a move's path may be",
                    crate::validate::position::MAX_SWEPT_MOVE
                ),
            ));
        }
        let g = &v.gravity;
        use crate::validate::gravity as gr;
        range(
            "validation.gravity.jump_voxels",
            g.jump_voxels,
            0.0,
            gr::MAX_JUMP_VOXELS,
        )?;
        range("validation.gravity.hang_ms", g.hang_ms, 0, gr::MAX_HANG_MS)?;
        range(
            "validation.gravity.fall_voxels_per_s2",
            g.fall_voxels_per_s2,
            gr::FALL_RANGE.0,
            gr::FALL_RANGE.1,
        )?;
        let spawn = &self.validation.spawn;
        let max = crate::validate::spawn::MAX_SPAWN_COORD;
        range("validation.spawn.x", spawn.x, -max, max)?;
        range("validation.spawn.z", spawn.z, -max, max)?;
        range("validation.spawn.radius", spawn.radius, 0, max as u32)?;
        range(
            "engine.workers",
            self.engine.workers,
            0,
            crate::engine::MAX_WORKERS,
        )?;
        Ok(())
    }

    /// `[store.postgres]`: limits always, the connection string only when
    /// it is the backend.
    fn validate_postgres(&self) -> Result<(), ConfigError> {
        use crate::store::pg;
        let p = &self.store.postgres;
        range(
            "store.postgres.max_connections",
            p.max_connections,
            1,
            pg::MAX_PG_MAX_CONNECTIONS,
        )?;
        for (field, ms) in [
            ("store.postgres.connect_timeout_ms", p.connect_timeout_ms),
            ("store.postgres.pool_wait_ms", p.pool_wait_ms),
            (
                "store.postgres.statement_timeout_ms",
                p.statement_timeout_ms,
            ),
        ] {
            range(field, ms, 1, pg::MAX_PG_TIMEOUT_MS)?;
        }
        range(
            "store.postgres.commit_retry_ms",
            p.commit_retry_ms,
            0,
            pg::MAX_PG_TIMEOUT_MS,
        )?;
        if self.store.backend == crate::store::StoreBackend::Postgres {
            p.client_config()
                .map_err(|reason| invalid("store.postgres.url", reason))?;
        }
        Ok(())
    }

    /// The effective configuration as TOML (e.g. for `--print-config`).
    /// Fails only for values TOML cannot hold (a seed above `i64::MAX`).
    pub fn to_toml_string(&self) -> Result<String, toml::ser::Error> {
        toml::to_string(self)
    }
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// `PATH, line N`, leaving out what is unknown.
fn location(path: &Path, line: &Option<usize>) -> String {
    let path = path.display().to_string();
    match line {
        Some(n) if path.is_empty() => format!("line {n}"),
        Some(n) => format!("{path}, line {n}"),
        None => path,
    }
}

fn invalid(field: &'static str, reason: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        field,
        reason: reason.into(),
    }
}

fn range<T: PartialOrd + std::fmt::Display>(
    field: &'static str,
    value: T,
    min: T,
    max: T,
) -> Result<(), ConfigError> {
    // Not `value < min || value > max`: a NaN would pass that.
    if !(value >= min && value <= max) {
        return Err(invalid(field, format!("{value} is outside {min}..={max}")));
    }
    Ok(())
}
