//! The online side of `strata-admin`: a QUIC client of the admin protocol
//! (ALPN `strata-admin/1`), pinned to the server's certificate, and the
//! arguments that choose between online and offline.

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Args;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use strata_protocol::admin::{
    AdminHello, AdminRequest, AdminResponse, AdminWelcome, ADMIN_ALPN, ADMIN_PROTOCOL_VERSION,
};
use strata_protocol::admin_parts::Joiner;
use strata_protocol::io::FramedReader;
use strata_protocol::{encode_frame, Direction, ErrorCode, FrameBuffer};

use crate::admin::world_source::{world_generator_of, DATA_DIR_CONFIG_NAME};
use crate::client_tls::client_config_pinned_with_alpn;
use crate::config::ServerConfig;
use crate::datadir::DataDir;
use crate::store::{open_store, ChunkStore, PgStore, StoreBackend};

/// How long connecting and each non-streaming answer may take.
pub const REMOTE_TIMEOUT: Duration = Duration::from_secs(30);

/// Where a command runs: a stopped server's data dir, or a running server.
#[derive(Debug, Clone, Args)]
pub struct TargetArgs {
    /// Data dir of a stopped server (offline).
    #[arg(long, conflicts_with = "server", required_unless_present = "server")]
    pub data_dir: Option<PathBuf>,
    /// Address of a running server (online), e.g. 127.0.0.1:4433; needs
    /// --cert and --token or --token-file.
    #[arg(long, requires = "cert")]
    pub server: Option<SocketAddr>,
    /// The server's certificate (DER, `<data-dir>/cert.der`) to pin.
    #[arg(long, requires = "server")]
    pub cert: Option<PathBuf>,
    /// An admin-role token (`strata-admin token issue --role admin`). On a
    /// shared host prefer --token-file: a command line is visible to every
    /// local user while the command runs.
    #[arg(long, requires = "server", conflicts_with = "token_file")]
    pub token: Option<String>,
    /// A file holding the admin token (surrounding whitespace ignored).
    #[arg(long, value_name = "FILE", requires = "server")]
    pub token_file: Option<PathBuf>,
}

/// Longest token file read: far above any token's length.
pub const MAX_TOKEN_FILE_BYTES: u64 = 64 * 1024;

/// The token in `path`, trimmed.
fn read_token_file(path: &Path) -> anyhow::Result<String> {
    use std::io::Read;
    let mut text = String::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_TOKEN_FILE_BYTES + 1).read_to_string(&mut text))
        .with_context(|| format!("reading the token file {}", path.display()))?;
    if text.len() as u64 > MAX_TOKEN_FILE_BYTES {
        bail!(
            "the token file {} is over {MAX_TOKEN_FILE_BYTES} bytes",
            path.display()
        );
    }
    let token = text.trim();
    if token.is_empty() {
        bail!("the token file {} is empty", path.display());
    }
    Ok(token.to_string())
}

/// A resolved target.
#[derive(Debug)]
pub enum Target {
    Offline(PathBuf),
    Online {
        server: SocketAddr,
        cert: PathBuf,
        token: String,
    },
}

impl TargetArgs {
    pub fn target(&self) -> anyhow::Result<Target> {
        let token = match (&self.token, &self.token_file) {
            (Some(t), _) => Some(t.clone()),
            (None, Some(path)) => Some(read_token_file(path)?),
            (None, None) => None,
        };
        match (&self.data_dir, self.server, &self.cert, token) {
            (Some(d), None, _, _) => Ok(Target::Offline(d.clone())),
            (None, Some(server), Some(cert), Some(token)) => Ok(Target::Online {
                server,
                cert: cert.clone(),
                token,
            }),
            _ => {
                bail!("give either --data-dir, or --server with --cert and --token or --token-file")
            }
        }
    }

    /// Sends `req` to the server when the target is online and returns its
    /// accepted answer; `None` when the target is a data dir.
    pub fn request_if_online(&self, req: &AdminRequest) -> anyhow::Result<Option<AdminResponse>> {
        match self.target()? {
            Target::Online {
                server,
                cert,
                token,
            } => request_once(server, &cert, &token, req).map(Some),
            Target::Offline(_) => Ok(None),
        }
    }
}

/// Opens the store of a stopped server's data dir: the `[store]` backend
/// that `DIR/strata.toml` names, else sled's `DIR/world.sled`. It holds no
/// leases (its writes are not fenced): a cluster's nodes must be stopped.
pub fn open_offline_store(dir: &Path) -> anyhow::Result<Arc<dyn ChunkStore>> {
    open_offline_store_as(dir, None)
}

/// [`open_offline_store`] with the server's config at `config` when given
/// (its `[store]` names the store, not `DIR/strata.toml`: a data dir left
/// with a `world.sled` after a move to PostgreSQL is not read by mistake).
pub fn open_offline_store_as(
    dir: &Path,
    config: Option<&Path>,
) -> anyhow::Result<Arc<dyn ChunkStore>> {
    let dd = DataDir::open_existing(dir)
        .with_context(|| format!("opening data dir {}", dir.display()))?;
    let cfg = offline_config(dir, config)?;
    let world_db = dd.world_db_path();
    // Opening sled creates a store: a data dir without one (never started,
    // or a PostgreSQL server's whose strata.toml is elsewhere) would get an
    // empty one, and a ban or zone written there would reach no server.
    if cfg.store.backend == StoreBackend::Sled && !world_db.exists() {
        anyhow::bail!(
            "{} does not exist: no server has stored a world in {} (on PostgreSQL, put the \
             server's strata.toml in the data dir)",
            world_db.display(),
            dir.display()
        );
    }
    // On PostgreSQL as an admin tool: its sessions are named so (a forced
    // restore refuses only running servers' sessions), and it migrates
    // only while no server uses the database.
    let store: Result<Arc<dyn ChunkStore>, _> = match cfg.store.backend {
        StoreBackend::Postgres => {
            PgStore::open_admin(&cfg.store.postgres, cfg.sequencer.region_chunks)
                .map(|s| Arc::new(s) as Arc<dyn ChunkStore>)
        }
        StoreBackend::Sled => open_store(&cfg.store, &world_db, cfg.sequencer.region_chunks, None),
    };
    let store = store.with_context(|| {
        format!(
            "opening the world store of {} (is the server still running? stop it or use --server)",
            dir.display()
        )
    })?;
    // Chunks stored as changes to generated terrain read through the
    // world's generator: the config's if the data dir has one, else the
    // one the store records. Without it those reads say what they need.
    if let Some(meta) = store.load_meta()? {
        let has_config = config.is_some() || dir.join(DATA_DIR_CONFIG_NAME).is_file();
        let generator = world_generator_of(has_config.then_some(&cfg), Some(&meta));
        if let Ok(g) = generator {
            store.attach_generator(Arc::new(g));
        }
    }
    Ok(store)
}

/// The config at `config` when given, else [`data_dir_config`].
pub fn offline_config(dir: &Path, config: Option<&Path>) -> anyhow::Result<ServerConfig> {
    match config {
        Some(path) => {
            ServerConfig::load(Some(path)).with_context(|| format!("loading {}", path.display()))
        }
        None => data_dir_config(dir),
    }
}

/// `DIR/strata.toml` when the data dir has one, else the defaults.
pub fn data_dir_config(dir: &Path) -> anyhow::Result<ServerConfig> {
    let path = dir.join(DATA_DIR_CONFIG_NAME);
    if !path.is_file() {
        return Ok(ServerConfig::default());
    }
    ServerConfig::load(Some(&path)).with_context(|| format!("loading {}", path.display()))
}

/// Runs an online command on a small runtime of its own.
pub fn block_on<T>(f: impl std::future::Future<Output = anyhow::Result<T>>) -> anyhow::Result<T> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?
        .block_on(f)
}

/// A progress bar on stderr, hidden when stderr is not a terminal.
pub fn progress(len: Option<u64>, template: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(len, ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}

/// A logged-in admin connection.
#[derive(Debug)]
pub struct AdminClient {
    endpoint: quinn::Endpoint,
    conn: quinn::Connection,
    send: quinn::SendStream,
    reader: FramedReader<quinn::RecvStream>,
    welcome: AdminWelcome,
}

impl AdminClient {
    /// Connects to `server`, trusting only the certificate in `cert`, and logs in.
    pub async fn connect_with_files(
        server: SocketAddr,
        cert: &Path,
        token: &str,
    ) -> anyhow::Result<Self> {
        let der = std::fs::read(cert).with_context(|| format!("reading {}", cert.display()))?;
        Self::connect(server, &der, token).await
    }

    /// Connects with the certificate's DER bytes and an admin token.
    pub async fn connect(server: SocketAddr, cert_der: &[u8], token: &str) -> anyhow::Result<Self> {
        Self::connect_version(server, cert_der, token, ADMIN_PROTOCOL_VERSION).await
    }

    /// Like [`Self::connect`] with any protocol version (tests).
    pub async fn connect_version(
        server: SocketAddr,
        cert_der: &[u8],
        token: &str,
        version: u32,
    ) -> anyhow::Result<Self> {
        let bind: SocketAddr = if server.is_ipv6() {
            "[::]:0"
        } else {
            "0.0.0.0:0"
        }
        .parse()
        .expect("literal");
        let mut endpoint = quinn::Endpoint::client(bind).context("binding a UDP socket")?;
        endpoint.set_default_client_config(client_config_pinned_with_alpn(cert_der, ADMIN_ALPN)?);
        let login = async {
            let conn = endpoint
                .connect(server, "localhost")?
                .await
                .with_context(|| format!("connecting to {server}"))?;
            let (send, recv) = conn.open_bi().await?;
            let mut c = AdminClient {
                endpoint: endpoint.clone(),
                conn,
                send,
                reader: FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient)),
                welcome: AdminWelcome {
                    admin: String::new(),
                    last_seq: 0,
                    world_seed: 0,
                    generator_version: 0,
                },
            };
            let hello = AdminRequest::Hello(AdminHello {
                protocol_version: version,
                token: token.to_string(),
            });
            match c.request(&hello).await? {
                AdminResponse::Welcome(w) => c.welcome = w,
                other => bail!("expected Welcome, got {other:?}"),
            }
            anyhow::Ok(c)
        };
        tokio::time::timeout(REMOTE_TIMEOUT, login)
            .await
            .context("timed out logging in")?
    }

    pub fn welcome(&self) -> &AdminWelcome {
        &self.welcome
    }

    /// Sends one request (no wait).
    pub async fn send(&mut self, req: &AdminRequest) -> anyhow::Result<()> {
        let frame = encode_frame(req, Direction::ClientToServer)?;
        self.send
            .write_all(&frame)
            .await
            .map_err(|e| self.gone(e.into()))
    }

    /// The next response. A server `Error` (or a close with a reason)
    /// becomes an error naming the code.
    pub async fn next(&mut self) -> anyhow::Result<AdminResponse> {
        match self.reader.next::<AdminResponse>().await {
            Ok(Some(AdminResponse::Error { code, message })) => {
                bail!("server refused ({code:?}): {message}")
            }
            Ok(Some(r)) => Ok(r),
            Ok(None) => Err(self.gone(anyhow::anyhow!("the server ended the stream"))),
            Err(e) => Err(self.gone(e.into())),
        }
    }

    /// Sends a request and waits for its response (a list answer's parts
    /// joined into one).
    pub async fn request(&mut self, req: &AdminRequest) -> anyhow::Result<AdminResponse> {
        self.send(req).await?;
        let mut joiner = Joiner::default();
        loop {
            let msg = tokio::time::timeout(REMOTE_TIMEOUT, self.next())
                .await
                .context("timed out waiting for the server")??;
            if let Some(whole) = joiner.push(msg)? {
                return Ok(whole);
            }
        }
    }

    /// The close reason, if the server closed the connection with one.
    fn gone(&self, fallback: anyhow::Error) -> anyhow::Error {
        if let Some(quinn::ConnectionError::ApplicationClosed(a)) = self.conn.close_reason() {
            if let Some(code) = ErrorCode::from_close_code(a.error_code.into_inner()) {
                return anyhow::anyhow!(
                    "server refused ({code:?}): {}",
                    String::from_utf8_lossy(&a.reason)
                );
            }
        }
        fallback
    }

    /// Closes politely.
    pub async fn close(mut self) {
        let _ = self.send.finish();
        self.conn.close(quinn::VarInt::from_u32(0), b"bye");
        let _ = tokio::time::timeout(Duration::from_secs(2), self.endpoint.wait_idle()).await;
    }
}

/// Connects for a command's online form.
pub async fn connect_target(
    server: SocketAddr,
    cert: &Path,
    token: &str,
) -> anyhow::Result<AdminClient> {
    AdminClient::connect_with_files(server, cert, token).await
}

/// Connects, sends one request, and returns its accepted answer.
pub fn request_once(
    server: SocketAddr,
    cert: &Path,
    token: &str,
    req: &AdminRequest,
) -> anyhow::Result<AdminResponse> {
    block_on(async move {
        let mut c = connect_target(server, cert, token).await?;
        let r = accepted(c.request(req).await?)?;
        c.close().await;
        Ok(r)
    })
}

/// Turns a `Refused` answer into an error, passing others through.
pub fn accepted(r: AdminResponse) -> anyhow::Result<AdminResponse> {
    match r {
        AdminResponse::Refused { message } => bail!("server refused the request: {message}"),
        other => Ok(other),
    }
}
