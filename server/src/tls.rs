//! TLS for QUIC: the server's self-signed certificate, the quinn server
//! config built from it and the transport limits, and a client config that
//! pins exactly that certificate.
//!
//! Everything uses rustls with the *ring* provider, chosen explicitly rather
//! than through rustls's process-wide default, and TLS 1.3 only (QUIC
//! requires it). The certificate is stored as DER (`cert.der`), the key as
//! PKCS#8 DER (`key.der`). Clients trust the certificate by pinning it: it is
//! the only root in their store, and normal WebPKI verification (signature,
//! validity, subject alternative name) still runs. Clients connect with the
//! server name `localhost` or any name in the certificate.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use quinn::crypto::rustls::QuicServerConfig;
use quinn::{AckFrequencyConfig, IdleTimeout, TransportConfig, VarInt};
use rustls::crypto::CryptoProvider;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName};
use strata_protocol::ALPN;
use thiserror::Error;

use crate::config::{NetSection, TlsSection, CONTROL_BIDI_STREAMS};
use crate::datadir::{read_capped_file, read_private_file, write_private_file, write_public_file};

/// Names every generated certificate covers, so local clients always work.
pub const BASE_SUBJECT_ALT_NAMES: [&str; 3] = ["localhost", "127.0.0.1", "::1"];
/// Subject common name of generated certificates.
pub const CERT_COMMON_NAME: &str = "Strata server (self-signed)";

/// Why a certificate or TLS configuration could not be made.
#[derive(Debug, Error)]
pub enum TlsError {
    #[error("cannot generate certificate: {0}")]
    Generate(#[from] rcgen::Error),
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("certificate or key is unusable: {0}")]
    Rustls(#[from] rustls::Error),
    #[error("the ring provider lacks QUIC's initial cipher suite")]
    NoInitialCipherSuite,
    #[error("{0:?} is neither a DNS name nor an IP address")]
    BadName(String),
    #[error("idle timeout {0:?} is too large for QUIC")]
    IdleTimeout(Duration),
}

/// A certificate and its private key. `Debug` elides the key.
#[derive(Debug)]
pub struct CertPair {
    cert: CertificateDer<'static>,
    key: PrivatePkcs8KeyDer<'static>,
}

impl CertPair {
    /// Generates an ECDSA P-256 self-signed certificate for
    /// [`BASE_SUBJECT_ALT_NAMES`] plus `extra_names` (IP literals become IP
    /// SANs, anything else DNS SANs).
    pub fn generate(extra_names: &[String]) -> Result<Self, TlsError> {
        let mut names: Vec<String> = BASE_SUBJECT_ALT_NAMES.map(String::from).to_vec();
        for name in extra_names {
            // rcgen accepts any ASCII as a DNS name; hold names to what a
            // client could actually ask for.
            if ServerName::try_from(name.as_str()).is_err() {
                return Err(TlsError::BadName(name.clone()));
            }
            if !names.contains(name) {
                names.push(name.clone());
            }
        }
        let mut params = rcgen::CertificateParams::new(names)?;
        params.distinguished_name = rcgen::DistinguishedName::new();
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, CERT_COMMON_NAME);
        let key = rcgen::KeyPair::generate()?;
        let cert = params.self_signed(&key)?;
        Ok(CertPair {
            cert: cert.der().clone(),
            key: PrivatePkcs8KeyDer::from(key.serialize_der()),
        })
    }

    /// Loads a pair saved by [`CertPair::save`] and checks that the key is
    /// valid and matches the certificate.
    pub fn load(cert_path: &Path, key_path: &Path) -> Result<Self, TlsError> {
        let cert = load_cert_der(cert_path)?;
        let key = read_private_file(key_path).map_err(|source| TlsError::Read {
            path: key_path.to_owned(),
            source,
        })?;
        let pair = CertPair {
            cert,
            key: PrivatePkcs8KeyDer::from(key),
        };
        rustls::sign::CertifiedKey::from_der(
            vec![pair.cert.clone()],
            pair.private_key(),
            &ring_provider(),
        )?;
        Ok(pair)
    }

    /// Writes the certificate (0644) and the key (0600), each atomically:
    /// the certificate first beside its place ([`staged_cert`]), then the
    /// key, then the certificate moved into place. A crash between leaves
    /// the key with the staged certificate, which the next start finishes
    /// moving ([`crate::datadir::DataDir::open_or_init`]).
    pub fn save(&self, cert_path: &Path, key_path: &Path) -> Result<(), TlsError> {
        fn write(path: &Path) -> impl FnOnce(std::io::Error) -> TlsError + '_ {
            move |source| TlsError::Write {
                path: path.to_owned(),
                source,
            }
        }
        let staged = staged_cert(cert_path);
        write_public_file(&staged, self.cert.as_ref()).map_err(write(&staged))?;
        write_private_file(key_path, self.key.secret_pkcs8_der()).map_err(write(key_path))?;
        crate::durable::rename(&staged, cert_path).map_err(write(cert_path))
    }

    /// The certificate, DER-encoded: what clients pin.
    pub fn cert_der(&self) -> &CertificateDer<'static> {
        &self.cert
    }

    fn private_key(&self) -> PrivateKeyDer<'static> {
        PrivateKeyDer::Pkcs8(self.key.clone_key())
    }
}

/// Where [`CertPair::save`] writes the certificate before the key.
pub fn staged_cert(cert_path: &Path) -> std::path::PathBuf {
    let mut name = cert_path.file_name().unwrap_or_default().to_owned();
    name.push(".new");
    cert_path.with_file_name(name)
}

/// Reads a DER certificate file (e.g. a copy of the server's `cert.der`).
pub fn load_cert_der(path: &Path) -> Result<CertificateDer<'static>, TlsError> {
    let bytes = read_capped_file(path).map_err(|source| TlsError::Read {
        path: path.to_owned(),
        source,
    })?;
    Ok(CertificateDer::from(bytes))
}

/// rustls's ring provider, passed explicitly everywhere.
fn ring_provider() -> CryptoProvider {
    rustls::crypto::ring::default_provider()
}

/// The server's QUIC transport limits from `[net]` and `[tls]`.
pub fn transport_config(net: &NetSection, tls: &TlsSection) -> Result<TransportConfig, TlsError> {
    let mut t = TransportConfig::default();
    t.stream_receive_window(VarInt::from_u32(net.stream_receive_window))
        .receive_window(VarInt::from_u32(net.connection_receive_window))
        .send_window(net.send_window)
        .max_concurrent_bidi_streams(VarInt::from_u32(CONTROL_BIDI_STREAMS))
        .max_concurrent_uni_streams(VarInt::from_u32(net.max_uni_streams))
        .max_idle_timeout(Some(idle_timeout(net.idle_timeout())?))
        .keep_alive_interval(Some(net.keep_alive()))
        .datagram_receive_buffer_size(Some(net.datagram_receive_buffer))
        .datagram_send_buffer_size(net.datagram_send_buffer)
        .enable_segmentation_offload(tls.enable_segmentation_offload);
    if let Some(delay) = net.ack_delay_max() {
        // Sent once the handshake is confirmed, and again as the RTT moves.
        let mut ack = AckFrequencyConfig::default();
        ack.max_ack_delay(Some(delay))
            .ack_eliciting_threshold(VarInt::from_u32(net.ack_eliciting_threshold));
        t.ack_frequency_config(Some(ack));
    }
    Ok(t)
}

fn idle_timeout(d: Duration) -> Result<IdleTimeout, TlsError> {
    IdleTimeout::try_from(d).map_err(|_| TlsError::IdleTimeout(d))
}

/// A quinn server config serving `pair` with ALPNs [`ALPN`] (players) and
/// `strata-admin/1` (admin sessions), and the
/// transport limits of `net` and `tls`.
pub fn server_config(
    pair: &CertPair,
    net: &NetSection,
    tls: &TlsSection,
) -> Result<quinn::ServerConfig, TlsError> {
    let mut crypto = rustls::ServerConfig::builder_with_provider(Arc::new(ring_provider()))
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .with_no_client_auth()
        .with_single_cert(vec![pair.cert.clone()], pair.private_key())?;
    crypto.alpn_protocols = vec![ALPN.to_vec(), strata_protocol::admin::ADMIN_ALPN.to_vec()];
    let quic = QuicServerConfig::try_from(crypto).map_err(|_| TlsError::NoInitialCipherSuite)?;
    let mut config = quinn::ServerConfig::with_crypto(Arc::new(quic));
    config.transport_config(Arc::new(transport_config(net, tls)?));
    Ok(config)
}
