//! The QUIC endpoint: accepts connections under a cap and runs a session
//! task for each, until shutdown.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Semaphore;
use tracing::{debug, info, Instrument};

use super::admin_session;
use super::session::{self, SessionContext};
use crate::shutdown::Shutdown;

/// How long shutdown waits for sessions to say goodbye.
pub const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// A bound endpoint, ready to accept.
#[derive(Debug)]
pub struct Listener {
    endpoint: quinn::Endpoint,
    ctx: Arc<SessionContext>,
    max_connections: usize,
}

impl Listener {
    pub fn new(
        endpoint: quinn::Endpoint,
        ctx: Arc<SessionContext>,
        max_connections: usize,
    ) -> Self {
        Self {
            endpoint,
            ctx,
            max_connections,
        }
    }

    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.endpoint.local_addr()
    }

    /// Accepts until `shutdown` fires, then stops accepting, lets sessions
    /// close with a reason, and waits for the endpoint to go idle.
    pub async fn run(self, mut shutdown: Shutdown) {
        let limit = Arc::new(Semaphore::new(self.max_connections));
        let mut next_session = 1u64;
        loop {
            tokio::select! {
                incoming = self.endpoint.accept() => {
                    let Some(incoming) = incoming else { break };
                    let Ok(permit) = limit.clone().try_acquire_owned() else {
                        debug!(remote = %incoming.remote_address(), "refused: connection limit");
                        incoming.refuse();
                        continue;
                    };
                    let id = next_session;
                    next_session += 1;
                    let remote = incoming.remote_address();
                    let ctx = self.ctx.clone();
                    let shutdown = shutdown.clone();
                    let span = tracing::info_span!("conn", %remote, session = id);
                    tokio::spawn(async move {
                        metrics::gauge!(crate::metrics::CONNECTIONS).increment(1.0);
                        match incoming.await {
                            Ok(conn) if is_admin(&conn) => {
                                admin_session::run(conn, id, ctx, shutdown).await
                            }
                            Ok(conn) => session::run(conn, id, ctx, shutdown).await,
                            Err(e) => debug!(error = %e, "handshake failed"),
                        }
                        metrics::gauge!(crate::metrics::CONNECTIONS).decrement(1.0);
                        drop(permit);
                    }.instrument(span));
                }
                _ = shutdown.wait() => break,
            }
        }
        info!("no longer accepting connections");
        self.endpoint.set_server_config(None);
        let all = self.max_connections as u32;
        let _ = tokio::time::timeout(SHUTDOWN_GRACE, limit.acquire_many(all)).await;
        let _ = tokio::time::timeout(SHUTDOWN_GRACE, self.endpoint.wait_idle()).await;
    }
}

/// Whether the client negotiated the admin ALPN (`strata-admin/1`).
fn is_admin(conn: &quinn::Connection) -> bool {
    conn.handshake_data()
        .and_then(|d| d.downcast::<quinn::crypto::rustls::HandshakeData>().ok())
        .and_then(|h| h.protocol)
        .is_some_and(|p| p == strata_protocol::admin::ADMIN_ALPN)
}
