//! The QUIC endpoint: admits connections (see [`super::admission`]) and
//! runs a session task for each, until shutdown.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tracing::{debug, info, Instrument};

use super::admin_session;
use super::admission::{Admission, Limits};
use super::session::{self, SessionContext};
use super::transport_stats;
use crate::shutdown::Shutdown;

/// How long shutdown waits for sessions to say goodbye.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// A bound endpoint, ready to accept.
#[derive(Debug)]
pub struct Listener {
    endpoint: quinn::Endpoint,
    ctx: Arc<SessionContext>,
    admission: Arc<Admission>,
}

impl Listener {
    pub fn new(endpoint: quinn::Endpoint, ctx: Arc<SessionContext>, limits: Limits) -> Self {
        Self {
            endpoint,
            ctx,
            admission: Admission::new(limits),
        }
    }

    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.endpoint.local_addr()
    }

    /// Accepts until `shutdown` fires, then stops accepting, lets sessions
    /// close with a reason, and waits for the endpoint to go idle.
    pub async fn run(self, mut shutdown: Shutdown) {
        let mut next_session = 1u64;
        loop {
            tokio::select! {
                incoming = self.endpoint.accept() => {
                    let Some(incoming) = incoming else { break };
                    let remote = incoming.remote_address();
                    // Stateless: a Retry holds no slot, and only a client
                    // that receives at its address can answer it.
                    if !incoming.remote_address_validated() && self.admission.wants_retry() {
                        metrics::counter!(crate::metrics::CONNECTIONS_RETRIED).increment(1);
                        if let Err(e) = incoming.retry() {
                            e.into_incoming().refuse();
                        }
                        continue;
                    }
                    let handshake = match self.admission.begin(remote.ip()) {
                        Ok(h) => h,
                        Err(_) => {
                            incoming.refuse();
                            continue;
                        }
                    };
                    let id = next_session;
                    next_session += 1;
                    let ctx = self.ctx.clone();
                    let shutdown = shutdown.clone();
                    let span = tracing::info_span!("conn", %remote, session = id);
                    let eviction = handshake.eviction();
                    tokio::spawn(async move {
                        metrics::gauge!(crate::metrics::CONNECTIONS).increment(1.0);
                        let tls = tokio::time::timeout_at(handshake.deadline, incoming);
                        let tls = tokio::select! {
                            tls = tls => Some(tls),
                            _ = eviction.wait() => None,
                        };
                        match tls {
                            Some(Ok(Ok(conn))) => {
                                let run = async {
                                    if is_admin(&conn) {
                                        admin_session::run(conn.clone(), id, ctx, shutdown, handshake).await
                                    } else {
                                        session::run(conn.clone(), id, ctx, shutdown, handshake).await
                                    }
                                };
                                let run = transport_stats::sampled(conn.clone(), run);
                                tokio::pin!(run);
                                // Never after an admission: only a handshake
                                // still in progress loses its slot. Closed
                                // with its reason before the session's
                                // future (and its own close) is dropped.
                                tokio::select! {
                                    _ = &mut run => {}
                                    _ = eviction.wait() => evicted(&conn),
                                }
                            }
                            Some(Ok(Err(e))) => debug!(error = %e, "handshake failed"),
                            Some(Err(_)) => debug!("TLS handshake timed out"),
                            None => debug!("TLS handshake evicted: every slot taken"),
                        }
                        metrics::gauge!(crate::metrics::CONNECTIONS).decrement(1.0);
                    }.instrument(span));
                }
                _ = shutdown.wait() => break,
            }
        }
        info!("no longer accepting connections");
        self.endpoint.set_server_config(None);
        self.admission.drained(SHUTDOWN_GRACE).await;
        let _ = tokio::time::timeout(SHUTDOWN_GRACE, self.endpoint.wait_idle()).await;
    }
}

/// Ends a connection whose handshake slot a newer connection took.
fn evicted(conn: &quinn::Connection) {
    debug!("handshake evicted: every slot taken");
    let why = crate::net::admission::Refused::Evicted.message();
    conn.close(
        session::close_code(strata_protocol::ErrorCode::TooManyConnections),
        why.as_bytes(),
    );
}

/// Whether the client negotiated the admin ALPN (`strata-admin/1`).
fn is_admin(conn: &quinn::Connection) -> bool {
    conn.handshake_data()
        .and_then(|d| d.downcast::<quinn::crypto::rustls::HandshakeData>().ok())
        .and_then(|h| h.protocol)
        .is_some_and(|p| p == strata_protocol::admin::ADMIN_ALPN)
}
