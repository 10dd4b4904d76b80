//! Client TLS: trust exactly the server's certificate (pinning), with full
//! verification still on. Used by `strata-admin`'s online commands and by
//! `strata-client` (feature `quic`).

use std::sync::Arc;
use std::time::Duration;

use crate::ALPN;
use thiserror::Error;

/// Keep-alive interval so idle sessions survive the server's idle timeout.
pub const KEEP_ALIVE: Duration = Duration::from_secs(5);
/// Bytes all of a connection's streams may hold unread at once, on the
/// client (quinn's default is unbounded): room for both streams' own
/// windows several times over.
pub const CLIENT_RECEIVE_WINDOW: u32 = 8 << 20;
/// Bytes of unread datagrams from the server a client keeps. Datagrams
/// stay enabled (quinn sends none on a connection that takes none, and
/// the client sends its positions as datagrams).
pub const CLIENT_DATAGRAM_BUFFER: usize = 2048;

#[derive(Debug, Error)]
pub enum TlsError {
    #[error("server certificate is not usable as a trust anchor: {0}")]
    BadCertificate(String),
    #[error("TLS setup failed: {0}")]
    Setup(String),
}

/// A QUIC client config that trusts only `cert_der` and speaks `strata/1`.
pub fn client_config_pinned(cert_der: &[u8]) -> Result<quinn::ClientConfig, TlsError> {
    client_config_pinned_with_alpn(cert_der, ALPN)
}

/// Like [`client_config_pinned`] with any ALPN (tests use a wrong one).
pub fn client_config_pinned_with_alpn(
    cert_der: &[u8],
    alpn: &[u8],
) -> Result<quinn::ClientConfig, TlsError> {
    let mut roots = rustls::RootCertStore::empty();
    roots
        .add(rustls::pki_types::CertificateDer::from(cert_der.to_vec()))
        .map_err(|e| TlsError::BadCertificate(e.to_string()))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut crypto = rustls::ClientConfig::builder_with_provider(provider)
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| TlsError::Setup(e.to_string()))?
        .with_root_certificates(roots)
        .with_no_client_auth();
    crypto.alpn_protocols = vec![alpn.to_vec()];
    let quic = quinn::crypto::rustls::QuicClientConfig::try_from(crypto)
        .map_err(|e| TlsError::Setup(e.to_string()))?;
    let mut cfg = quinn::ClientConfig::new(Arc::new(quic));
    let mut transport = quinn::TransportConfig::default();
    transport.keep_alive_interval(Some(KEEP_ALIVE));
    // What a server may make the client hold, whatever server it is: the
    // client opens its one bidirectional stream itself, the server opens
    // one unidirectional (the updates) and sends no datagrams (the client
    // reads none: at most `CLIENT_DATAGRAM_BUFFER` bytes of them are kept,
    // older ones dropped), and all streams together buffer at most
    // `CLIENT_RECEIVE_WINDOW`.
    transport.max_concurrent_bidi_streams(quinn::VarInt::from_u32(0));
    transport.max_concurrent_uni_streams(quinn::VarInt::from_u32(1));
    transport.receive_window(quinn::VarInt::from_u32(CLIENT_RECEIVE_WINDOW));
    transport.datagram_receive_buffer_size(Some(CLIENT_DATAGRAM_BUFFER));
    cfg.transport_config(Arc::new(transport));
    Ok(cfg)
}
