//! Real QUIC over loopback: a pinned client talks to the server config; a
//! client pinning another certificate, expecting another name or offering
//! another ALPN is refused. Every await is bounded by a timeout.

use std::net::SocketAddr;
use std::time::Duration;

use quinn::crypto::rustls::HandshakeData;
use quinn::{ClientConfig, Connection, ConnectionError, Endpoint};
use strata_client_sim::tls::{client_config_pinned, client_config_pinned_with_alpn};
use strata_protocol::ALPN;
use strata_server::config::{NetSection, TlsSection};
use strata_server::tls::{server_config, CertPair};

/// Upper bound on any single network step of these tests.
const STEP: Duration = Duration::from_secs(10);

/// Starts a server that answers each bidi stream with "pong:" + request.
fn start_server(pair: &CertPair, tls: &TlsSection) -> (Endpoint, SocketAddr) {
    let config = server_config(pair, &NetSection::default(), tls).unwrap();
    let endpoint = Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = endpoint.local_addr().unwrap();
    let server = endpoint.clone();
    tokio::spawn(async move {
        while let Some(incoming) = server.accept().await {
            tokio::spawn(async move {
                let Ok(conn) = incoming.await else { return };
                while let Ok((mut send, mut recv)) = conn.accept_bi().await {
                    let Ok(req) = recv.read_to_end(1024).await else {
                        return;
                    };
                    let mut reply = b"pong:".to_vec();
                    reply.extend_from_slice(&req);
                    let _ = send.write_all(&reply).await;
                    let _ = send.finish();
                }
            });
        }
    });
    (endpoint, addr)
}

async fn connect(
    config: ClientConfig,
    addr: SocketAddr,
    name: &str,
) -> Result<Connection, ConnectionError> {
    let mut client = Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    client.set_default_client_config(config);
    let connecting = client.connect(addr, name).unwrap();
    tokio::time::timeout(STEP, connecting)
        .await
        .expect("handshake timed out")
}

async fn ping(conn: &Connection, msg: &[u8]) -> Vec<u8> {
    tokio::time::timeout(STEP, async {
        let (mut send, mut recv) = conn.open_bi().await.unwrap();
        send.write_all(msg).await.unwrap();
        send.finish().unwrap();
        recv.read_to_end(1024).await.unwrap()
    })
    .await
    .expect("exchange timed out")
}

/// The client's verifier (not a timeout or a server error) refused the cert.
fn assert_certificate_refused(err: &ConnectionError, why: &str) {
    let ConnectionError::TransportError(e) = err else {
        panic!("expected a local TLS failure, got {err:?}");
    };
    let text = e.to_string();
    assert!(
        text.contains("invalid peer certificate") && text.contains(why),
        "{text}"
    );
}

#[tokio::test]
async fn pinned_client_connects_and_exchanges_a_message() {
    let pair = CertPair::generate(&["strata.example".into()]).unwrap();
    let (_server, addr) = start_server(&pair, &TlsSection::default());
    let config = client_config_pinned(pair.cert_der().as_ref()).unwrap();
    for name in ["localhost", "127.0.0.1", "strata.example"] {
        let conn = connect(config.clone(), addr, name).await.unwrap();
        let alpn = conn
            .handshake_data()
            .unwrap()
            .downcast::<HandshakeData>()
            .unwrap()
            .protocol;
        assert_eq!(alpn.as_deref(), Some(ALPN));
        assert_eq!(ping(&conn, b"hello").await, b"pong:hello");
    }
}

#[tokio::test]
async fn segmentation_offload_can_be_disabled() {
    let pair = CertPair::generate(&[]).unwrap();
    let tls = TlsSection {
        enable_segmentation_offload: false,
        ..TlsSection::default()
    };
    let (_server, addr) = start_server(&pair, &tls);
    let config = client_config_pinned(pair.cert_der().as_ref()).unwrap();
    let conn = connect(config, addr, "localhost").await.unwrap();
    assert_eq!(ping(&conn, b"no-gso").await, b"pong:no-gso");
}

#[tokio::test]
async fn only_one_bidi_stream_at_a_time() {
    let pair = CertPair::generate(&[]).unwrap();
    let (_server, addr) = start_server(&pair, &TlsSection::default());
    let conn = connect(
        client_config_pinned(pair.cert_der().as_ref()).unwrap(),
        addr,
        "localhost",
    )
    .await
    .unwrap();
    // Hold the control stream open (not finished) so the server keeps it.
    let (mut first, mut first_recv) = tokio::time::timeout(STEP, conn.open_bi())
        .await
        .unwrap()
        .unwrap();
    first.write_all(b"x").await.unwrap();
    let second = tokio::time::timeout(Duration::from_millis(300), conn.open_bi()).await;
    assert!(
        second.is_err(),
        "a second concurrent bidi stream was allowed"
    );

    // Once the first stream is done, the server grants credit for another.
    first.finish().unwrap();
    let reply = tokio::time::timeout(STEP, first_recv.read_to_end(1024))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(reply, b"pong:x");
    assert_eq!(ping(&conn, b"again").await, b"pong:again");
}

#[tokio::test]
async fn client_pinning_another_certificate_is_refused() {
    let pair = CertPair::generate(&[]).unwrap();
    let impostor = CertPair::generate(&[]).unwrap();
    let (_server, addr) = start_server(&pair, &TlsSection::default());
    let config = client_config_pinned(impostor.cert_der().as_ref()).unwrap();
    let err = connect(config, addr, "localhost").await.unwrap_err();
    assert_certificate_refused(&err, "BadSignature");
}

#[tokio::test]
async fn name_outside_the_certificate_is_refused() {
    let pair = CertPair::generate(&[]).unwrap();
    let (_server, addr) = start_server(&pair, &TlsSection::default());
    let config = client_config_pinned(pair.cert_der().as_ref()).unwrap();
    let err = connect(config, addr, "other.example").await.unwrap_err();
    assert_certificate_refused(&err, "not valid for name");
}

#[tokio::test]
async fn wrong_alpn_is_refused() {
    let pair = CertPair::generate(&[]).unwrap();
    let (_server, addr) = start_server(&pair, &TlsSection::default());
    let config = client_config_pinned_with_alpn(pair.cert_der().as_ref(), b"h3").unwrap();
    let err = connect(config, addr, "localhost").await.unwrap_err();
    assert!(
        matches!(err, ConnectionError::ConnectionClosed(_)),
        "unexpected error {err:?}"
    );
}
