//! `[net] ack_delay_max_ms` reaches clients as QUIC ACK_FREQUENCY. Over a
//! link with a real RTT (the client's sends held 60 ms by its delayed
//! socket), a client of a server that asks acknowledges far fewer of the
//! server's packets than a client of one that asks nothing.
//!
//! Real quinn on 127.0.0.1 with the server's own `server_config`, and the
//! client library's delayed endpoint.

use std::time::Duration;

use strata_client_sim::client::client_endpoint_delayed;
use strata_client_sim::tls::client_config_pinned;
use strata_server::config::{NetSection, TlsSection};
use strata_server::tls::{server_config, CertPair};

/// The client's one-way send delay: the RTT both ends measure.
const LINK: Duration = Duration::from_millis(60);
/// Server packets sent, one small write each.
const PACKETS: usize = 150;
/// Spacing of the writes: well under the RTT, so one ACK can cover many.
const SPACING: Duration = Duration::from_millis(4);
/// The whole exchange, both servers.
const LIMIT: Duration = Duration::from_secs(30);

/// What the client saw: ACK frames it sent, datagrams it received, and
/// its RTT estimate.
struct Seen {
    acks: u64,
    received: u64,
    rtt: Duration,
}

async fn exchange(net: NetSection) -> Seen {
    let pair = CertPair::generate(&[]).unwrap();
    let config = server_config(&pair, &net, &TlsSection::default()).unwrap();
    let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = server.local_addr().unwrap();
    let sender = tokio::spawn(async move {
        let conn = server.accept().await.unwrap().await.unwrap();
        // Let the handshake settle and the RTT estimate form first.
        tokio::time::sleep(4 * LINK).await;
        let mut s = conn.open_uni().await.unwrap();
        for i in 0..PACKETS {
            s.write_all(&[i as u8; 64]).await.unwrap();
            tokio::time::sleep(SPACING).await;
        }
        s.finish().unwrap();
        conn.closed().await;
        server.wait_idle().await;
    });

    let endpoint = client_endpoint_delayed(addr, LINK).unwrap();
    let client = client_config_pinned(pair.cert_der().as_ref()).unwrap();
    let conn = endpoint
        .connect_with(client, addr, "localhost")
        .unwrap()
        .await
        .unwrap();
    let mut r = conn.accept_uni().await.unwrap();
    let data = r.read_to_end(1 << 20).await.unwrap();
    assert_eq!(data.len(), PACKETS * 64, "every byte arrives");
    let stats = conn.stats();
    let seen = Seen {
        acks: stats.frame_tx.acks,
        received: stats.udp_rx.datagrams,
        rtt: conn.rtt(),
    };
    conn.close(0u32.into(), b"done");
    sender.await.unwrap();
    endpoint.wait_idle().await;
    seen
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_acknowledge_less_when_the_server_asks() {
    tokio::time::timeout(LIMIT, async {
        let plain = exchange(NetSection::default()).await;
        let asked = exchange(NetSection {
            ack_delay_max_ms: 200,
            ack_eliciting_threshold: 9,
            ..NetSection::default()
        })
        .await;
        for (name, s) in [("plain", &plain), ("asked", &asked)] {
            eprintln!(
                "{name}: {} ACK frames for {} datagrams received, rtt {:?}",
                s.acks, s.received, s.rtt
            );
            assert!(s.rtt >= LINK, "{name}: the delayed link sets the RTT");
            assert!(s.received >= PACKETS as u64 / 2, "{name}: packets arrive");
        }
        // QUIC's own rule acknowledges every second packet (or within
        // 25 ms); asked for 60 ms and ten packets, the client sends a
        // fraction of that.
        assert!(
            asked.acks * 2 < plain.acks,
            "asked {} ACKs against plain {}",
            asked.acks,
            plain.acks
        );
    })
    .await
    .expect("the exchanges finish in time");
}
