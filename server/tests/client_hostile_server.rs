//! The client library against a server that breaks the protocol: a real
//! QUIC endpoint on 127.0.0.1 with the server's TLS config, which greets
//! the client as Strata would and then sends what no Strata server sends.
//! The client ends the connection rather than doing the server's bidding.

use std::time::Duration;

use strata_client_sim::{Client, ClientOptions};
use strata_protocol::{
    encode_frame, Direction, OpUpdate, Role, ServerMessage, Start, Welcome, WorldUpdate,
};
use strata_server::config::{NetSection, TlsSection};
use strata_server::tls::{server_config, CertPair};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{ChunkPos, Edit};

/// Each exchange, all of it.
const LIMIT: Duration = Duration::from_secs(30);

/// How long a client that keeps the connection is watched.
const KEPT: Duration = Duration::from_secs(2);

/// A server that welcomes one client, then writes `updates` on its
/// updates stream; returns whether the client closed the connection
/// within `wait`.
async fn hostile(updates: Vec<WorldUpdate>, opts: ClientOptions, wait: Duration) -> bool {
    let pair = CertPair::generate(&[]).unwrap();
    let config = server_config(&pair, &NetSection::default(), &TlsSection::default()).unwrap();
    let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = server.local_addr().unwrap();
    let serving = tokio::spawn(async move {
        let conn = server.accept().await.unwrap().await.unwrap();
        let (mut control, mut hello) = conn.accept_bi().await.unwrap();
        // The Hello, whatever it says.
        let mut buf = [0u8; 4096];
        let _ = hello.read(&mut buf).await.unwrap();
        let welcome = ServerMessage::Welcome(Welcome {
            session: 1,
            player: "p".into(),
            role: Role::Player,
            world_seed: 1,
            generator_version: 1,
            generator_params: String::new(),
            server_time: 0,
            view_radius: 2,
            last_seq: 0,
            start: Start::Spawn {
                x: 0,
                z: 0,
                radius: 8,
            },
        });
        let frame = encode_frame(&welcome, Direction::ServerToClient).unwrap();
        control.write_all(&frame).await.unwrap();
        let mut out = conn.open_uni().await.unwrap();
        for u in updates {
            let frame = encode_frame(&u, Direction::ServerToClient).unwrap();
            if out.write_all(&frame).await.is_err() {
                break;
            }
        }
        let _ = tokio::time::timeout(LIMIT, conn.closed()).await;
        server.wait_idle().await;
    });
    let client = Client::connect_opts(addr, pair.cert_der().as_ref(), "token", opts)
        .await
        .unwrap();
    let closed = tokio::time::timeout(wait, client.closed()).await.is_ok();
    drop(client);
    serving.abort();
    closed
}

fn op() -> WorldUpdate {
    let at = |v: f64| Fixed::from_f64(v).unwrap();
    WorldUpdate::Op(OpUpdate {
        seq: 1,
        edit: Edit::Explode {
            center: FixedVec3::new(at(0.0), at(0.0), at(0.0)),
            radius: at(16.0),
            power: 255,
        },
        chunks: Vec::new(),
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_op_to_a_client_that_did_not_ask_for_ops_ends_the_connection() {
    assert!(hostile(vec![op()], ClientOptions::default(), LIMIT).await);
    // A client that asked for ops keeps the connection.
    let replaying = ClientOptions {
        capabilities: strata_protocol::CAP_OP_REPLAY,
        ..ClientOptions::default()
    };
    assert!(!hostile(vec![op()], replaying, KEPT).await);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsubscribe_past_the_protocol_cap_ends_the_connection() {
    let max = strata_protocol::limits::MAX_UNSUBSCRIBED_PER_UPDATE;
    let many = |n: usize| {
        let chunks = (0..n as i32).map(|i| ChunkPos::new(i, 0, 0)).collect();
        vec![WorldUpdate::UnsubscribedMany { chunks }]
    };
    assert!(hostile(many(max + 1), ClientOptions::default(), LIMIT).await);
    assert!(!hostile(many(max), ClientOptions::default(), KEPT).await);
}
