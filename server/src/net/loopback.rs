//! Tests' QUIC connections on loopback: a real endpoint pair.

use std::sync::Arc;

use crate::config::{NetSection, TlsSection};
use crate::tls::{server_config, CertPair};

/// A connected pair on 127.0.0.1: the server's side, the client's side,
/// and both endpoints (kept alive by the caller). `client_transport`
/// replaces the client's transport settings.
pub async fn pair(
    client_transport: Option<quinn::TransportConfig>,
) -> (
    quinn::Connection,
    quinn::Connection,
    (quinn::Endpoint, quinn::Endpoint),
) {
    let certs = CertPair::generate(&[]).unwrap();
    let config = server_config(&certs, &NetSection::default(), &TlsSection::default()).unwrap();
    let server = quinn::Endpoint::server(config, "127.0.0.1:0".parse().unwrap()).unwrap();
    let addr = server.local_addr().unwrap();
    let mut client_cfg =
        strata_protocol::client_tls::client_config_pinned(certs.cert_der()).unwrap();
    if let Some(t) = client_transport {
        client_cfg.transport_config(Arc::new(t));
    }
    let mut client = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    client.set_default_client_config(client_cfg);
    let connecting = client.connect(addr, "localhost").unwrap();
    // The handshake goes on only once the server takes the attempt.
    let (server_conn, conn) = tokio::join!(
        async { server.accept().await.unwrap().await.unwrap() },
        connecting
    );
    (server_conn, conn.unwrap(), (server, client))
}
