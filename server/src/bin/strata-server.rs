//! `strata-server`: the authoritative Strata server.

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;
use strata_server::app;
use strata_server::config::ServerConfig;
use tracing_subscriber::EnvFilter;

/// mimalloc: the tick's meshes, frames and QUIC buffers allocate and free
/// across threads all the time, where glibc's malloc spent about 10 % of
/// the server's CPU at 500 bots (BENCHMARKS.md). Its transparent huge
/// pages stay: turning them off did not pay (BENCHMARKS.md, session 47).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Authoritative multiplayer terrain server for smooth voxel worlds.
///
/// With no arguments it runs on its embedded defaults: 127.0.0.1:4433 and
/// ./strata-data (created on first run, with a self-signed certificate and
/// an auth secret).
#[derive(Debug, Parser)]
#[command(version)]
struct Args {
    /// TOML config file (see deploy/strata.toml); flags override it.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Data directory: world database, certificate, auth secret.
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// UDP address to listen on, e.g. 0.0.0.0:4433 (port 0 picks one).
    #[arg(long)]
    listen: Option<SocketAddr>,
}

/// SIGTERM and SIGINT, caught from the moment this is made: made before
/// the server says it listens, so a supervisor that stops it right after
/// still gets a graceful shutdown (the default action would kill it).
struct Signals {
    term: tokio::signal::unix::Signal,
    int: tokio::signal::unix::Signal,
}

impl Signals {
    fn catch() -> anyhow::Result<Self> {
        use tokio::signal::unix::{signal, SignalKind};
        Ok(Self {
            term: signal(SignalKind::terminate())?,
            int: signal(SignalKind::interrupt())?,
        })
    }

    async fn next(&mut self) -> &'static str {
        tokio::select! {
            _ = self.int.recv() => "SIGINT",
            _ = self.term.recv() => "SIGTERM",
        }
    }
}

/// The log filter without `RUST_LOG`: QUIC's and TLS's own warnings are
/// left out, as a peer with no login (even one faking its address) can
/// draw one per packet it sends; Strata logs the refusals it makes itself,
/// at most one line a second each.
const DEFAULT_LOG_FILTER: &str = "info,quinn_proto=error,quinn=error,quinn_udp=warn,rustls=error";

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| EnvFilter::new(DEFAULT_LOG_FILTER)),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let args = Args::parse();
    let mut cfg = ServerConfig::load(args.config.as_deref()).context("loading config")?;
    cfg.apply_overrides(args.data_dir, args.listen);
    // The runtime is sized by the config, so it starts after it is read.
    let mut runtime = tokio::runtime::Builder::new_multi_thread();
    runtime.enable_all();
    if let Some(n) = cfg.server.net_threads() {
        runtime.worker_threads(n);
    }
    let runtime = runtime.build().context("starting the async runtime")?;
    let served = runtime.block_on(serve(cfg));
    // Everything recovery needs is durable by now: blocking work still
    // running (a snapshot reader ending) gets this long, not forever.
    runtime.shutdown_timeout(EXIT_GRACE);
    served
}

/// How long the exit waits for blocking work left once the server stopped.
const EXIT_GRACE: std::time::Duration = std::time::Duration::from_secs(5);

async fn serve(cfg: ServerConfig) -> anyhow::Result<()> {
    let metrics_connections = cfg.metrics.max_connections;
    let metrics = match cfg.metrics.listen {
        Some(addr) => {
            let handle = strata_server::metrics::shared()?;
            let listener = strata_server::metrics::bind(addr)
                .await
                .with_context(|| format!("binding the metrics listener {addr}"))?;
            Some((listener, handle))
        }
        None => None,
    };
    // Served from the start: `/healthz` answers 503 while the server starts
    // (opening the store, replaying its log) instead of leaving probes hanging.
    let health = std::sync::Arc::new(strata_server::health::Health::default());
    if let Some((listener, handle)) = metrics {
        tokio::spawn(strata_server::metrics::serve(
            listener,
            metrics_connections,
            handle,
            health.clone(),
        ));
    }
    let mut signals = Signals::catch()?;
    let running = app::start_with_health(cfg, health).await?;
    // One machine-readable line on stdout: tests and scripts read the port
    // (and may close the pipe after it: nothing else is printed there).
    let console = running
        .console_addr
        .map_or(String::new(), |a| format!("; console http://{a}/"));
    println!(
        "strata-server listening on {} (certificate {}){console}",
        running.addr,
        running.data_dir.cert_path().display()
    );
    tokio::select! {
        signal = signals.next() => {
            tracing::info!(signal, "shutting down");
            running.shutdown().await
        }
        () = running.engine_stopped() => {
            tracing::error!("the engine stopped; closing every session and exiting");
            if let Some(why) = running.superseded() {
                let _ = running.shutdown().await;
                eprintln!("strata-server: {why}");
                std::process::exit(strata_server::app::EXIT_SUPERSEDED);
            }
            // The engine's error, or this one should it have returned Ok.
            running.shutdown().await?;
            anyhow::bail!("the engine stopped")
        }
    }
}
