//! The client library against a server that breaks the protocol: a real
//! QUIC endpoint on 127.0.0.1 with the server's TLS config, which greets
//! the client as Strata would and then sends what no Strata server sends.
//! The client ends the connection rather than doing the server's bidding.

use std::time::Duration;

use strata_client_sim::{Client, ClientOptions, ClusterClient, JoinRate};
use strata_protocol::{
    encode_frame, ChunkVersion, Direction, OpUpdate, RegionHolder, RegionOwner, Role,
    ServerMessage, Start, Welcome, WorldUpdate,
};
use strata_server::config::{NetSection, TlsSection};
use strata_server::tls::{server_config, CertPair};
use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::{ChunkPos, Edit};

/// Each exchange, all of it.
const LIMIT: Duration = Duration::from_secs(30);

/// How long a client that keeps the connection is watched.
const KEPT: Duration = Duration::from_secs(2);

/// A QUIC endpoint on 127.0.0.1 with the server's TLS, and its cert.
fn endpoint() -> (quinn::Endpoint, CertPair) {
    let pair = CertPair::generate(&[]).unwrap();
    let config = server_config(&pair, &NetSection::default(), &TlsSection::default()).unwrap();
    let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    (server, pair)
}

/// Accepts one client and greets it as Strata would; returns the
/// connection and its control stream.
async fn welcome(server: &quinn::Endpoint) -> (quinn::Connection, quinn::SendStream) {
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
    (conn, control)
}

/// A server that welcomes one client, then writes `updates` on its
/// updates stream; returns whether the client closed the connection
/// within `wait`.
async fn hostile(updates: Vec<WorldUpdate>, opts: ClientOptions, wait: Duration) -> bool {
    hostile_on(Vec::new(), updates, opts, wait).await
}

/// As [`hostile`], with `control` written on the control stream first.
async fn hostile_on(
    control: Vec<ServerMessage>,
    updates: Vec<WorldUpdate>,
    opts: ClientOptions,
    wait: Duration,
) -> bool {
    let (server, pair) = endpoint();
    let addr = server.local_addr().unwrap();
    let serving = tokio::spawn(async move {
        let (conn, mut control_stream) = welcome(&server).await;
        for m in control {
            let frame = encode_frame(&m, Direction::ServerToClient).unwrap();
            control_stream.write_all(&frame).await.unwrap();
        }
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_verdict_listing_more_chunks_than_any_edit_writes_ends_the_connection() {
    let max = strata_protocol::limits::MAX_EDIT_CHANGES;
    let verdict = |n: usize| {
        let changes = (0..n as i32)
            .map(|i| ChunkVersion {
                pos: ChunkPos::new(i, 0, 0),
                version: 1,
            })
            .collect();
        vec![ServerMessage::EditAccepted {
            client_edit_id: 1,
            seq: 1,
            changes,
        }]
    };
    let opts = ClientOptions::default;
    assert!(hostile_on(verdict(max + 1), Vec::new(), opts(), LIMIT).await);
    assert!(!hostile_on(verdict(max), Vec::new(), opts(), KEPT).await);
}

/// Local UDP sockets standing for hosts a hostile node names.
const VICTIMS: usize = 40;
/// Addresses each of its `RegionOwners` names (one under the client's
/// cap on nodes, which the home node takes).
const NAMED_PER_MESSAGE: usize = 7;
/// How long each of its messages stands before the next names others.
const NAMED_FOR: Duration = Duration::from_millis(400);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_naming_new_addresses_gets_no_more_handshakes_than_the_join_rate() {
    let mut victims = Vec::new();
    for _ in 0..VICTIMS {
        let v = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        victims.push(std::sync::Arc::new(v));
    }
    // Every other victim by name: a lookup, then a handshake.
    let names: Vec<String> = victims
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let port = v.local_addr().unwrap().port();
            match i % 2 {
                0 => format!("127.0.0.1:{port}"),
                _ => format!("localhost:{port}"),
            }
        })
        .collect();
    // Handshakes: the distinct (victim, sender) pairs heard from (each
    // connection attempt sends from a socket of its own).
    let heard = std::sync::Arc::new(std::sync::Mutex::new(std::collections::BTreeSet::new()));
    let listening: Vec<_> = victims
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let (v, heard) = (v.clone(), heard.clone());
            tokio::spawn(async move {
                let mut buf = [0u8; 2048];
                while let Ok((_, from)) = v.recv_from(&mut buf).await {
                    heard.lock().unwrap().insert((i, from));
                }
            })
        })
        .collect();

    // The node: every NAMED_FOR a `RegionOwners` naming 7 victims, each
    // the writer of a region around the player.
    let (server, pair) = endpoint();
    let home = server.local_addr().unwrap();
    let serving = tokio::spawn(async move {
        let (conn, mut control) = welcome(&server).await;
        for m in 0.. {
            let regions = (0..NAMED_PER_MESSAGE)
                .map(|k| RegionOwner {
                    region_x: k as i32,
                    region_z: 0,
                    holder: RegionHolder::Node {
                        node: format!("n{k}"),
                        addr: names[(m * NAMED_PER_MESSAGE + k) % VICTIMS].clone(),
                    },
                })
                .collect();
            let msg = ServerMessage::RegionOwners {
                region_chunks: 8,
                regions,
                ticket: None,
                node: "hostile".into(),
            };
            let frame = encode_frame(&msg, Direction::ServerToClient).unwrap();
            if control.write_all(&frame).await.is_err() {
                break;
            }
            tokio::time::sleep(NAMED_FOR).await;
        }
        drop(conn);
    });

    let rate = JoinRate {
        burst: 3,
        every: Duration::from_secs(1),
    };
    let opts = ClientOptions {
        join_rate: rate,
        ..ClientOptions::default()
    };
    let mut client = ClusterClient::connect(home, pair.cert_der().as_ref(), "token", opts)
        .await
        .unwrap();
    let started = std::time::Instant::now();
    let run = Duration::from_millis(3500);
    while started.elapsed() < run {
        client.follow().await.unwrap();
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    let elapsed = started.elapsed();
    drop(client);
    serving.abort();
    // A handshake's first flight leaves at once; late retransmits of one
    // already heard add nothing.
    tokio::time::sleep(Duration::from_millis(200)).await;
    for l in listening {
        l.abort();
    }
    let handshakes = heard.lock().unwrap().len();
    let allowed = rate.burst as usize + elapsed.as_secs() as usize;
    assert!(
        (2..=allowed).contains(&handshakes),
        "{handshakes} handshakes to {VICTIMS} addresses in {elapsed:?} (the rate allows {allowed})"
    );
}
