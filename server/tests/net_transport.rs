//! The server's `[net]` transport knobs over real quinn on 127.0.0.1, with
//! the server's own `server_config`:
//! - `ack_delay_max_ms` reaches clients as QUIC ACK_FREQUENCY. Over a link
//!   with a real RTT (the client's sends held 60 ms by its delayed socket),
//!   a client of a server that asks acknowledges far fewer of the server's
//!   packets than a client of one that asks nothing.
//! - `send_interval_ms`: the updates writer writes at most once per
//!   interval, so frames queued meanwhile share packets.

use std::future::Future;
use std::time::Duration;

use bytes::Bytes;
use strata_client_sim::client::client_endpoint_delayed;
use strata_client_sim::tls::client_config_pinned;
use strata_server::config::{NetSection, TlsSection};
use strata_server::net::writer::spawn_writer;
use strata_server::tls::{server_config, CertPair};

/// The client's one-way send delay in the ACK test: the RTT both ends
/// measure.
const LINK: Duration = Duration::from_millis(60);
/// Server packets sent in the ACK test, one small write each.
const PACKETS: usize = 150;
/// Spacing of the ACK test's writes: well under the RTT, so one ACK can
/// cover many.
const SPACING: Duration = Duration::from_millis(4);
/// Frames queued in the interval test, one every [`FRAME_SPACING`].
const FRAMES: usize = 40;
const FRAME_SPACING: Duration = Duration::from_millis(5);
/// Each test, all its exchanges.
const LIMIT: Duration = Duration::from_secs(30);

/// What the client saw of one exchange.
struct Seen {
    data: Vec<u8>,
    stats: quinn::ConnectionStats,
    rtt: Duration,
}

/// One connection to a server configured by `net`: `serve` gets the
/// server's side and writes a uni stream; the client, whose sends leave
/// `link` late, reads it to the end.
async fn exchange<F, Fut>(net: NetSection, link: Duration, serve: F) -> Seen
where
    F: FnOnce(quinn::Connection, NetSection) -> Fut + Send + 'static,
    Fut: Future<Output = ()> + Send,
{
    let pair = CertPair::generate(&[]).unwrap();
    let config = server_config(&pair, &net, &TlsSection::default()).unwrap();
    let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = server.local_addr().unwrap();
    let sender = tokio::spawn(async move {
        let conn = server.accept().await.unwrap().await.unwrap();
        serve(conn.clone(), net).await;
        conn.closed().await;
        server.wait_idle().await;
    });

    let endpoint = client_endpoint_delayed(addr, link).unwrap();
    let client = client_config_pinned(pair.cert_der().as_ref()).unwrap();
    let conn = endpoint
        .connect_with(client, addr, "localhost")
        .unwrap()
        .await
        .unwrap();
    let mut r = conn.accept_uni().await.unwrap();
    let data = r.read_to_end(1 << 20).await.unwrap();
    let seen = Seen {
        data,
        stats: conn.stats(),
        rtt: conn.rtt(),
    };
    conn.close(0u32.into(), b"done");
    sender.await.unwrap();
    endpoint.wait_idle().await;
    seen
}

/// [`PACKETS`] small writes, [`SPACING`] apart, once the RTT is known.
async fn spaced_writes(conn: quinn::Connection, _net: NetSection) {
    tokio::time::sleep(4 * LINK).await;
    let mut s = conn.open_uni().await.unwrap();
    for i in 0..PACKETS {
        s.write_all(&[i as u8; 64]).await.unwrap();
        tokio::time::sleep(SPACING).await;
    }
    s.finish().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_acknowledge_less_when_the_server_asks() {
    tokio::time::timeout(LIMIT, async {
        let plain = exchange(NetSection::default(), LINK, spaced_writes).await;
        let net = NetSection {
            ack_delay_max_ms: 200,
            ack_eliciting_threshold: 9,
            ..NetSection::default()
        };
        let asked = exchange(net, LINK, spaced_writes).await;
        for (name, s) in [("plain", &plain), ("asked", &asked)] {
            let received = s.stats.udp_rx.datagrams;
            let acks = s.stats.frame_tx.acks;
            eprintln!(
                "{name}: {acks} ACK frames for {received} datagrams, rtt {:?}",
                s.rtt
            );
            assert_eq!(s.data.len(), PACKETS * 64, "{name}: every byte arrives");
            assert!(s.rtt >= LINK, "{name}: the delayed link sets the RTT");
        }
        // QUIC's own rule acknowledges every second packet (or within
        // 25 ms); asked for 60 ms and ten packets, the client sends a
        // fraction of that.
        let (asked, plain) = (asked.stats.frame_tx.acks, plain.stats.frame_tx.acks);
        assert!(
            asked * 2 < plain,
            "asked {asked} ACKs against plain {plain}"
        );
    })
    .await
    .expect("the exchanges finish in time");
}

/// [`FRAMES`] frames queued [`FRAME_SPACING`] apart on the server's
/// updates writer, holding `interval` between writes.
async fn queued_frames(interval: Duration) -> Seen {
    let serve = move |conn: quinn::Connection, net: NetSection| async move {
        let uni = conn.open_uni().await.unwrap();
        let queue = (net.writer_queue, net.writer_queue_bytes);
        let (tx, task) = spawn_writer(uni, queue, interval, "updates");
        for i in 0..FRAMES {
            tx.try_send(Bytes::from(vec![i as u8; 32])).unwrap();
            tokio::time::sleep(FRAME_SPACING).await;
        }
        drop(tx);
        task.await.unwrap();
    };
    exchange(NetSection::default(), Duration::ZERO, serve).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_interval_gathers_a_sessions_frames_into_fewer_writes() {
    tokio::time::timeout(LIMIT, async {
        let each = queued_frames(Duration::ZERO).await;
        let gathered = queued_frames(Duration::from_millis(60)).await;
        let want: Vec<u8> = (0..FRAMES).flat_map(|i| [i as u8; 32]).collect();
        assert_eq!(each.data, want, "every frame arrives, in order");
        assert_eq!(gathered.data, want, "every frame arrives, in order");
        let (each, gathered) = (each.stats.frame_rx.stream, gathered.stats.frame_rx.stream);
        eprintln!("{each} STREAM frames at once, {gathered} with a 60 ms interval");
        // 40 frames over 200 ms: about one write each at once, and about
        // five with 60 ms between writes.
        assert!(each >= FRAMES as u64 / 2, "{each}");
        assert!(gathered * 3 <= each, "{gathered} against {each}");
    })
    .await
    .expect("the exchanges finish in time");
}

/// What any server may make a client hold: one unidirectional stream (the
/// updates), no bidirectional one, datagrams of a packet at most. A
/// second stream the server tries to open waits for credit the client
/// never gives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_lets_a_server_open_one_stream_and_no_more() {
    tokio::time::timeout(LIMIT, async {
        let pair = CertPair::generate(&[]).unwrap();
        let config = server_config(&pair, &NetSection::default(), &TlsSection::default()).unwrap();
        let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
        let addr = server.local_addr().unwrap();
        let endpoint = client_endpoint_delayed(addr, Duration::ZERO).unwrap();
        let client = client_config_pinned(pair.cert_der().as_ref()).unwrap();
        let connecting = endpoint.connect_with(client, addr, "localhost").unwrap();
        let conn = server.accept().await.unwrap().await.unwrap();
        let client_conn = connecting.await.unwrap();

        let wait = Duration::from_millis(500);
        let mut first = conn.open_uni().await.expect("the updates stream");
        first.write_all(b"x").await.unwrap();
        assert!(
            tokio::time::timeout(wait, conn.open_uni()).await.is_err(),
            "a second unidirectional stream was granted"
        );
        assert!(
            tokio::time::timeout(wait, conn.open_bi()).await.is_err(),
            "a bidirectional stream was granted"
        );
        let most = strata_protocol::client_tls::CLIENT_DATAGRAM_BUFFER;
        assert!(
            conn.max_datagram_size().is_some_and(|n| n <= most),
            "datagrams to the client: {:?}",
            conn.max_datagram_size()
        );
        drop(client_conn);
    })
    .await
    .expect("within the limit");
}
