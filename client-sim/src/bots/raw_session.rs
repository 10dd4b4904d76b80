//! A bare player session for the hostile roles: the real handshake, the
//! control stream and the updates stream, but no replica (a hostile keeps
//! no world and regenerates nothing). What the server sends is handed to
//! optional callbacks, or read and dropped.

use std::net::SocketAddr;
use std::sync::Arc;

use bytes::Bytes;
use strata_protocol::io::FramedReader;
use strata_protocol::{
    encode, encode_frame, ClientMessage, Direction, EditRequest, ErrorCode, FrameBuffer,
    PositionUpdate, ServerMessage, Welcome, WorldUpdate, PROTOCOL_VERSION,
};
use strata_terrain::{ChunkPos, Edit, FixedVec3};
use tokio::task::JoinHandle;

use crate::client::{ClientError, CONNECT_TIMEOUT};

/// Called with every control message after `Welcome`.
pub type OnControl = Arc<dyn Fn(&ServerMessage) + Send + Sync>;
/// Called with every update; without one the updates stream is drained
/// undecoded.
pub type OnUpdate = Arc<dyn Fn(&WorldUpdate) + Send + Sync>;

/// One welcomed session. Dropping it closes the connection.
pub struct RawSession {
    pub conn: quinn::Connection,
    pub welcome: Welcome,
    send: quinn::SendStream,
    next_position: u32,
    next_edit: u64,
    tasks: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for RawSession {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawSession")
            .field("session", &self.welcome.session)
            .finish_non_exhaustive()
    }
}

/// The reason a connection ended, as a short name: the `ErrorCode` the
/// server closed it with (`Kicked`, `NotAuthenticated`...), else the kind
/// of QUIC close (`refused`, `timed_out`, `reset`, `transport`, `local`).
pub fn close_name(e: &quinn::ConnectionError) -> String {
    use quinn::ConnectionError as E;
    match e {
        E::ApplicationClosed(a) => ErrorCode::from_close_code(a.error_code.into_inner())
            .map_or_else(|| "application".to_string(), |c| format!("{c:?}")),
        E::ConnectionClosed(c) if c.error_code == quinn::TransportErrorCode::CONNECTION_REFUSED => {
            "refused".to_string()
        }
        E::ConnectionClosed(_) | E::TransportError(_) | E::VersionMismatch => {
            "transport".to_string()
        }
        E::TimedOut => "timed_out".to_string(),
        E::Reset => "reset".to_string(),
        E::LocallyClosed => "local".to_string(),
        E::CidsExhausted => "cids_exhausted".to_string(),
    }
}

impl RawSession {
    /// Connects through `endpoint` to `server`, says Hello with `token` and
    /// waits for `Welcome` (at most [`CONNECT_TIMEOUT`]). A connection the
    /// server ends without an `ErrorCode` is `Closed` with its
    /// [`close_name`].
    pub async fn open(
        endpoint: &quinn::Endpoint,
        server: SocketAddr,
        tls: quinn::ClientConfig,
        token: &str,
        on_control: Option<OnControl>,
        on_update: Option<OnUpdate>,
    ) -> Result<RawSession, ClientError> {
        let closed = |e: quinn::ConnectionError| match &e {
            quinn::ConnectionError::ApplicationClosed(a) => {
                match ErrorCode::from_close_code(a.error_code.into_inner()) {
                    Some(code) => ClientError::Refused {
                        code,
                        message: String::from_utf8_lossy(&a.reason).into_owned(),
                    },
                    None => ClientError::Closed(close_name(&e)),
                }
            }
            _ => ClientError::Closed(close_name(&e)),
        };
        let handshake = async {
            let conn = endpoint
                .connect_with(tls, server, "localhost")
                .map_err(|e| ClientError::Connect(e.to_string()))?
                .await
                .map_err(closed)?;
            let (send, control, welcome) =
                crate::client::say_hello(&conn, token, PROTOCOL_VERSION, 0, closed).await?;
            Ok::<_, ClientError>((conn, send, control, welcome))
        };
        let (conn, send, control, welcome) = tokio::time::timeout(CONNECT_TIMEOUT, handshake)
            .await
            .map_err(|_| ClientError::Timeout("Welcome"))??;
        let tasks = vec![
            tokio::spawn(read_control(control, on_control)),
            tokio::spawn(read_updates(conn.clone(), on_update)),
        ];
        Ok(RawSession {
            conn,
            welcome,
            send,
            next_position: 1,
            next_edit: 1,
            tasks,
        })
    }

    /// Writes one control message (waits while QUIC flow control is full).
    pub async fn send(&mut self, msg: &ClientMessage) -> Result<(), ClientError> {
        let frame = encode_frame(msg, Direction::ClientToServer)
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.send
            .write_all(&frame)
            .await
            .map_err(|e| ClientError::Closed(e.to_string()))
    }

    /// Writes control messages as one write, so they reach the server
    /// together (one packet when they fit).
    pub async fn send_all(&mut self, msgs: &[ClientMessage]) -> Result<(), ClientError> {
        let mut frames = Vec::new();
        for msg in msgs {
            frames.extend(
                encode_frame(msg, Direction::ClientToServer)
                    .map_err(|e| ClientError::Protocol(e.to_string()))?,
            );
        }
        self.send
            .write_all(&frames)
            .await
            .map_err(|e| ClientError::Closed(e.to_string()))
    }

    /// Sends an edit; returns its `client_edit_id`.
    pub async fn edit(&mut self, edit: Edit) -> Result<u64, ClientError> {
        let id = self.next_edit;
        self.next_edit += 1;
        let msg = ClientMessage::Edit(EditRequest {
            client_edit_id: id,
            edit,
        });
        self.send(&msg).await.map(|()| id)
    }

    pub async fn subscribe(&mut self, center: ChunkPos, radius: u8) -> Result<(), ClientError> {
        self.send(&ClientMessage::Subscribe { center, radius })
            .await
    }

    /// Queues one position datagram (quinn may drop older unsent ones).
    pub fn position(&mut self, pos: FixedVec3) -> Result<(), ClientError> {
        let seq = self.next_position;
        self.next_position = self.next_position.wrapping_add(1);
        let bytes = encode(&PositionUpdate { seq, pos }, Direction::ClientToServer)
            .map_err(|e| ClientError::Protocol(e.to_string()))?;
        self.conn
            .send_datagram(Bytes::from(bytes))
            .map_err(|e| ClientError::Closed(e.to_string()))
    }

    /// Why the connection ended (see [`close_name`]); `None` while open.
    pub fn close_reason(&self) -> Option<String> {
        self.conn.close_reason().map(|e| close_name(&e))
    }
}

impl Drop for RawSession {
    fn drop(&mut self) {
        self.conn.close(quinn::VarInt::from_u32(0), b"bye");
        for t in &self.tasks {
            t.abort();
        }
    }
}

async fn read_control(mut reader: FramedReader<quinn::RecvStream>, on: Option<OnControl>) {
    while let Ok(Some(msg)) = reader.next::<ServerMessage>().await {
        if let Some(f) = &on {
            f(&msg);
        }
    }
}

async fn read_updates(conn: quinn::Connection, on: Option<OnUpdate>) {
    let Ok(mut recv) = conn.accept_uni().await else {
        return;
    };
    match on {
        None => while let Ok(Some(_)) = recv.read_chunk(1 << 16, true).await {},
        Some(f) => {
            let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient));
            while let Ok(Some(u)) = reader.next::<WorldUpdate>().await {
                f(&u);
            }
        }
    }
}
