//! `strata-bots`: load-test a Strata server with many real QUIC clients.
//! Argument parsing and printing only; the bots live in
//! `strata_client_sim::bots`.

use std::io::IsTerminal;
use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::Parser;
use strata_client_sim::bots::duration::parse_run_duration;
use strata_client_sim::bots::hostile::{DEFAULT_CONNECTIONS, DEFAULT_REACH, DEFAULT_SESSIONS};
use strata_client_sim::bots::{
    self, Attack, BotsConfig, HostileConfig, Profile, Tokens, VerifyMode,
};
use strata_server::app;
use strata_server::config::ServerConfig;
use strata_server::datadir::DataDir;
use tracing_subscriber::EnvFilter;

/// Load-test a Strata server with many bots, each a real QUIC client.
///
/// Every bot connects, subscribes to the chunks around it, walks (position
/// datagrams), edits by profile and keeps a replica whose meshes it checks
/// against the server's mesh hashes. After `--duration` the bots stop
/// editing, wait until the world is quiet, and compare every replica chunk
/// with the server's copy. A progress bar (stderr, terminals only) shows
/// connected bots, accepted edits per second and the ack p99.
///
/// Bots live in a square area starting at x = z = 512 (away from the
/// protected spawn), 24 × 24 voxels per bot. With `--data-dir` each bot gets
/// its own token (player `bot-<i>`) signed with the server's secret; with
/// `--token` all bots are one player and share its rate limits (the server's
/// `engine.sessions_per_player`, default 1, must then allow `--bots`). The
/// server's `server.max_connections` (default 256) must allow `--bots`
/// sessions, and `server.max_handshakes_per_address` (default 16) limits how
/// many connect at once from this machine (refused ones retry).
///
/// The summary reports edits sent, accepted and rejected by reason, ack and
/// broadcast latency (edit sent → its delta at another bot), bytes in and
/// out, mean delta size, resyncs, replica and mesh mismatches. Ack latency
/// times accepted edits only: beside it are the edits rejected, those never
/// answered, and edit_slots_skipped, the slots that fell due while a bot's
/// last edit still awaited its verdict (no edit was sent for them). The
/// exit code is non-zero if any replica ended different from the server or
/// a bot's task failed (bots_failed).
///
/// SIGTERM during the ramp or the edits ends them early (no edits start
/// after a SIGTERM in the ramp): the bots then wait for quiet, check their
/// replicas and print the summary as at the end of --duration. A SIGTERM
/// after the edits, or a second one, exits 143 at once without a summary.
///
/// `--ack-log FILE` writes one JSON line per accepted edit, as soon as it
/// is acknowledged: {"seq":17,"chunks":[{"x":16,"y":1,"z":16,"version":4}]}
/// (the edit's sequence number and every chunk it changed with its new
/// version). `strata-admin verify-acks --data-dir DIR FILE` then checks the
/// stored world holds all of them.
///
/// `--hostile N --attack KIND` adds N hostile players (tokens `hostile-<i>`,
/// so --data-dir or --spawn-server) that attack through the real protocol
/// while the bots edit, from connections bound to --hostile-bind:
/// position-flood (far-apart position datagrams, --hostile-rate per second),
/// border-flip (position datagrams flipping over a chunk border, as many),
/// rejected-edits (edits always refused, --hostile-rate per second; kicked
/// players reconnect), far-subscribe (subscriptions and full-chunk requests
/// 150+ chunks away), teleport (edit, reconnect thousands of voxels away,
/// edit), handshake-flood (--hostile-connections connections that never
/// say Hello), token-share (--hostile-sessions sessions of one token),
/// subscribe-flood (subscriptions to its own view, the radius flipping,
/// --hostile-rate per second), wall-walk (builds a wall, reports the far
/// side of it and edits where only that side reaches) or fly-over (the
/// same, reporting its way up over the wall first).
/// The summary's "hostile" object holds their counters; every other field
/// counts the honest bots only.
#[derive(Debug, Parser)]
#[command(name = "strata-bots", version, about, verbatim_doc_comment)]
struct Args {
    /// Server address, e.g. 127.0.0.1:4433 (not with --spawn-server).
    #[arg(long, required_unless_present = "spawn_server")]
    server: Option<SocketAddr>,
    /// The server's certificate (DER) to pin; defaults to DIR/cert.der with --data-dir.
    #[arg(long)]
    cert: Option<PathBuf>,
    /// One token for every bot (from `strata-admin token issue`).
    #[arg(long, conflicts_with = "data_dir")]
    token: Option<String>,
    /// The server's data dir: mint a token per bot with its secret.
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Start a server in this process on a temporary data dir.
    #[arg(long, conflicts_with_all = ["server", "cert", "token", "data_dir"])]
    spawn_server: bool,
    /// Number of bots.
    #[arg(long, default_value_t = 10)]
    bots: usize,
    /// How long the bots edit: 500ms, 30s, 2m...
    #[arg(long, default_value = "30s", value_parser = parse_run_duration)]
    duration: std::time::Duration,
    /// miners, builders, demolition, explorers or mixed (a quarter of each).
    #[arg(long, default_value = "mixed")]
    profile: Profile,
    /// Edits per second per bot (0 = walk only).
    #[arg(long, default_value_t = 1.0)]
    edit_rate: f64,
    /// Chunks around each bot it subscribes to (Chebyshev radius, 1..=8).
    #[arg(long, default_value_t = 2)]
    view_radius: u8,
    /// End-of-run comparison: all held chunks, only modified ones, or off.
    #[arg(long, default_value = "all")]
    verify: VerifyMode,
    /// Longest each bot's end-of-run check waits for the server's copies
    /// of its chunks (up to 1h); the rest count as unverified. `--verify
    /// all` at view radius 8 asks for thousands of chunks per bot.
    #[arg(long, default_value = "45s", value_parser = parse_run_duration)]
    verify_timeout: std::time::Duration,
    /// The first N bots stop reading their updates once spawned (a frozen
    /// client); they keep editing and are left out of the comparison.
    #[arg(long, default_value_t = 0)]
    stalled: usize,
    /// Per-stream receive window, in bytes, of each stalled bot's
    /// connection (quinn's stream_receive_window: every stream, the control
    /// stream too, not only updates; default: the client's own, 1.25 MB;
    /// 1024..=67108864). A small one
    /// fills the server's queue for a stalled bot after kilobytes of
    /// updates, so a short run reaches its backpressure (deltas dropped,
    /// chunks withdrawn). Stalled bots so connected take the client's
    /// default options: no --link-delay, --predict, --thin or --op-replay.
    #[arg(long)]
    stalled_window: Option<u32>,
    /// Let each bot edit as soon as it stands in the world, while the others
    /// still join (a join storm under load). By default the edits, and the
    /// DURATION, start once every bot has joined and loaded its surroundings.
    #[arg(long)]
    no_ramp: bool,
    /// Reconnect when the server has been silent this long despite pings
    /// (a killed server's connections otherwise linger until QUIC's idle
    /// timeout).
    #[arg(long, default_value = "10s", value_parser = parse_run_duration)]
    silence_limit: std::time::Duration,
    /// Hold each bot's sends this long before they leave (default: none):
    /// a simulated one-way network delay, so the server sees a real RTT on
    /// loopback (e.g. 50ms).
    #[arg(long, value_parser = parse_run_duration)]
    link_delay: Option<std::time::Duration>,
    /// Seed of the bots' choices.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// South-west corner X,Z of the square the bots live in (voxels); it
    /// must lie in the server's spawn area. Bots of different fleets (or
    /// of different cluster nodes) keep apart with different corners.
    #[arg(long, default_value = "512,512", value_parser = parse_origin, allow_hyphen_values = true)]
    area_origin: (i32, i32),
    /// Region side in chunks, as the server's `[sequencer] region_chunks`:
    /// the summary counts the bots' walks from one region into another.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=65536))]
    region_chunks: u32,
    /// On a cluster: a bot whose edit is refused because another node
    /// writes the region it stands in moves to that node (its ticket keeps
    /// its place).
    #[arg(long)]
    follow_owners: bool,
    /// Players are PREFIX-0, PREFIX-1, ... (minted tokens only). Fleets on
    /// one cluster need different prefixes: a second login of a player
    /// replaces the first.
    #[arg(long, default_value = "bot", value_parser = parse_prefix)]
    player_prefix: String,
    /// Write one JSON line per accepted edit to FILE (format above).
    #[arg(long)]
    ack_log: Option<PathBuf>,
    /// Print the summary as one JSON line on stdout.
    #[arg(long)]
    json: bool,
    /// Bots predict their own edits (apply them at once to a predicted
    /// view, then reconcile with the server); the summary adds how often
    /// the prediction was exact.
    #[arg(long)]
    predict: bool,
    /// Thin clients: ask for every chunk whole (`CAP_SNAPSHOTS`) and never
    /// run the generator.
    #[arg(long)]
    thin: bool,
    /// Replay accepted edits from ops (`CAP_OP_REPLAY`) instead of deltas.
    #[arg(long)]
    op_replay: bool,
    /// Hostile players beside the bots (each runs --attack).
    #[arg(long, default_value_t = 0)]
    hostile: usize,
    /// position-flood, border-flip, rejected-edits, far-subscribe,
    /// teleport, handshake-flood, token-share, subscribe-flood, wall-walk
    /// or fly-over.
    #[arg(long)]
    attack: Option<Attack>,
    /// Local address of every hostile connection [default: 127.0.0.2 for a
    /// server on 127.0.0.1, ::1 for [::1], else any].
    #[arg(long)]
    hostile_bind: Option<IpAddr>,
    /// Position datagrams (position-flood, border-flip, default 50000), edits
    /// (rejected-edits, default 1000) or subscriptions (subscribe-flood,
    /// default 1000) per second per hostile player.
    #[arg(long)]
    hostile_rate: Option<u32>,
    /// Sessions a token-share player opens with its one token.
    #[arg(long, default_value_t = DEFAULT_SESSIONS)]
    hostile_sessions: usize,
    /// Connections a handshake-flood player holds open at once.
    #[arg(long, default_value_t = DEFAULT_CONNECTIONS)]
    hostile_connections: usize,
    /// The server's reach in voxels ([validation] reach), for teleport's
    /// count of edits accepted beyond it.
    #[arg(long, default_value_t = DEFAULT_REACH)]
    hostile_reach: f64,
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let args = Args::parse();
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(args)) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(2),
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// A future that resolves at the first SIGTERM while it is held (the run
/// holds it through the ramp and the edits, and drops it when they end). A SIGTERM after that, or a second one,
/// ends the process (status 143), as without a handler.
fn sigterm() -> anyhow::Result<impl std::future::Future<Output = ()>> {
    use tokio::signal::unix::{signal, SignalKind};
    let mut term = signal(SignalKind::terminate()).context("listening for SIGTERM")?;
    let (told, heard) = tokio::sync::oneshot::channel::<()>();
    tokio::spawn(async move {
        term.recv().await;
        if told.send(()).is_ok() {
            term.recv().await;
        }
        std::process::exit(143);
    });
    Ok(async move {
        let _ = heard.await;
    })
}

/// Runs the bots; `Ok(false)` when the replicas did not converge.
async fn run(args: Args) -> anyhow::Result<bool> {
    match (args.hostile, args.attack) {
        (0, Some(_)) => bail!("--attack needs --hostile N (N > 0)"),
        (n, None) if n > 0 => bail!("--hostile needs --attack KIND"),
        _ => {}
    }
    let mut spawned = None;
    let (server, cert_der, tokens) = if args.spawn_server {
        let dir = tempfile::tempdir().context("creating a temp data dir")?;
        let mut cfg = ServerConfig::default();
        cfg.server.listen = "127.0.0.1:0".parse()?;
        cfg.server.data_dir = dir.path().join("data");
        let room = args.bots as u32 + 16;
        cfg.server.max_connections = cfg.server.max_connections.max(room);
        cfg.server.max_handshakes = cfg.server.max_handshakes.max(room);
        cfg.server.max_handshakes_per_address = cfg.server.max_handshakes_per_address.max(room);
        let running = app::start(cfg).await.context("starting the server")?;
        eprintln!(
            "strata-bots: server listening on {} (data in {})",
            running.addr,
            running.data_dir.root().display()
        );
        let out = (
            running.addr,
            running.cert_der.clone(),
            Tokens::Minted(running.data_dir.secret().clone()),
        );
        spawned = Some((running, dir));
        out
    } else {
        let server = args.server.context("--server is required")?;
        let dir = match &args.data_dir {
            Some(d) => Some(
                DataDir::open_existing(d)
                    .with_context(|| format!("opening data dir {}", d.display()))?,
            ),
            None => None,
        };
        let cert = match (&args.cert, &dir) {
            (Some(p), _) => {
                std::fs::read(p).with_context(|| format!("reading certificate {}", p.display()))?
            }
            (None, Some(d)) => d.cert().cert_der().to_vec(),
            (None, None) => bail!("--cert is required without --data-dir"),
        };
        let tokens = match (args.token, dir) {
            (Some(t), _) => Tokens::Shared(t),
            (None, Some(d)) => Tokens::Minted(d.secret().clone()),
            (None, None) => bail!("give --token or --data-dir"),
        };
        (server, cert, tokens)
    };
    let cfg = BotsConfig {
        server,
        cert_der,
        tokens,
        bots: args.bots,
        duration: args.duration,
        profile: args.profile,
        edit_rate: args.edit_rate,
        view_radius: args.view_radius,
        verify: args.verify,
        verify_timeout: args.verify_timeout,
        seed: args.seed,
        stalled: args.stalled,
        stalled_window: args.stalled_window,
        ramp: !args.no_ramp,
        ack_log: args.ack_log,
        progress: true,
        area_origin: args.area_origin,
        region_chunks: args.region_chunks,
        follow_owners: args.follow_owners,
        player_prefix: args.player_prefix,
        silence_limit: args.silence_limit,
        link_delay: args.link_delay.unwrap_or_default(),
        predict: args.predict,
        capabilities: capabilities(args.thin, args.op_replay),
    };
    let hostile = args.attack.map(|attack| HostileConfig {
        bind: args
            .hostile_bind
            .unwrap_or_else(|| HostileConfig::default_bind(server)),
        rate: args.hostile_rate,
        sessions: args.hostile_sessions,
        connections: args.hostile_connections,
        reach: args.hostile_reach,
        ..HostileConfig::new(attack, args.hostile, server)
    });
    let summary = bots::run_until(cfg, hostile, sigterm()?).await?;
    if args.json {
        println!("{}", summary.to_json());
    } else {
        print!("{}", summary.human());
    }
    if let Some((running, _dir)) = spawned {
        running.shutdown().await?;
    }
    Ok(summary.consistent())
}

/// The `Hello` capability bits the flags ask for.
/// `X,Z` in voxels, inside the world's coordinate range.
fn parse_origin(s: &str) -> Result<(i32, i32), String> {
    let (x, z) = s
        .split_once(',')
        .ok_or_else(|| format!("{s:?} is not X,Z"))?;
    let coord = |v: &str| -> Result<i32, String> {
        let n: i32 = v.trim().parse().map_err(|e| format!("{v:?}: {e}"))?;
        let limit = strata_terrain::edit::COORD_LIMIT_VOXELS / 2;
        if n.abs() > limit {
            return Err(format!("{n} is outside -{limit}..={limit}"));
        }
        Ok(n)
    };
    Ok((coord(x)?, coord(z)?))
}

fn capabilities(thin: bool, op_replay: bool) -> u32 {
    use strata_protocol::{CAP_OP_REPLAY, CAP_SNAPSHOTS};
    (if thin { CAP_SNAPSHOTS } else { 0 }) | (if op_replay { CAP_OP_REPLAY } else { 0 })
}

/// A player-name prefix: the name of its 1,000,000th bot must be valid.
fn parse_prefix(s: &str) -> Result<String, String> {
    strata_auth::validate_player_name(&format!("{s}-999999"))
        .map(|()| s.to_string())
        .map_err(|e| e.to_string())
}
