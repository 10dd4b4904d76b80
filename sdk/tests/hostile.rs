//! The C ABI against a server that breaks the protocol: a real QUIC
//! endpoint on 127.0.0.1 with the server's TLS config, which greets the
//! client as Strata would, then sends chunks no view covers. The session
//! ends with DISCONNECTED (a protocol violation) instead of generating and
//! holding whatever it is sent.

use crate::common::ffi::{connect_with, last_error, poll, stats};

use std::ffi::CStr;
use std::ptr::null_mut;
use std::time::{Duration, Instant};

use strata::*;
use strata_protocol::{encode_frame, Direction, Role, ServerMessage, Start, Welcome, WorldUpdate};
use strata_server::config::{NetSection, TlsSection};
use strata_server::tls::{server_config, CertPair};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Chunk, ChunkPos, Voxel};
use tokio::sync::oneshot;

/// The longest any step waits.
const WAIT: Duration = Duration::from_secs(20);

/// A Welcome of view radius `view_radius` with these generator parameters.
fn welcome(view_radius: u8, world_seed: u64, generator_params: String) -> ServerMessage {
    ServerMessage::Welcome(Welcome {
        session: 1,
        player: "p".into(),
        role: Role::Player,
        world_seed,
        generator_version: strata_terrain::gen::GENERATOR_VERSION,
        generator_params,
        server_time: 0,
        view_radius,
        last_seq: 0,
        start: Start::Spawn {
            x: 0,
            z: 0,
            radius: 8,
        },
    })
}

/// A hostile server: greets one client with `greeting`, writes `first` on
/// its updates stream, then `then` once `go` fires; keeps the connection
/// until the client ends it.
struct Hostile {
    /// Kept: the server's task runs on it.
    _runtime: tokio::runtime::Runtime,
    addr: String,
    cert: Vec<u8>,
    go: Option<oneshot::Sender<()>>,
}

impl Hostile {
    fn start(greeting: ServerMessage, first: Vec<WorldUpdate>, then: Vec<WorldUpdate>) -> Self {
        Self::start_with(&NetSection::default(), greeting, first, then)
    }

    /// [`Self::start`] with `net`'s transport settings. It reads nothing
    /// on the control stream past the Hello.
    fn start_with(
        net: &NetSection,
        greeting: ServerMessage,
        first: Vec<WorldUpdate>,
        then: Vec<WorldUpdate>,
    ) -> Self {
        let runtime = tokio::runtime::Runtime::new().unwrap();
        let pair = CertPair::generate(&[]).unwrap();
        let config = server_config(&pair, net, &TlsSection::default()).unwrap();
        let _guard = runtime.enter();
        let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
        let addr = server.local_addr().unwrap().to_string();
        let (go, went) = oneshot::channel();
        runtime.spawn(async move {
            let conn = server.accept().await.unwrap().await.unwrap();
            let (mut control, mut hello) = conn.accept_bi().await.unwrap();
            // The Hello, whatever it says.
            let mut buf = [0u8; 4096];
            let _ = hello.read(&mut buf).await.unwrap();
            let frame = encode_frame(&greeting, Direction::ServerToClient).unwrap();
            control.write_all(&frame).await.unwrap();
            let mut out = conn.open_uni().await.unwrap();
            let write = |updates: Vec<WorldUpdate>| {
                let mut bytes = Vec::new();
                for u in updates {
                    bytes.extend(encode_frame(&u, Direction::ServerToClient).unwrap());
                }
                bytes
            };
            let _ = out.write_all(&write(first)).await;
            if went.await.is_ok() {
                let _ = out.write_all(&write(then)).await;
            }
            let _ = tokio::time::timeout(WAIT, conn.closed()).await;
        });
        Hostile {
            _runtime: runtime,
            addr,
            cert: pair.cert_der().to_vec(),
            go: Some(go),
        }
    }

    fn connect(&self) -> *mut StrataSession {
        let options = StrataConnectOptions {
            size: std::mem::size_of::<StrataConnectOptions>() as u32,
            predict: 0,
            capabilities: 0,
        };
        connect_with(&self.addr, &self.cert, "token", &options)
    }
}

fn message(ev: &StrataEvent) -> String {
    let bytes: Vec<u8> = ev.message.iter().map(|&c| c as u8).collect();
    CStr::from_bytes_until_nul(&bytes)
        .unwrap()
        .to_string_lossy()
        .into_owned()
}

/// Polls until `stop` picks an event or the stats out, or [`WAIT`] passes;
/// returns the DISCONNECTED event, if one came.
fn run_until(
    s: *mut StrataSession,
    mut stop: impl FnMut(&StrataEvent, &StrataStats) -> bool,
) -> Option<StrataEvent> {
    let start = Instant::now();
    while start.elapsed() < WAIT {
        let ev = poll(s);
        if ev.kind == StrataEventKind::Disconnected {
            return Some(ev);
        }
        if stop(&ev, &stats(s)) {
            return None;
        }
        if ev.kind == StrataEventKind::None {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    None
}

#[test]
fn a_chunk_outside_the_world_ends_the_session_and_is_never_held() {
    // Parameters the client can run: a `Generated` would be generated.
    let seed = 7;
    let far = ChunkPos::new(1 << 26, 0, 0);
    let server = Hostile::start(
        welcome(2, seed, format!("seed = {seed}\n")),
        vec![WorldUpdate::Generated { pos: far }],
        Vec::new(),
    );
    let s = server.connect();
    let ended = run_until(s, |_, st| st.chunks_held > 0);
    // Not held, so not meshed (an origin past i32 once panicked here).
    let mut mesh = null_mut();
    // SAFETY: `s` is live; `mesh` is writable.
    let st = unsafe { strata_mesh(s, far.x, far.y, far.z, 0, 0, &mut mesh) };
    assert_eq!(st, StrataStatus::NotHeld, "{}", last_error());
    let held = stats(s);
    assert_eq!((held.chunks_held, held.generated), (0, 0));
    let ev = ended.expect("the session ended");
    assert_eq!(ev.error_code, 0, "the client ended it, not the server");
    let why = message(&ev);
    assert!(
        why.starts_with("protocol violation: ") && why.contains("outside the world"),
        "{why}"
    );
    // SAFETY: `s` is live and nothing else uses it.
    unsafe { strata_session_free(s) };
}

#[test]
fn chunks_past_what_any_view_covers_end_the_session() {
    // Radius 0 in a world one chunk row tall: 33 x 33 chunks at most
    // (the radius plus the largest hysteresis, 16, on each side).
    let max = 33 * 33;
    let air = Chunk::uniform(Voxel::AIR);
    let snapshot = |x: i32, z: i32| WorldUpdate::Snapshot {
        pos: ChunkPos::new(x, 0, z),
        version: 1,
        hash: chunk_hash(&air),
        mesh_hash: 0,
        data: encode_chunk(&air),
    };
    let mut first: Vec<WorldUpdate> = (-16..=16)
        .flat_map(|z| (-16..=16).map(move |x| (x, z)))
        .map(|(x, z)| snapshot(x, z))
        .collect();
    assert_eq!(first.len(), max);
    // A marker: the client has taken every chunk before it.
    let center = ChunkPos::new(0, 0, 0);
    first.push(WorldUpdate::InterestComplete { center, radius: 0 });
    let mut server = Hostile::start(
        welcome(0, 1, "min_y = 0\nmax_y = 31\n".into()),
        first,
        vec![snapshot(17, 0)],
    );
    let s = server.connect();
    let ended = run_until(s, |ev, _| ev.kind == StrataEventKind::ViewLoaded);
    assert!(ended.is_none(), "a full view is no violation: {ended:?}");
    assert_eq!(stats(s).chunks_held, max as u64);
    // One chunk more than any view of this server covers.
    server.go.take().unwrap().send(()).unwrap();
    let ev = run_until(s, |_, st| st.chunks_held > max as u64).expect("the session ended");
    let why = message(&ev);
    assert!(
        why.starts_with("protocol violation: ") && why.contains(&format!("the {max} chunks")),
        "{why}"
    );
    assert_eq!(stats(s).chunks_held, max as u64);
    // SAFETY: `s` is live and nothing else uses it.
    unsafe { strata_session_free(s) };
}

/// A server that stops reading the control stream (it grants no more
/// stream credit) fails the client's requests once `SEND_TIMEOUT` passes,
/// each unsent, instead of holding the caller for good (a cluster
/// session's dispatcher, which serves every node, included).
#[test]
fn a_server_that_stops_reading_fails_requests_instead_of_holding_them() {
    use strata_client::client::{ClientError, SEND_TIMEOUT};
    let net = NetSection {
        stream_receive_window: 1024,
        ..NetSection::default()
    };
    let seed = 7;
    let server = Hostile::start_with(
        &net,
        welcome(2, seed, format!("seed = {seed}\n")),
        Vec::new(),
        Vec::new(),
    );
    let runtime = tokio::runtime::Runtime::new().unwrap();
    runtime.block_on(async {
        let addr = server.addr.parse().unwrap();
        let client = strata_client::Client::connect(addr, &server.cert, "token")
            .await
            .unwrap();
        let edit =
            strata_client::edits::mine(strata_client::glam::DVec3::new(0.0, 10.0, 0.0), 1.0, 60)
                .unwrap();
        let mut sent = 0;
        let err = loop {
            let started = Instant::now();
            let submitted = tokio::time::timeout(WAIT, client.submit(edit.clone()))
                .await
                .expect("a request held past WAIT");
            match submitted {
                Ok(_) => sent += 1,
                Err(e) => {
                    assert!(started.elapsed() >= SEND_TIMEOUT);
                    break e;
                }
            }
            assert!(sent < 100_000, "the window never filled");
        };
        assert!(matches!(err, ClientError::Timeout(_)), "{err}");
        assert!(sent >= strata_client::client::CONTROL_QUEUE, "{sent}");
    });
}
