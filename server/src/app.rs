//! Building a running server from its config: data dir, store, world,
//! engine thread and QUIC endpoint.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{Generator, GENERATOR_VERSION};
use strata_terrain::{MaterialTable, World};
use tracing::info;

use crate::cluster::ticket::TicketKey;
use crate::config::ServerConfig;
use crate::datadir::DataDir;
use crate::engine::{Engine, EngineHandle, StreamPolicy};
use crate::health::Health;
use crate::net::endpoint::Listener;
use crate::net::player_buckets::PlayerBuckets;
use crate::net::position_reads::PositionReads;
use crate::net::session::SessionContext;
use crate::sequencer::Sequencer;
use crate::shutdown::{self, Shutdown, ShutdownTrigger};
use crate::store::{Checkpointer, ChunkStore, WorldMeta, STORE_FORMAT_VERSION};
use crate::structures::load_structures;
use crate::validate::zones::Zone;
use crate::validate::WorldBounds;

/// Blob name under which protected zones are stored.
pub use crate::stored_zones::ZONES_BLOB;

/// Exit status of a cluster node stopped because another process started
/// under its `node_id`: the systemd units do not restart on it
/// (`RestartPreventExitStatus`), so two processes sharing an id never
/// take turns superseding each other.
pub const EXIT_SUPERSEDED: i32 = 3;

/// A server that is listening.
#[derive(Debug)]
pub struct Running {
    pub addr: SocketAddr,
    /// DER bytes of the certificate clients must pin.
    pub cert_der: Vec<u8>,
    pub data_dir: DataDir,
    trigger: ShutdownTrigger,
    listener: tokio::task::JoinHandle<()>,
    engine: EngineHandle,
    engine_thread: std::thread::JoinHandle<anyhow::Result<()>>,
    checkpointer: Checkpointer,
    store: Arc<dyn ChunkStore>,
    health: Arc<Health>,
    /// Becomes true when the engine thread ends.
    engine_exit: tokio::sync::watch::Receiver<bool>,
    /// What signs and checks this node's tickets (a cluster's only).
    pub tickets: Option<TicketKey>,
    /// The web console's address, when `[console] listen` is set.
    pub console_addr: Option<SocketAddr>,
    console: Option<crate::console::RunningConsole>,
    /// Read the access list and the zones again from the store now and then.
    reloads: [tokio::task::JoinHandle<()>; 2],
}

fn load_zones(store: &dyn ChunkStore, cfg: &ServerConfig) -> anyhow::Result<Vec<Zone>> {
    Ok(crate::stored_zones::stored(store)?
        .unwrap_or_else(|| Sequencer::default_zones(&cfg.validation)))
}

/// The world's generator from the config, and the generator parameter text
/// its store records (compared on every start, so a data dir refuses a
/// changed generator).
pub fn world_generator(cfg: &ServerConfig) -> anyhow::Result<(Generator, String)> {
    let params = &cfg.world.generator;
    Ok(match &cfg.world.heightmap {
        Some(section) => {
            let (g, fingerprint) = crate::heightmap::load(section, params)?;
            // The fingerprint makes the data dir refuse a different map.
            (g, format!("{}# {fingerprint}\n", toml::to_string(params)?))
        }
        None => (
            Generator::fractal(params.clone())?,
            toml::to_string(params)?,
        ),
    })
}

/// The generator parameter text to check `stored` against: `given`, or
/// the stored text when it is `given` as a data dir recorded it before raw
/// heightmaps' sizes were part of the fingerprint (logged: the map's size
/// goes unchecked for that data dir).
pub fn recorded_params(given: String, stored: Option<&WorldMeta>) -> String {
    match stored {
        Some(m)
            if m.generator_params != given
                && crate::heightmap::without_raw_size(&given).as_deref()
                    == Some(m.generator_params.as_str()) =>
        {
            tracing::warn!(
                "this world was made before a raw heightmap's width and height were recorded: \
                 they are not checked against it"
            );
            m.generator_params.clone()
        }
        _ => given,
    }
}

/// Opens the data dir and store, checks the world metadata against the
/// config, and binds the endpoint. Nothing is accepted until [`Running`]
/// exists; call [`Running::shutdown`] to stop.
pub async fn start(cfg: ServerConfig) -> anyhow::Result<Running> {
    start_with_health(cfg, Arc::default()).await
}

/// [`start`], reporting readiness through `health`, which a `/healthz`
/// already serving can answer from while the server starts ("not
/// accepting connections" until it does).
pub async fn start_with_health(cfg: ServerConfig, health: Arc<Health>) -> anyhow::Result<Running> {
    cfg.validate()?;
    if cfg.server.retry_above_handshakes >= cfg.server.max_handshakes {
        tracing::warn!(
            retry_above_handshakes = cfg.server.retry_above_handshakes,
            max_handshakes = cfg.server.max_handshakes,
            "retry_above_handshakes is not below max_handshakes: no Retry is ever sent, and spoofed sources can take every handshake slot"
        );
    }
    // On PostgreSQL the world lives outside the data dir: whether it holds
    // one decides, as `world.sled` does, if missing identity files may be
    // made anew.
    let pg_world = match cfg.store.backend {
        crate::store::StoreBackend::Postgres => {
            let store =
                crate::store::PgStore::open(&cfg.store.postgres, cfg.sequencer.region_chunks)?;
            store
                .load_meta()?
                .map(|_| "the world in the PostgreSQL store")
        }
        crate::store::StoreBackend::Sled => None,
    };
    let (data_dir, report) =
        DataDir::open_or_init_beside(&cfg.server.data_dir, &cfg.tls.extra_names, pg_world)
            .with_context(|| format!("opening data dir {}", cfg.server.data_dir.display()))?;
    for (what, path) in [
        ("data dir", &report.created_dir),
        ("certificate", &report.created_cert),
        ("auth secret", &report.created_secret),
    ] {
        if let Some(p) = path {
            info!(path = %p.display(), "generated {what}");
        }
    }
    let store = crate::store::open_store(
        &cfg.store,
        &data_dir.world_db_path(),
        cfg.sequencer.region_chunks,
        cfg.cluster.as_ref(),
    )?;
    // Before the world is read: no restore replaces it under this server.
    store.serve()?;
    let params = cfg.world.generator.clone();
    let mut validation = cfg.validation.clone();
    validation.bounds = WorldBounds {
        min_y: params.min_y,
        max_y: params.max_y,
    };
    let (generator, generator_params) = world_generator(&cfg)?;
    let generator_params = recorded_params(generator_params, store.load_meta()?.as_ref());
    let generator = Arc::new(generator);
    let meta = store.init_meta(&WorldMeta {
        format_version: STORE_FORMAT_VERSION,
        seed: params.seed,
        generator_version: GENERATOR_VERSION,
        generator_params: generator_params.clone(),
        last_seq: 0,
    })?;
    // The metadata matched: new chunks may be stored as changes to it.
    store.attach_generator(generator.clone());
    let structures = match &cfg.world.structures_dir {
        Some(dir) => load_structures(Path::new(dir))?,
        None => StructureLibrary::default(),
    };
    let zones = load_zones(&*store, &cfg)?;
    let access =
        crate::auth::AccessList::from_blob(store.get_blob(crate::auth::ACCESS_BLOB)?.as_deref())?;
    // A cluster node numbers its edits from a seq block of its own.
    let start_seq = store.reserve_seqs(meta.last_seq)?;
    let mut seq = Sequencer::new(
        World::new(generator.clone()),
        cfg.sequencer,
        validation.clone(),
        start_seq,
        MaterialTable::default(),
        structures,
        zones,
    );
    seq.restore_positions(
        store
            .recent_player_positions(cfg.validation.remembered_players)
            .context("reading stored player positions")?,
    );
    let mut versions = HashMap::new();
    for item in store.modified_chunks() {
        let (pos, version) = item?;
        versions.insert(pos, version);
    }
    info!(
        last_seq = meta.last_seq,
        modified_chunks = versions.len(),
        "world loaded"
    );
    // A cluster's tickets are signed for its world; a server alone on its
    // store mints and accepts none.
    let tickets = match (&cfg.cluster, store.world_id()) {
        (None, _) => None,
        (Some(_), Some(world)) => Some(TicketKey::new(data_dir.secret().clone(), world)),
        (Some(_), None) => anyhow::bail!("a cluster node's store has no world id"),
    };
    let engine = Engine::new(
        seq,
        store.clone(),
        cfg.engine,
        StreamPolicy {
            send_budget: cfg.net.send_budget_bytes_per_tick,
            regenerable: cfg.world.heightmap.is_none(),
        },
        cfg.interest,
        validation.bounds,
        versions,
    )?;
    let engine = match &tickets {
        Some(key) => engine.with_ticket_key(key.clone()),
        None => engine,
    };
    let engine = engine.with_health(health.clone());
    let (exit_tx, engine_exit) = tokio::sync::watch::channel(false);
    let on_exit = {
        let health = health.clone();
        move || {
            health.engine_stopped();
            let _ = exit_tx.send(true);
        }
    };
    let (engine, engine_thread) = engine.spawn(on_exit)?;
    // Background store work (checkpoints, a cluster node's lease renewals)
    // tells readiness of its failures too.
    store.report_to(health.clone());
    let checkpointer = Checkpointer::spawn(
        store.clone(),
        cfg.store.checkpoint_pace(),
        Some(health.clone()),
    )?;
    let server_config = crate::tls::server_config(data_dir.cert(), &cfg.net, &cfg.tls)?;
    let endpoint = quinn::Endpoint::server(server_config, cfg.server.listen)
        .with_context(|| format!("binding {}", cfg.server.listen))?;
    let addr = endpoint.local_addr()?;
    store.bound_at(&addr.to_string());
    let ctx = SessionContext {
        secret: data_dir.secret().clone(),
        token_max_ttl: cfg.auth.token_max_ttl.0,
        tickets: tickets.clone(),
        engine: engine.clone(),
        store: store.clone(),
        world_seed: meta.seed,
        generator_version: meta.generator_version,
        generator_params: meta.generator_params.clone(),
        view_radius: cfg.interest.radius(),
        writer_queue: cfg.net.writer_queue,
        writer_queue_bytes: cfg.net.writer_queue_bytes,
        control_writer_queue: cfg.net.control_writer_queue,
        send_interval: cfg.net.send_interval(),
        request_rate: cfg.validation.request_rate,
        request_buckets: PlayerBuckets::new(cfg.server.max_connections as usize),
        join_rate: cfg.validation.join_rate,
        join_buckets: PlayerBuckets::new(cfg.server.max_connections as usize),
        position_rate: cfg.validation.position_rate,
        access: std::sync::RwLock::new(access),
        access_writes: tokio::sync::Mutex::new(()),
        default_zones: Sequencer::default_zones(&cfg.validation),
        zone_writes: tokio::sync::Mutex::new(()),
        position_reads: match &cfg.cluster {
            Some(c) => PositionReads::new(
                c.position_reads_with(cfg.store.postgres.max_connections),
                std::time::Duration::from_millis(c.position_read_ms),
            ),
            None => PositionReads::default(),
        },
        health: health.clone(),
    };
    let ctx = Arc::new(ctx);
    // Bound before anything is accepted, so a taken port fails the start.
    let console = match cfg.console.listen {
        Some(_) => Some(
            crate::console::start(
                cfg.console.clone(),
                crate::console::ConsoleParts {
                    ctx: ctx.clone(),
                    store: store.clone(),
                    generator,
                    metrics: crate::metrics::shared()?,
                    data_dir: cfg.server.data_dir.clone(),
                    region_chunks: cfg.sequencer.region_chunks,
                    node_id: cfg.cluster.as_ref().map(|c| c.node_id.clone()),
                },
            )
            .await
            .with_context(|| format!("starting the console on {:?}", cfg.console.listen))?,
        ),
        None => None,
    };
    // Every port is bound: only now does this process take its cluster
    // node id over (a start that failed supersedes nobody).
    if let Err(e) = store.register_node() {
        // What started so far stops, as in `Running::shutdown`.
        if let Some(console) = console {
            console.stop();
        }
        let store = store.clone();
        let _ = tokio::task::spawn_blocking(move || {
            engine.stop();
            let _ = engine_thread.join();
            let _ = checkpointer.stop();
            let _ = store.close();
        })
        .await;
        return Err(anyhow::Error::from(e).context("registering the cluster node"));
    }
    let (trigger, shutdown) = shutdown::channel();
    // Bans and revocations written by another node apply here too.
    // Bans, revocations and zones written by another node apply here too.
    let reloads = [
        tokio::spawn(crate::net::admin_session::reload_access(
            ctx.clone(),
            shutdown.clone(),
        )),
        tokio::spawn(crate::net::admin_zones::reload(
            ctx.clone(),
            shutdown.clone(),
        )),
    ];
    let listener = Listener::new(
        endpoint,
        ctx,
        cfg.server.admission(cfg.engine.sessions_per_player),
    );
    let listener = tokio::spawn(listener.run(shutdown));
    health.set_accepting(true);
    Ok(Running {
        addr,
        cert_der: data_dir.cert().cert_der().to_vec(),
        data_dir,
        trigger,
        listener,
        engine,
        engine_thread,
        checkpointer,
        store,
        health,
        engine_exit,
        tickets,
        console_addr: console.as_ref().map(|c| c.addr),
        console,
        reloads,
    })
}

impl Running {
    /// Why the engine stopped, when another process took this cluster
    /// node's id (the server then exits with [`EXIT_SUPERSEDED`]).
    pub fn superseded(&self) -> Option<String> {
        self.store.superseded()
    }

    /// A listener for this server's shutdown signal.
    pub fn shutdown_signal(&self) -> Shutdown {
        self.trigger.subscribe()
    }

    /// Readiness, for `/healthz`.
    pub fn health(&self) -> Arc<Health> {
        self.health.clone()
    }

    /// Resolves when the engine thread has ended (on its own, it only does
    /// so when a commit failed, it panicked, or another process took its
    /// cluster node id: [`Self::superseded`]): the server can serve no one
    /// and should [`Self::shutdown`] and exit non-zero.
    pub async fn engine_stopped(&self) {
        let mut rx = self.engine_exit.clone();
        let _ = rx.wait_for(|stopped| *stopped).await;
    }

    /// Finishes and flushes the batch in flight and acknowledges it, then
    /// stops accepting and closes every session with a reason. Returns the
    /// engine's error if it had stopped on one (the sessions are closed
    /// all the same).
    pub async fn shutdown(self) -> anyhow::Result<()> {
        self.health.set_accepting(false);
        if let Some(console) = self.console {
            console.stop();
        }
        // They only read the store: stopped before the store closes.
        for reload in self.reloads {
            reload.abort();
            let _ = reload.await;
        }
        let engine = self.engine;
        let engine_thread = self.engine_thread;
        let checkpointer = self.checkpointer;
        let store = self.store;
        let engine_result = tokio::task::spawn_blocking(move || {
            engine.stop();
            let joined = engine_thread.join();
            // Nothing commits now: fold the deltas left into chunk records.
            if let Err(e) = checkpointer.stop() {
                tracing::error!(error = %e, "final checkpoint failed; the deltas stay for the next start");
            }
            // A cluster node hands its regions over at once.
            if let Err(e) = store.close() {
                tracing::warn!(error = %e, "closing the store failed; leases run out on their own");
            }
            joined
        })
        .await;
        self.trigger.trigger();
        let _ = self.listener.await;
        engine_result?.map_err(|_| anyhow::anyhow!("engine thread panicked"))??;
        info!("server stopped");
        Ok(())
    }
}
