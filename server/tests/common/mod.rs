//! A real server on 127.0.0.1 with port 0 and a temp data dir, plus tokens.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use strata_client_sim::Client;
use strata_protocol::Role;
use strata_server::app::{self, Running};
use strata_server::auth;
use strata_server::config::ServerConfig;
use strata_server::datadir::DataDir;
use strata_terrain::{Fixed, FixedVec3};

/// The store a test's server runs on: sled in its data dir, or a
/// PostgreSQL database of the test's own ([`Backend::postgres`]).
#[derive(Debug)]
pub enum Backend {
    Sled,
    Postgres(strata_tests::postgres::PgDb),
}

impl Backend {
    /// PostgreSQL for `test`; `None` (said) when it is missing outside CI.
    pub fn postgres(test: &str) -> Option<Backend> {
        strata_tests::postgres::database(test).map(Backend::Postgres)
    }

    /// Points a server config at this store.
    pub fn apply(&self, cfg: &mut ServerConfig) {
        if let Backend::Postgres(db) = self {
            cfg.store.backend = strata_server::store::StoreBackend::Postgres;
            cfg.store.postgres.url = db.url();
        }
    }

    /// The `[store]` TOML of a child-process server's config.
    pub fn toml(&self) -> String {
        match self {
            Backend::Sled => String::new(),
            Backend::Postgres(db) => db.store_toml(),
        }
    }

    /// The store a (stopped) server of `data_dir` wrote, opened offline.
    pub fn open_store(
        &self,
        data_dir: &Path,
    ) -> std::sync::Arc<dyn strata_server::store::ChunkStore> {
        let mut cfg = test_config(data_dir);
        self.apply(&mut cfg);
        let store = strata_server::store::open_store(
            &cfg.store,
            &data_dir.join("world.sled"),
            cfg.sequencer.region_chunks,
            None,
        )
        .unwrap();
        // As the server does: chunks stored from generated read through it.
        let (generator, _) = strata_server::app::world_generator(&cfg).unwrap();
        store.attach_generator(std::sync::Arc::new(generator));
        store
    }
}

/// Two tests of one body, `async fn $on(backend: Backend)`: `$sled` on
/// sled and `$pg` on PostgreSQL (not run, and said, when it is missing
/// outside CI). Needs `#[macro_use] mod common;`.
#[allow(unused_macros)]
macro_rules! on_both_backends {
    ($sled:ident, $pg:ident, $on:ident) => {
        #[tokio::test]
        async fn $sled() {
            $on(Backend::Sled).await;
        }

        #[tokio::test]
        async fn $pg() {
            if let Some(b) = Backend::postgres(stringify!($pg)) {
                $on(b).await;
            }
        }
    };
}

/// Every network test gives up after this long.
pub const TEST_TIMEOUT: Duration = Duration::from_secs(60);

/// A config for tests: loopback, port 0, no spawn protection, fast ticks.
pub fn test_config(data_dir: &Path) -> ServerConfig {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = data_dir.to_path_buf();
    cfg.validation.spawn_protection_radius = 0;
    cfg.interest.view_radius = 2;
    cfg.engine.tick_ms = 5;
    cfg
}

pub async fn start(data_dir: &Path) -> Running {
    start_on(data_dir, &Backend::Sled).await
}

/// [`start`] with the store on `backend`.
pub async fn start_on(data_dir: &Path, backend: &Backend) -> Running {
    let mut cfg = test_config(data_dir);
    backend.apply(&mut cfg);
    app::start(cfg).await.expect("server starts")
}

pub fn token(server: &Running, player: &str, role: Role) -> String {
    auth::issue(
        server.data_dir.secret(),
        player,
        role,
        Duration::from_secs(3600),
        auth::unix_now(),
    )
    .unwrap()
}

pub async fn connect(server: &Running, player: &str, role: Role) -> Client {
    Client::connect(server.addr, &server.cert_der, &token(server, player, role))
        .await
        .expect("client connects")
}

/// Feet position in fixed point.
pub fn at(x: f64, y: f64, z: f64) -> FixedVec3 {
    FixedVec3::from_f64([x, y, z]).unwrap()
}

pub fn r(v: f64) -> Fixed {
    Fixed::from_f64(v).unwrap()
}

/// A QUIC connection to `addr` whose streams each hold at most `window`
/// unread bytes, so the server's writes to a stream it does not read soon
/// block on flow control.
pub async fn connect_small_window(
    addr: SocketAddr,
    mut cfg: quinn::ClientConfig,
    window: u32,
) -> (quinn::Endpoint, quinn::Connection) {
    let mut transport = quinn::TransportConfig::default();
    transport.stream_receive_window(quinn::VarInt::from_u32(window));
    cfg.transport_config(std::sync::Arc::new(transport));
    let mut endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    endpoint.set_default_client_config(cfg);
    let conn = endpoint.connect(addr, "localhost").unwrap().await.unwrap();
    (endpoint, conn)
}

/// Polls `f` every 20 ms until it is true or `limit` passes.
pub async fn eventually(limit: Duration, mut f: impl FnMut() -> bool) -> bool {
    let start = std::time::Instant::now();
    while start.elapsed() < limit {
        if f() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    f()
}

/// Config for child-process servers: no spawn protection, a high edit rate.
pub const FAST_EDITS: &str =
    "[validation]\nspawn_protection_radius = 0\n[validation.edit_rate]\nper_second = 1000\ncapacity = 1000\n";

/// A `strata-server` child process, killed when dropped: a test that fails
/// before it stops its server leaves none running.
#[derive(Debug)]
pub struct ServerProcess(Child);

impl std::ops::Deref for ServerProcess {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for ServerProcess {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        // Errors only say it has ended already.
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts the real `strata-server` binary on 127.0.0.1 port 0 with `config`
/// and returns it with the address it printed.
pub fn spawn_server(data_dir: &Path, config: &str) -> (ServerProcess, SocketAddr) {
    let path = data_dir.with_extension("toml");
    std::fs::write(&path, config).unwrap();
    let mut child = ServerProcess(
        Command::new(env!("CARGO_BIN_EXE_strata-server"))
            .arg("--config")
            .arg(&path)
            .arg("--data-dir")
            .arg(data_dir)
            .arg("--listen")
            .arg("127.0.0.1:0")
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("strata-server starts"),
    );
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split_whitespace()
        .find_map(|w| w.parse::<SocketAddr>().ok())
        .unwrap_or_else(|| panic!("no address in {line:?}"));
    (child, addr)
}

/// A client of a child-process server, with a token from its data dir.
pub async fn process_client(data_dir: &Path, addr: SocketAddr, player: &str) -> Client {
    process_client_opts(data_dir, addr, player, Default::default()).await
}

/// [`process_client`] with client options (capabilities, ...).
pub async fn process_client_opts(
    data_dir: &Path,
    addr: SocketAddr,
    player: &str,
    opts: strata_client_sim::ClientOptions,
) -> Client {
    let dd = DataDir::open_existing(data_dir).unwrap();
    let token = auth::issue(
        dd.secret(),
        player,
        Role::Player,
        Duration::from_secs(600),
        auth::unix_now(),
    )
    .unwrap();
    Client::connect_opts(addr, dd.cert().cert_der(), &token, opts)
        .await
        .unwrap()
}

/// The text of a Prometheus endpoint's `/metrics`.
pub fn scrape(addr: SocketAddr) -> String {
    http_get(addr, "/metrics")
}

/// The whole HTTP/1.1 response (status line, headers, body) to `GET path`.
pub fn http_get(addr: SocketAddr, path: &str) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let request = format!("GET {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n");
    s.write_all(request.as_bytes()).unwrap();
    let mut body = String::new();
    s.read_to_string(&mut body).unwrap();
    body
}

/// The value of an unlabelled metric in a scrape.
pub fn metric(text: &str, name: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' '))
        .and_then(|v| v.trim().parse().ok())
}

/// A free TCP port on loopback for a metrics endpoint.
pub fn free_metrics_addr() -> SocketAddr {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
}

/// A surface voxel at (x, z) and the feet position standing on it.
pub fn spot(x: i32, z: i32) -> (FixedVec3, strata_terrain::VoxelPos) {
    let g = strata_terrain::gen::Generator::fractal(Default::default()).unwrap();
    let y = g.surface_height(x, z);
    (
        at(x as f64, y + 1.0, z as f64),
        strata_terrain::VoxelPos::new(x, y.floor() as i32, z),
    )
}

/// Live sessions, from the admin protocol.
pub async fn live_sessions(server: &Running) -> u32 {
    admin_stats(server).await.sessions
}

/// The admin protocol's `Stats`.
pub async fn admin_stats(server: &Running) -> strata_protocol::admin::ServerStats {
    use strata_protocol::admin::{AdminRequest, AdminResponse};
    let token = token(server, "ops", Role::Admin);
    let mut admin =
        strata_server::admin::remote::AdminClient::connect(server.addr, &server.cert_der, &token)
            .await
            .unwrap();
    let stats = match admin.request(&AdminRequest::Stats).await.unwrap() {
        AdminResponse::Stats(s) => s,
        other => panic!("unexpected {other:?}"),
    };
    admin.close().await;
    stats
}

/// [`connect`] with `Hello` capability bits.
pub async fn connect_caps(server: &Running, player: &str, capabilities: u32) -> Client {
    let opts = strata_client_sim::ClientOptions {
        capabilities,
        ..Default::default()
    };
    let t = token(server, player, Role::Player);
    Client::connect_opts(server.addr, &server.cert_der, &t, opts)
        .await
        .expect("client connects")
}

/// The server's version and chunk hash of `pos`, from the admin protocol.
pub async fn server_chunk(server: &Running, pos: strata_terrain::ChunkPos) -> (u64, u64) {
    use strata_protocol::admin::{AdminRequest, AdminResponse};
    let token = token(server, "ops", Role::Admin);
    let mut admin =
        strata_server::admin::remote::AdminClient::connect(server.addr, &server.cert_der, &token)
            .await
            .unwrap();
    let r = match admin
        .request(&AdminRequest::InspectChunk { pos })
        .await
        .unwrap()
    {
        AdminResponse::Chunk { version, data, .. } => {
            let chunk = strata_terrain::chunk_codec::decode_chunk(&data).unwrap();
            (version, strata_terrain::hash::chunk_hash(&chunk))
        }
        other => panic!("unexpected {other:?}"),
    };
    admin.close().await;
    r
}

/// An engine on a flat stone world in a fresh sled store at `dir`, one
/// worker, spawned: its handle and thread.
pub fn flat_engine(
    dir: &Path,
) -> (
    strata_server::engine::EngineHandle,
    std::thread::JoinHandle<anyhow::Result<()>>,
) {
    use std::sync::Arc;
    use strata_server::engine::{Engine, EngineConfig, StreamPolicy};
    use strata_server::sequencer::{Sequencer, SequencerConfig};
    use strata_server::store::{ChunkStore, SledStore, WorldMeta};
    let store = Arc::new(SledStore::open(dir).unwrap());
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    let world = strata_terrain::World::new(Arc::new(strata_terrain::world::FlatGenerator {
        ground: strata_terrain::Voxel::solid(strata_terrain::material::ids::STONE),
    }));
    let seq = Sequencer::new(
        world,
        SequencerConfig::default(),
        strata_server::validate::ValidationConfig::default(),
        0,
        strata_terrain::MaterialTable::default(),
        strata_terrain::edit::StructureLibrary::default(),
        Vec::new(),
    );
    let engine = Engine::new(
        seq,
        store,
        EngineConfig {
            workers: 1,
            ..Default::default()
        },
        StreamPolicy {
            send_budget: 1 << 20,
            regenerable: true,
        },
        strata_server::interest::InterestConfig::default(),
        strata_server::validate::bounds::WorldBounds::default(),
        Default::default(),
    )
    .unwrap();
    engine.spawn(|| {}).unwrap()
}
