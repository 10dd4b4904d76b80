//! One connection: handshake (Hello, token, version), then a loop that
//! routes control messages and position datagrams to the engine.

use std::sync::mpsc::TrySendError;
use std::sync::Arc;
use std::time::Duration;

use bytes::Bytes;
use strata_protocol::io::{FramedReader, ReadError};
use strata_protocol::limits::MAX_FORGET_CHUNKS;
use strata_protocol::{
    decode, ClientMessage, Direction, ErrorCode, FrameBuffer, FrameError, PositionUpdate, Refusal,
    RejectReason, ServerMessage, Welcome, PROTOCOL_VERSION,
};
use tokio::sync::oneshot;
use tracing::{debug, info, warn, Instrument};

use super::admission::Handshake;
use super::player_buckets::{BucketHold, PlayerBuckets};
use super::player_slots::PlayerSlot;
use super::position_reads::{PositionReads, ReadRefused};
use super::writer::{spawn_writer, FrameSender, SendRefused};
use crate::auth::{self, AuthError, Secret};
use crate::engine::{
    fanout_control, now_ms, Command, EngineHandle, LatestPosition, Queued, SessionShare, REPLACED,
};
use crate::log_every::LogEvery;
use crate::shutdown::Shutdown;
use crate::validate::ratelimit::{BucketConfig, TokenBucket};

/// How long a closing connection waits for its last frames to drain.
pub const DRAIN_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a session waits for room in the engine's queue for a command
/// its client relies on before closing as overloaded.
pub const ENGINE_WAIT_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a session waits for the engine to take one of its own queued
/// commands (its share, `[engine] session_commands`): long, since a busy
/// engine drains a deep queue over many ticks.
pub const SHARE_WAIT_TIMEOUT: Duration = Duration::from_secs(30);
/// Pause between attempts while the engine's queue is full.
pub const ENGINE_RETRY: Duration = Duration::from_millis(1);

/// What every connection task shares.
#[derive(Debug)]
pub struct SessionContext {
    pub secret: Secret,
    /// `[auth] token_max_ttl`: no token is good longer after its issue.
    pub token_max_ttl: std::time::Duration,
    /// Checks `Arrive` tickets: a cluster node's only (`None` alone).
    pub tickets: Option<crate::cluster::ticket::TicketKey>,
    pub engine: EngineHandle,
    /// Read-only use by admin sessions (snapshots, stats).
    pub store: std::sync::Arc<dyn crate::store::ChunkStore>,
    pub world_seed: u64,
    pub generator_version: u32,
    pub generator_params: String,
    pub view_radius: u8,
    /// Per-connection queue of world updates.
    pub writer_queue: usize,
    /// Bytes each of a connection's writers may hold (`[net]
    /// writer_queue_bytes`).
    pub writer_queue_bytes: usize,
    /// Per-connection queue of control frames (`[net] control_writer_queue`).
    pub control_writer_queue: usize,
    /// Shortest time between two writes of a session's updates (zero: none).
    pub send_interval: Duration,
    /// Each player's bucket for requests (`[validation.request_rate]`, in
    /// chunks; see [`request_cost`]).
    pub request_rate: BucketConfig,
    /// The players' request buckets, kept across their sessions.
    pub request_buckets: PlayerBuckets,
    /// Each player's bucket of logins (`[validation.join_rate]`), taken
    /// before its Join reaches the engine.
    pub join_rate: BucketConfig,
    /// The players' login buckets, kept across their sessions.
    pub join_buckets: PlayerBuckets,
    /// Each session's bucket of position reports (`[validation.position_rate]`).
    pub position_rate: BucketConfig,
    /// Bans and revocations, checked at every Hello; admin sessions change
    /// it (one at a time, under `access_writes`) and persist it first.
    pub access: std::sync::RwLock<auth::AccessList>,
    pub access_writes: tokio::sync::Mutex<()>,
    /// The zones this server starts with when none are stored
    /// (`[validation] spawn_protection_radius`); the first change stores
    /// them with it.
    pub default_zones: Vec<crate::validate::zones::Zone>,
    /// Zone changes and reloads, one at a time (`net/admin_zones.rs`).
    pub zone_writes: tokio::sync::Mutex<()>,
    /// On a cluster node, the logins' reads of stored positions: at most
    /// `[cluster] position_reads` at once, each within `position_read_ms`.
    pub position_reads: PositionReads,
    /// Readiness: the store reads made here (the access list and zones
    /// reloads, a cluster node's position reads) report how they went.
    pub health: std::sync::Arc<crate::health::Health>,
}

impl SessionContext {
    /// Verifies `token` now, its life capped at `[auth] token_max_ttl`
    /// from its issue ([`auth::verify_within`]).
    pub fn verify_token(&self, token: &str) -> Result<auth::Claims, AuthError> {
        auth::verify_within(&self.secret, token, auth::unix_now(), self.token_max_ttl)
    }

    /// Whether verified `claims` may join now.
    pub fn admitted(&self, claims: &auth::Claims) -> Result<(), auth::Denied> {
        let list = self.access.read().unwrap_or_else(|e| e.into_inner());
        list.check(claims, auth::unix_now())
    }
}

/// Application close codes (QUIC `CONNECTION_CLOSE` error codes).
pub fn close_code(code: ErrorCode) -> quinn::VarInt {
    quinn::VarInt::from_u32(code.close_code())
}

/// Closes its connection when dropped (a no-op once it is closed).
struct CloseOnExit(quinn::Connection);

impl Drop for CloseOnExit {
    fn drop(&mut self) {
        self.0.close(quinn::VarInt::from_u32(0), b"session over");
    }
}

/// Sends `Error`, lets it drain, and closes the connection with the same code.
async fn refuse(
    conn: &quinn::Connection,
    control: FrameSender,
    task: tokio::task::JoinHandle<()>,
    code: ErrorCode,
    message: &str,
) {
    let _ = control.try_send(fanout_control(&ServerMessage::Error {
        code,
        message: message.to_string(),
    }));
    drop(control);
    let _ = tokio::time::timeout(DRAIN_TIMEOUT, task).await;
    conn.close(close_code(code), message.as_bytes());
}

/// The connection's first bidirectional stream, opened by the client
/// before the handshake's `deadline`; otherwise the connection is closed
/// (or was).
pub(super) async fn accept_first_stream(
    conn: &quinn::Connection,
    what: &str,
    deadline: tokio::time::Instant,
) -> Option<(quinn::SendStream, quinn::RecvStream)> {
    match tokio::time::timeout_at(deadline, conn.accept_bi()).await {
        Ok(Ok(s)) => Some(s),
        Ok(Err(e)) => {
            debug!(error = %e, "connection closed before its {what}");
            None
        }
        Err(_) => {
            conn.close(
                close_code(ErrorCode::NotAuthenticated),
                format!("no {what}").as_bytes(),
            );
            None
        }
    }
}

/// Runs one connection to completion.
/// `handshake` holds the connection's handshake slot until Hello is
/// verified; the session then needs a session slot.
pub async fn run(
    conn: quinn::Connection,
    session: u64,
    ctx: Arc<SessionContext>,
    shutdown: Shutdown,
    handshake: Handshake,
) {
    // However this ends: a connection whose session is over is closed,
    // never left open by a stream a writer task still holds.
    let _closing = CloseOnExit(conn.clone());
    let deadline = handshake.deadline;
    let Some((send, recv)) = accept_first_stream(&conn, "control stream", deadline).await else {
        return;
    };
    let (control, control_task) = spawn_writer(
        send,
        (ctx.control_writer_queue, ctx.writer_queue_bytes),
        Duration::ZERO,
        "control",
    );
    let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ClientToServer));
    let hello = match tokio::time::timeout_at(deadline, reader.next::<ClientMessage>()).await {
        Ok(Ok(Some(ClientMessage::Hello(h)))) => h,
        Ok(Ok(Some(_))) => {
            return refuse(
                &conn,
                control,
                control_task,
                ErrorCode::NotAuthenticated,
                "first message must be Hello",
            )
            .await
        }
        Ok(Ok(None)) => return,
        Ok(Err(e)) => {
            return refuse(
                &conn,
                control,
                control_task,
                read_error_code(&e),
                &e.to_string(),
            )
            .await
        }
        Err(_) => {
            return refuse(
                &conn,
                control,
                control_task,
                ErrorCode::NotAuthenticated,
                "no Hello in time",
            )
            .await
        }
    };
    if hello.protocol_version != PROTOCOL_VERSION {
        let msg = format!(
            "protocol version {} is not supported; this server speaks {PROTOCOL_VERSION}",
            hello.protocol_version
        );
        return refuse(
            &conn,
            control,
            control_task,
            ErrorCode::UnsupportedVersion,
            &msg,
        )
        .await;
    }
    let claims = match check_token(&ctx, &hello.token) {
        Ok(c) => c,
        Err((code, message)) => {
            return refuse(&conn, control, control_task, code, &message).await;
        }
    };
    if let Err(denied) = ctx.admitted(&claims) {
        refused_login("denied");
        if let Some(refused) = DENIED_REFUSALS.event() {
            warn!(player = %claims.player, %denied, refused, "refused a denied player");
        }
        let code = ErrorCode::Forbidden;
        return refuse(&conn, control, control_task, code, &denied.to_string()).await;
    }
    // Cheap first, and before a session slot is taken (a refusal's drain
    // holds only this handshake's slot): a player past its logins never
    // reaches the engine (a Join ends the player's older session and,
    // resumed, its first position re-centres a whole view).
    let buckets = ctx.clone();
    let _joins = match join_allowed(&buckets, &claims.player) {
        Ok(hold) => hold,
        Err(message) => {
            let code = ErrorCode::TooManyConnections;
            return refuse(&conn, control, control_task, code, &message).await;
        }
    };
    // Held until the session ends, or a newer login of the player takes it.
    let slot = match handshake.admit_player(&claims.player, session) {
        Ok(slot) => slot,
        Err(why) => {
            // No login happened: a player retrying at a full server keeps
            // its logins for when a slot frees.
            _joins.give_back(1, now_ms());
            let code = ErrorCode::TooManyConnections;
            return refuse(&conn, control, control_task, code, why.message()).await;
        }
    };
    let span = tracing::info_span!("session", id = session, player = %claims.player, role = claims.role.name());
    let logged_in = joined(
        conn,
        (session, deadline),
        ctx,
        &slot,
        shutdown,
        control,
        control_task,
        reader,
        claims,
        // Untrusted bits: only the ones this server knows are kept.
        strata_protocol::capabilities::known(hello.capabilities),
    )
    .instrument(span)
    .await;
    if !logged_in {
        // Refused with "try again shortly" before any Join: its retries
        // are not charged as logins.
        _joins.give_back(1, now_ms());
    }
}

/// Whether the player logged in (its Join reached the engine, or the
/// client failed on its own): else its login is not charged.
#[allow(clippy::too_many_arguments)]
async fn joined(
    conn: quinn::Connection,
    (session, deadline): (u64, tokio::time::Instant),
    ctx: Arc<SessionContext>,
    slot: &PlayerSlot,
    mut shutdown: Shutdown,
    control: FrameSender,
    control_task: tokio::task::JoinHandle<()>,
    mut reader: FramedReader<quinn::RecvStream>,
    claims: auth::Claims,
    capabilities: u32,
) -> bool {
    // A client that grants no stream credit would hold its session slot
    // forever: the updates stream must open within the handshake's time.
    let uni = match tokio::time::timeout_at(deadline, conn.open_uni()).await {
        Ok(Ok(u)) => u,
        Ok(Err(e)) => {
            debug!(error = %e, "could not open the updates stream");
            return true;
        }
        Err(_) => {
            let code = ErrorCode::Malformed;
            let why = "no stream credit for the updates stream in time";
            refuse(&conn, control, control_task, code, why).await;
            return true;
        }
    };
    let queue = (ctx.writer_queue, ctx.writer_queue_bytes);
    let (updates, updates_task) = spawn_writer(uni, queue, ctx.send_interval, "updates");
    let stored = match stored_position(&ctx, &claims.player).await {
        Ok(stored) => stored,
        Err(refused) => {
            drop(updates);
            updates_task.abort();
            let code = ErrorCode::TooManyConnections;
            refuse(&conn, control, control_task, code, &refused.to_string()).await;
            return false;
        }
    };
    let (reply_tx, reply_rx) = oneshot::channel();
    let (kick_tx, mut kick_rx) = oneshot::channel();
    let latest = Arc::new(LatestPosition::default());
    let join = Command::Join {
        session,
        player: claims.player.clone(),
        role: claims.role,
        control: control.clone(),
        updates,
        reply: reply_tx,
        kick: kick_tx,
        position: latest.clone(),
        capabilities,
        stored: stored.map(Box::new),
    };
    // Its slot taken meanwhile: the newer login's Join must not be ended by
    // this older one's.
    if slot.is_replaced() {
        drop(join);
        updates_task.abort();
        refuse(&conn, control, control_task, ErrorCode::Kicked, REPLACED).await;
        return false;
    }
    if !ctx.engine.try_send(join) {
        refuse(
            &conn,
            control,
            control_task,
            ErrorCode::TooManyConnections,
            "server is overloaded",
        )
        .await;
        return false;
    }
    let Ok(joined) = reply_rx.await else {
        refuse(
            &conn,
            control,
            control_task,
            ErrorCode::ShuttingDown,
            "server is shutting down",
        )
        .await;
        return true;
    };
    // A ban between the Hello's check and the engine's Join found no session
    // to end; the engine knows this one now, so any later ban kicks it.
    if let Err(denied) = ctx.admitted(&claims) {
        warn!(%denied, "refused a player denied while joining");
        leave(&ctx.engine, session).await;
        updates_task.abort();
        let code = ErrorCode::Forbidden;
        refuse(&conn, control, control_task, code, &denied.to_string()).await;
        return true;
    }
    let welcome = Welcome {
        session,
        player: claims.player.clone(),
        role: claims.role,
        world_seed: ctx.world_seed,
        generator_version: ctx.generator_version,
        generator_params: ctx.generator_params.clone(),
        server_time: now_ms(),
        view_radius: ctx.view_radius,
        last_seq: joined.last_seq,
        start: joined.start,
    };
    let _ = control.try_send(fanout_control(&ServerMessage::Welcome(welcome)));
    info!("session started");
    let end = serve(
        &conn,
        (session, &claims.player),
        &ctx,
        &control,
        &mut reader,
        &mut shutdown,
        (&mut kick_rx, slot),
        &latest,
        admin_until(&claims),
    )
    .await;
    leave(&ctx.engine, session).await;
    match end {
        End::ClientClosed => {
            conn.close(quinn::VarInt::from_u32(0), b"bye");
            control_task.abort();
        }
        End::Refused(code, message) => refuse(&conn, control, control_task, code, &message).await,
        End::Gone => control_task.abort(),
    }
    updates_task.abort();
    info!("session ended");
    true
}

enum End {
    ClientClosed,
    Gone,
    Refused(ErrorCode, String),
}

/// Refused tokens, logged at most once a second (anyone can send them).
static TOKEN_REFUSALS: LogEvery = LogEvery::new(crate::log_every::LOG_EVERY);
/// Logins refused for a valid token whose player or token is denied (a
/// ban, a revocation): any holder of one can retry at will.
static DENIED_REFUSALS: LogEvery = LogEvery::new(crate::log_every::LOG_EVERY);

/// Counts a login refused for `reason` (`strata_connections_refused_total`).
pub(super) fn refused_login(reason: &'static str) {
    metrics::counter!(crate::metrics::CONNECTIONS_REFUSED, "reason" => reason).increment(1);
}
/// Logins refused for their rate, logged likewise.
static JOIN_REFUSALS: LogEvery = LogEvery::new(crate::log_every::LOG_EVERY);
/// Logins refused for want of their stored position, logged likewise.
static POSITION_REFUSALS: LogEvery = LogEvery::new(crate::log_every::LOG_EVERY);

/// Takes one of `player`'s login tokens (`[validation.join_rate]`) and
/// holds its bucket for the session; none left: the reason to refuse.
fn join_allowed<'a>(ctx: &'a SessionContext, player: &str) -> Result<BucketHold<'a>, String> {
    let hold = ctx.join_buckets.hold(player, ctx.join_rate, now_ms());
    let wait = match hold.try_take(1, now_ms()) {
        Ok(()) => return Ok(hold),
        Err(wait) => wait,
    };
    metrics::counter!(crate::metrics::CONNECTIONS_REFUSED, "reason" => "join_rate").increment(1);
    if let Some(refused) = JOIN_REFUSALS.event() {
        warn!(%player, refused, "refusing logins past [validation.join_rate]");
    }
    Err(match wait {
        Some(ms) => format!(
            "this player logs in too often; try again in {} s",
            ms.div_ceil(1000)
        ),
        None => "this player logs in too often; no more logins".into(),
    })
}

/// Verifies a Hello's token; a refusal comes with its error code.
pub(super) fn check_token(
    ctx: &SessionContext,
    token: &str,
) -> Result<auth::Claims, (ErrorCode, String)> {
    ctx.verify_token(token).map_err(|e| {
        refused_login("bad_token");
        if let Some(refused) = TOKEN_REFUSALS.event() {
            warn!(error = %e, refused, "refused a token");
        }
        let code = if matches!(e, AuthError::Expired { .. }) {
            ErrorCode::ExpiredToken
        } else {
            ErrorCode::BadToken
        };
        (code, e.to_string())
    })
}

pub(super) fn read_error_code(e: &ReadError) -> ErrorCode {
    match e {
        ReadError::Frame(FrameError::Oversized { .. }) => ErrorCode::FrameTooLarge,
        _ => ErrorCode::Malformed,
    }
}

/// When an admin-role session's token expires: its admin powers (every
/// edit kind, protected zones) end with it, as an admin connection's do.
/// A player's session outlives its token.
fn admin_until(claims: &auth::Claims) -> Option<tokio::time::Instant> {
    (claims.role == strata_protocol::Role::Admin).then(|| {
        let left = claims.expires_at.saturating_sub(auth::unix_now());
        tokio::time::Instant::now() + Duration::from_secs(left)
    })
}

#[allow(clippy::too_many_arguments)]
async fn serve(
    conn: &quinn::Connection,
    (session, player): (u64, &str),
    ctx: &SessionContext,
    control: &FrameSender,
    reader: &mut FramedReader<quinn::RecvStream>,
    shutdown: &mut Shutdown,
    (kicked, slot): (&mut oneshot::Receiver<crate::engine::Kick>, &PlayerSlot),
    latest: &LatestPosition,
    admin_until: Option<tokio::time::Instant>,
) -> End {
    // The player's bucket, shared with its other sessions and kept after
    // this one ends.
    let requests = ctx.request_buckets.hold(player, ctx.request_rate, now_ms());
    let mut positions = TokenBucket::new(ctx.position_rate, now_ms());
    // The session's share of the engine's player queue (`[engine]
    // session_commands`).
    let share = ctx.engine.session_share();
    // A request waiting for tokens, and when they are there: the control
    // stream is not read meanwhile (positions, kicks and shutdown still are).
    let mut throttled: Option<(ClientMessage, tokio::time::Instant)> = None;
    let mut view = FirstView::Unpaid;
    let view_cost = view_cost(ctx.view_radius);
    loop {
        let wake = throttled
            .as_ref()
            .map_or_else(tokio::time::Instant::now, |(_, at)| *at);
        let view_wake = view.wake();
        // An end first: a kicked, expired or shut down session takes no
        // more requests, however many its client has queued; the rest
        // share the session fairly (a backlog of requests does not hold
        // up its position reports, nor they it).
        let woke = tokio::select! {
            biased;
            end = must_end(shutdown, kicked, admin_until, Some((conn, slot))) => return end,
            woke = async {
                tokio::select! {
                    _ = tokio::time::sleep_until(view_wake), if view.is_waiting() => Woke::ViewDue,
                    _ = tokio::time::sleep_until(wake), if throttled.is_some() => Woke::TokensDue,
                    msg = reader.next::<ClientMessage>(), if throttled.is_none() => Woke::Read(msg),
                    dg = conn.read_datagram() => Woke::Datagram(dg),
                }
            } => woke,
        };
        let (m, waited) = match woke {
            Woke::ViewDue => {
                if view.charge(&requests, view_cost, true) {
                    queue_position(session, &ctx.engine, latest, &mut positions);
                }
                continue;
            }
            Woke::TokensDue => match throttled.take() {
                Some((m, _)) => (m, true),
                None => continue,
            },
            Woke::Read(msg) => match msg {
                Ok(Some(m)) => (m, false),
                Ok(None) => return End::ClientClosed,
                Err(ReadError::Io(e)) => {
                    debug!(error = %e, "control stream ended");
                    return End::Gone;
                }
                Err(e) => return End::Refused(read_error_code(&e), e.to_string()),
            },
            Woke::Datagram(Ok(bytes)) => {
                if offer_position(latest, &bytes) && view.charge(&requests, view_cost, false) {
                    queue_position(session, &ctx.engine, latest, &mut positions);
                }
                continue;
            }
            Woke::Datagram(Err(e)) => {
                debug!(error = %e, "connection ended");
                return End::Gone;
            }
        };
        // Cheap first: a request the session has no tokens for waits before
        // anything is checked or queued.
        let ms = requests.spend(request_cost(&m, ctx.view_radius), now_ms());
        if ms > 0 {
            // Counted once per request, not again if a clock tick short.
            if !waited {
                metrics::counter!(crate::metrics::REQUESTS_THROTTLED).increment(1);
            }
            let at = tokio::time::Instant::now() + Duration::from_millis(ms);
            throttled = Some((m, at));
            continue;
        }
        let routed = match route((session, player), ctx, &share, control, m) {
            Ok(Some(cmd)) => {
                let ending = must_end(shutdown, kicked, admin_until, Some((conn, slot)));
                deliver_unless(ending, &ctx.engine, &share, cmd, WAITS).await
            }
            Ok(None) => Ok(()),
            Err(end) => Err(end),
        };
        if let Err(end) = routed {
            return end;
        }
    }
}

/// What woke a session's loop, its end aside.
enum Woke {
    /// Its first view's tokens are there.
    ViewDue,
    /// The throttled request's tokens are there.
    TokensDue,
    Read(Result<Option<ClientMessage>, ReadError>),
    Datagram(Result<bytes::Bytes, quinn::ConnectionError>),
}

/// Resolves once the session must end, whatever it is doing: its client
/// closing the connection (`conn`), the server shutting down, its admin
/// token expiring (an admin-role session), or the engine's kick.
async fn must_end(
    shutdown: &mut Shutdown,
    kicked: &mut oneshot::Receiver<crate::engine::Kick>,
    admin_until: Option<tokio::time::Instant>,
    session: Option<(&quinn::Connection, &PlayerSlot)>,
) -> End {
    let expiry = admin_until.unwrap_or_else(tokio::time::Instant::now);
    let closed = async {
        match session {
            Some((c, _)) => drop(c.closed().await),
            None => std::future::pending().await,
        }
    };
    let replaced = async {
        match session {
            Some((_, slot)) => slot.replaced().await,
            None => std::future::pending().await,
        }
    };
    tokio::select! {
        biased;
        // The client gone: no request it left buffered reaches the
        // engine, nor does one wait for room there on its behalf.
        () = closed => End::ClientClosed,
        // Its slot is a newer login's (a full server): no later than its
        // Join would end this session.
        () = replaced => End::Refused(ErrorCode::Kicked, REPLACED.into()),
        _ = shutdown.wait() => {
            End::Refused(ErrorCode::ShuttingDown, "server is shutting down".into())
        }
        kick = kicked => {
            let internal = (ErrorCode::Internal, "the server ended this session".into());
            let (code, message) = kick.unwrap_or(internal);
            End::Refused(code, message)
        }
        _ = tokio::time::sleep_until(expiry), if admin_until.is_some() => {
            End::Refused(ErrorCode::ExpiredToken, "the admin token expired".into())
        }
    }
}

/// What a request costs a player's bucket, in chunks it makes the engine
/// touch: a subscription its whole view ((2r+1)^3, the radius capped at the
/// server's view radius), a forget its list, a resync, snapshot request or
/// ticket [`RESEND_COST`], an edit [`EDIT_COST`]; whatever reaches the
/// engine at least [`COMMAND_COST`]; a ping 1.
pub fn request_cost(m: &ClientMessage, view_radius: u8) -> u64 {
    match m {
        ClientMessage::Hello(_) => 0,
        ClientMessage::Edit(_) => EDIT_COST,
        ClientMessage::Subscribe { radius, .. } => {
            view_cost((*radius).min(view_radius)).max(COMMAND_COST)
        }
        // Even an empty list is a command the engine serves.
        ClientMessage::Forget { chunks } => (chunks.len() as u64).max(COMMAND_COST),
        ClientMessage::ResyncRequest { .. }
        | ClientMessage::FullSnapshotRequest { .. }
        | ClientMessage::Arrive(_) => RESEND_COST,
        ClientMessage::Ping { .. } => 1,
    }
}

/// The chunks of a view of `radius`: (2r+1)^3.
pub fn view_cost(radius: u8) -> u64 {
    let side = 2 * u64::from(radius) + 1;
    side * side * side
}

/// Whether a session's first view is paid for. Its first position report
/// re-centres it on a whole view, so that report costs the player's
/// request bucket what a `Subscribe` of the view would ([`view_cost`]),
/// once a session (a reconnect gets no free view). Without the tokens the
/// report waits, unread by the engine, the newest one kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FirstView {
    Unpaid,
    /// Tokens are due then.
    Waiting(tokio::time::Instant),
    Paid,
}

impl FirstView {
    fn is_waiting(&self) -> bool {
        matches!(self, FirstView::Waiting(_))
    }

    /// When the tokens are due (now when nothing waits).
    fn wake(&self) -> tokio::time::Instant {
        match self {
            FirstView::Waiting(at) => *at,
            _ => tokio::time::Instant::now(),
        }
    }

    /// Whether a report may go to the engine now: the first one takes
    /// `cost` tokens, or waits for them (`due`: the wait is over, try
    /// again). The wait is counted once, as a throttled request.
    fn charge(&mut self, requests: &BucketHold<'_>, cost: u64, due: bool) -> bool {
        match self {
            FirstView::Paid => return true,
            FirstView::Waiting(_) if !due => return false,
            _ => {}
        }
        let ms = requests.spend(cost, now_ms());
        if ms == 0 {
            *self = FirstView::Paid;
            return true;
        }
        if *self == FirstView::Unpaid {
            metrics::counter!(crate::metrics::REQUESTS_THROTTLED).increment(1);
        }
        *self = FirstView::Waiting(tokio::time::Instant::now() + Duration::from_millis(ms));
        false
    }
}

/// The least a request the engine serves costs a player's bucket: each is
/// a command the one engine thread takes (a channel receive, a handler, a
/// gauge), whatever it names. With the default rate (10,000 a second) a
/// player's empty forgets or radius-0 subscriptions reach the engine at
/// most 1,250 times a second.
pub const COMMAND_COST: u64 = 8;

/// What a resync, a full-snapshot request or a ticket costs a session's
/// request bucket, in chunks. The engine's work is a few set lookups and
/// queueing one chunk; sending it again is paced by the session's stream
/// budget like any snapshot. A client checking its whole radius-8 view
/// (4,913 chunks) fits the default burst.
pub const RESEND_COST: u64 = COMMAND_COST;

/// What an edit costs a player's request bucket: a command, as any. The
/// sequencer's per-player buckets (`edit_rate`, `reject_rate`) limit the
/// edits it takes in; this bounds the ones refused before they charge
/// those (`Busy`, `NodeFull`), which still cost prechecks and a queue slot.
pub const EDIT_COST: u64 = COMMAND_COST;

/// Queues a reply on a session's control stream. A full queue ends the
/// session, as it does for the engine's replies: a client that does not
/// read its verdicts is not silently missing some.
fn reply(control: &FrameSender, msg: &ServerMessage) -> Result<(), End> {
    match control.try_send(fanout_control(msg)) {
        Ok(()) | Err(SendRefused::Closed) => Ok(()),
        Err(SendRefused::Full) => Err(End::Refused(
            ErrorCode::Internal,
            "the client does not read its control stream".into(),
        )),
    }
}

/// Datagrams are unreliable and the next one supersedes this one: it
/// replaces the session's pending update (a bad one is dropped). True when
/// the slot was empty: then a command must be queued for it
/// ([`queue_position`]), unless the update waits ([`FirstView`]).
fn offer_position(latest: &LatestPosition, bytes: &Bytes) -> bool {
    match decode::<PositionUpdate>(bytes, Direction::ClientToServer) {
        Ok(update) => latest.offer(update),
        Err(e) => {
            debug!(error = %e, "bad position datagram");
            false
        }
    }
}

/// Queues the command for the pending update, taking one of `tokens`;
/// with no token left or a full engine queue, the update is dropped and
/// counted.
fn queue_position(
    session: u64,
    engine: &EngineHandle,
    latest: &LatestPosition,
    tokens: &mut TokenBucket,
) {
    // The slot was empty, so no command names it: clearing it is safe.
    tokens.refill(now_ms());
    let why = if !tokens.take(1) {
        "rate"
    } else if !engine.try_send(Command::Position { session }) {
        "queue_full"
    } else {
        return;
    };
    latest.clear();
    metrics::counter!(crate::metrics::POSITIONS_DROPPED, "reason" => why).increment(1);
}

/// Tells the engine the session ended. It must arrive, or the engine keeps
/// a ghost peer (and its chunks hot): it waits for room in the control
/// queue for as long as the engine runs.
async fn leave(engine: &EngineHandle, session: u64) {
    let mut cmd = Command::Leave { session };
    loop {
        match engine.offer(cmd) {
            Ok(()) | Err(TrySendError::Disconnected(_)) => return,
            Err(TrySendError::Full(back)) => cmd = back,
        }
        tokio::time::sleep(ENGINE_RETRY).await;
    }
}

/// On a cluster node, where the shared store last has `player` (after the
/// login bucket, under `[cluster] position_reads`, see
/// `net/position_reads.rs`): the engine bounds tickets and places the
/// resume with it. No answer in time, or a failed read, refuses the login
/// (counted, logged at most once a second): never counted as none.
async fn stored_position(
    ctx: &SessionContext,
    player: &str,
) -> Result<Option<crate::store::StoredPosition>, ReadRefused> {
    if !ctx.store.clustered() {
        return Ok(None);
    }
    let refused = match ctx
        .position_reads
        .read(&ctx.store, player, &ctx.health)
        .await
    {
        Ok(stored) => return Ok(stored),
        Err(refused) => refused,
    };
    let reason = refused.reason();
    metrics::counter!(crate::metrics::CONNECTIONS_REFUSED, "reason" => reason).increment(1);
    if let Some(count) = POSITION_REFUSALS.event() {
        let error = match &refused {
            ReadRefused::Failed(e) => e.as_str(),
            _ => "",
        };
        let wait = ctx.position_reads.wait();
        warn!(%player, reason, error, ?wait, refused = count,
            "refusing a login: its stored position was not read ([cluster] position_reads, position_read_ms)");
    }
    Err(refused)
}

/// Queues a command the client relies on (subscriptions, resyncs). The
/// session's share of the queue first: at its share it waits for the
/// engine to take one of its own commands, so one client's burst holds at
/// most that much of the queue all players share. While the queue itself
/// is full it waits too. Waiting, it stops reading its control stream, so
/// QUIC flow control slows the client down. A session whose own commands
/// wait in a long queue is not overloaded: its share is waited for up to
/// `waits.share` ([`SHARE_WAIT_TIMEOUT`]); only a queue full for
/// `waits.queue` ([`ENGINE_WAIT_TIMEOUT`]) closes the session as overloaded.
async fn deliver(
    engine: &EngineHandle,
    share: &SessionShare,
    cmd: Command,
    waits: Waits,
) -> Result<(), End> {
    let slot = match share.try_take() {
        Some(slot) => slot,
        None => {
            metrics::counter!(crate::metrics::SESSION_QUEUE_FULL).increment(1);
            match tokio::time::timeout(waits.share, share.take()).await {
                Ok(Some(slot)) => slot,
                Ok(None) => return Err(End::Gone),
                Err(_) => return Err(overloaded()),
            }
        }
    };
    let deadline = tokio::time::Instant::now() + waits.queue;
    let mut queued = Queued::held(cmd, slot);
    loop {
        match engine.offer_queued(queued) {
            Ok(()) => return Ok(()),
            Err(TrySendError::Disconnected(_)) => return Err(End::Gone),
            Err(TrySendError::Full(back)) => queued = back,
        }
        if tokio::time::Instant::now() >= deadline {
            return Err(overloaded());
        }
        tokio::time::sleep(ENGINE_RETRY).await;
    }
}

/// [`deliver`], unless `ending` resolves first: waiting for room in the
/// engine's queue (up to 30 s), a session still ends when it must (a kick,
/// shutdown, its admin token expiring), its command not queued.
async fn deliver_unless(
    ending: impl std::future::Future<Output = End>,
    engine: &EngineHandle,
    share: &SessionShare,
    cmd: Command,
    waits: Waits,
) -> Result<(), End> {
    tokio::select! {
        biased;
        end = ending => Err(end),
        delivered = deliver(engine, share, cmd, waits) => delivered,
    }
}

/// How long [`deliver`] waits for the session's share, and for room in
/// the queue.
#[derive(Debug, Clone, Copy)]
struct Waits {
    share: Duration,
    queue: Duration,
}

/// What sessions wait.
const WAITS: Waits = Waits {
    share: SHARE_WAIT_TIMEOUT,
    queue: ENGINE_WAIT_TIMEOUT,
};

/// The end of a session that waited out [`ENGINE_WAIT_TIMEOUT`] for room,
/// or [`SHARE_WAIT_TIMEOUT`] for its own share.
fn overloaded() -> End {
    warn!("engine queue full; closing the session");
    End::Refused(ErrorCode::TooManyConnections, "server is overloaded".into())
}

/// Handles a control message; returns the command the engine must get.
fn route(
    (session, player): (u64, &str),
    ctx: &SessionContext,
    share: &SessionShare,
    control: &FrameSender,
    m: ClientMessage,
) -> Result<Option<Command>, End> {
    let cmd = match m {
        ClientMessage::Hello(_) => {
            return Err(End::Refused(
                ErrorCode::Malformed,
                "Hello was already received".into(),
            ))
        }
        ClientMessage::Edit(request) => {
            let id = request.client_edit_id;
            let received = std::time::Instant::now();
            let edit = Command::Edit {
                session,
                request,
                received,
            };
            // At the session's share, as with a full queue: `Busy` at once.
            let slot = share.try_take();
            if slot.is_none() {
                metrics::counter!(crate::metrics::SESSION_QUEUE_FULL).increment(1);
            }
            let queued = slot.is_some_and(|slot| {
                let sent = ctx.engine.offer_queued(Queued::held(edit, slot));
                sent.is_ok()
            });
            if !queued {
                let msg = ServerMessage::EditRejected {
                    client_edit_id: id,
                    reason: RejectReason::Busy,
                };
                reply(control, &msg)?;
            }
            return Ok(None);
        }
        ClientMessage::Subscribe { center, radius } => Command::Subscribe {
            session,
            center,
            radius,
        },
        ClientMessage::Forget { chunks } => {
            // Cheap-checked here: an oversized list never reaches the engine.
            if chunks.len() > MAX_FORGET_CHUNKS {
                let refusal = Refusal::ForgetTooLarge {
                    chunks: u32::try_from(chunks.len()).unwrap_or(u32::MAX),
                    max: MAX_FORGET_CHUNKS as u32,
                };
                reply(control, &ServerMessage::RequestRefused(refusal))?;
                return Ok(None);
            }
            Command::Forget { session, chunks }
        }
        ClientMessage::ResyncRequest { pos } => Command::Resync { session, pos },
        ClientMessage::Arrive(ticket) => {
            // Signature, player and age here: a bad ticket never reaches
            // the engine.
            if let Err(reason) =
                crate::cluster::ticket::verify(ctx.tickets.as_ref(), &ticket, player, now_ms())
            {
                let refusal = Refusal::BadTicket { reason };
                reply(control, &ServerMessage::RequestRefused(refusal))?;
                return Ok(None);
            }
            Command::Arrive {
                session,
                feet: ticket.feet,
                issued_ms: ticket.issued_ms,
            }
        }
        ClientMessage::FullSnapshotRequest { pos } => Command::FullSnapshot { session, pos },
        ClientMessage::Ping { nonce } => {
            let pong = ServerMessage::Pong {
                nonce,
                server_time: now_ms(),
            };
            reply(control, &pong)?;
            return Ok(None);
        }
    };
    Ok(Some(cmd))
}

/// A context whose engine is the returned inbox, `queue` commands on each
/// lane (a test's stand-in engine serves it, or nobody does).
#[cfg(test)]
pub(crate) fn test_context(
    dir: &std::path::Path,
    queue: usize,
) -> (Arc<SessionContext>, crate::engine::Inbox) {
    let (engine, inbox) = crate::engine::inbox_channel(queue, queue);
    let rate = BucketConfig {
        capacity: 1,
        per_second: 1,
    };
    let ctx = SessionContext {
        secret: crate::auth::Secret::from_bytes([7; crate::auth::SECRET_LEN]),
        token_max_ttl: crate::auth::MAX_TOKEN_TTL,
        tickets: None,
        engine,
        store: Arc::new(crate::store::SledStore::open(dir).unwrap()),
        world_seed: 1,
        generator_version: 1,
        generator_params: String::new(),
        view_radius: 1,
        writer_queue: 1,
        writer_queue_bytes: crate::config::DEFAULT_WRITER_QUEUE_BYTES,
        control_writer_queue: 1,
        send_interval: Duration::ZERO,
        request_rate: rate,
        request_buckets: crate::net::player_buckets::PlayerBuckets::new(1),
        join_rate: rate,
        join_buckets: crate::net::player_buckets::PlayerBuckets::new(1),
        position_rate: rate,
        position_reads: crate::net::position_reads::PositionReads::default(),
        access: std::sync::RwLock::default(),
        access_writes: tokio::sync::Mutex::new(()),
        default_zones: Vec::new(),
        zone_writes: tokio::sync::Mutex::new(()),
        health: Arc::default(),
    };
    (Arc::new(ctx), inbox)
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::ChunkPos;

    #[test]
    fn a_request_costs_the_chunks_it_makes_the_engine_touch() {
        let sub = |radius| ClientMessage::Subscribe {
            center: ChunkPos::new(0, 0, 0),
            radius,
        };
        assert_eq!(request_cost(&sub(2), 8), 125);
        assert_eq!(request_cost(&sub(8), 8), 17 * 17 * 17);
        // A radius above the server's view costs only the view it gets.
        assert_eq!(request_cost(&sub(255), 8), 17 * 17 * 17);
        let forget = ClientMessage::Forget {
            chunks: vec![ChunkPos::new(1, 2, 3); 40],
        };
        assert_eq!(request_cost(&forget, 8), 40);
        let nothing = ClientMessage::Forget { chunks: Vec::new() };
        assert_eq!(
            request_cost(&nothing, 8),
            COMMAND_COST,
            "an empty list is not free"
        );
        let one = ClientMessage::Forget {
            chunks: vec![ChunkPos::new(1, 2, 3)],
        };
        assert_eq!(request_cost(&one, 8), COMMAND_COST);
        assert_eq!(
            request_cost(&sub(0), 8),
            COMMAND_COST,
            "nor is a view of one chunk"
        );
        let resync = ClientMessage::ResyncRequest {
            pos: ChunkPos::new(0, 0, 0),
        };
        assert_eq!(request_cost(&resync, 8), RESEND_COST);
        assert_eq!(request_cost(&ClientMessage::Ping { nonce: 1 }, 8), 1);
        let edit = ClientMessage::Edit(strata_protocol::EditRequest {
            client_edit_id: 1,
            edit: strata_terrain::Edit::Mine {
                center: strata_terrain::edit::FixedVec3::from_voxels(0, 0, 0),
                radius: strata_terrain::edit::Fixed::from_voxels(1),
                strength: 1,
            },
        });
        assert_eq!(request_cost(&edit, 8), EDIT_COST);
        assert_eq!(EDIT_COST, COMMAND_COST, "an edit is a command as any");
        assert_eq!(RESEND_COST, COMMAND_COST);
    }

    #[test]
    fn a_sessions_first_view_costs_its_view_once_and_waits_for_the_tokens() {
        // One view (radius 2) of tokens, one token a second.
        let cfg = BucketConfig {
            capacity: 125,
            per_second: 1,
        };
        let buckets = PlayerBuckets::new(1);
        let hold = buckets.hold("ann", cfg, now_ms());
        let mut first = FirstView::Unpaid;
        assert!(first.charge(&hold, view_cost(2), false));
        assert!(first.charge(&hold, view_cost(2), false), "once a session");
        assert_eq!(first, FirstView::Paid);
        // A reconnect's first view finds the bucket spent: it waits.
        let mut again = FirstView::Unpaid;
        assert!(!again.charge(&hold, view_cost(2), false));
        assert!(again.is_waiting());
        assert!(again.wake() > tokio::time::Instant::now());
        assert!(!again.charge(&hold, view_cost(2), false), "not before due");
        assert!(!again.charge(&hold, view_cost(2), true), "still short");
        assert!(again.is_waiting());
    }

    /// A player command, as the sessions queue them.
    fn resync(session: u64) -> Command {
        Command::Resync {
            session,
            pos: ChunkPos::new(0, 0, 0),
        }
    }

    fn resynced(rx: &crate::engine::Inbox, wait: Duration) -> Option<u64> {
        match rx.recv_timeout(wait) {
            Ok(Command::Resync { session, .. }) => Some(session),
            _ => None,
        }
    }

    #[tokio::test]
    async fn deliver_waits_for_room_in_the_engine_queue() {
        let (engine, rx) = crate::engine::inbox_channel(1, 1);
        let share = engine.session_share();
        assert!(engine.try_send(resync(1)), "the queue has one slot");
        let drain = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(30));
            let mut got = Vec::new();
            while let Some(session) = resynced(&rx, Duration::from_secs(2)) {
                got.push(session);
            }
            got
        });
        let waited = std::time::Instant::now();
        assert!(
            deliver(&engine, &share, resync(2), both(Duration::from_secs(5)))
                .await
                .is_ok()
        );
        assert!(
            waited.elapsed() >= Duration::from_millis(20),
            "it waited for room"
        );
        drop(engine);
        assert_eq!(drain.join().unwrap(), vec![1, 2], "nothing lost, in order");
    }

    #[tokio::test]
    async fn deliver_gives_up_on_a_stuck_engine_and_notices_a_gone_one() {
        let (engine, rx) = crate::engine::inbox_channel(1, 1);
        let share = engine.session_share();
        assert!(engine.try_send(resync(1)));
        match deliver(&engine, &share, resync(2), both(Duration::from_millis(50))).await {
            Err(End::Refused(ErrorCode::TooManyConnections, m)) => {
                assert!(m.contains("overloaded"))
            }
            _ => panic!("expected an overloaded refusal"),
        }
        assert_eq!(resynced(&rx, Duration::ZERO), Some(1));
        assert!(
            rx.recv_timeout(Duration::ZERO).is_err(),
            "the refused command was not queued"
        );
        assert_eq!(share.in_use(), 0, "nor holds its slot");
        drop(rx);
        assert!(matches!(
            deliver(&engine, &share, resync(3), both(Duration::from_millis(50))).await,
            Err(End::Gone)
        ));
    }

    /// A session waiting for room in the engine's queue ends at once when
    /// it must (here: shutdown), its command not queued and its slot free.
    #[tokio::test]
    async fn a_session_waiting_on_a_full_queue_still_ends_when_it_must() {
        let (engine, rx) = crate::engine::inbox_channel(1, 1);
        let share = engine.session_share();
        assert!(engine.try_send(resync(1)), "the queue is full now");
        let (trigger, mut shutdown) = crate::shutdown::channel();
        let (_kick, mut kicked) = oneshot::channel();
        let waits = both(Duration::from_secs(60));
        let started = std::time::Instant::now();
        let delivering = async {
            let ending = must_end(&mut shutdown, &mut kicked, None, None);
            deliver_unless(ending, &engine, &share, resync(2), waits).await
        };
        let stop = async {
            tokio::time::sleep(Duration::from_millis(50)).await;
            trigger.trigger();
        };
        let (delivered, ()) = tokio::join!(delivering, stop);
        assert!(matches!(
            delivered,
            Err(End::Refused(ErrorCode::ShuttingDown, _))
        ));
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "it did not wait the queue out"
        );
        assert_eq!(resynced(&rx, Duration::ZERO), Some(1));
        assert!(rx.recv_timeout(Duration::ZERO).is_err(), "not queued");
        assert_eq!(share.in_use(), 0, "nor holds its slot");
    }

    /// A session waiting for room in the engine's queue ends at once when
    /// its client closes, or when a newer login of its player takes its
    /// slot: nothing it left buffered reaches the engine.
    #[tokio::test]
    async fn a_waiting_session_ends_when_its_client_closes_or_its_slot_is_taken() {
        let (engine, rx) = crate::engine::inbox_channel(1, 1);
        let share = engine.session_share();
        assert!(engine.try_send(resync(1)), "the queue is full now");
        let slots = super::super::player_slots::PlayerSlots::new(
            Arc::new(tokio::sync::Semaphore::new(1)),
            1,
        );
        let slot = slots.take("ana", 1).unwrap();
        let (server_side, client_side, _endpoints) = super::super::loopback::pair(None).await;
        let close = async { client_side.close(0u32.into(), b"bye") };
        let (ended, ()) = waiting_until(&engine, &share, (&server_side, &slot), close).await;
        assert!(matches!(ended, Err(End::ClientClosed)));
        // A session still connected, its slot taken by its player's newer login.
        let (server_side, _client_side, _endpoints) = super::super::loopback::pair(None).await;
        let newer = async { slots.take("ana", 2).expect("its own slot") };
        let (ended, _newer) = waiting_until(&engine, &share, (&server_side, &slot), newer).await;
        assert!(
            matches!(&ended, Err(End::Refused(ErrorCode::Kicked, m)) if m == REPLACED),
            "ended as replaced"
        );
        assert_eq!(resynced(&rx, Duration::ZERO), Some(1));
        assert!(
            rx.recv_timeout(Duration::ZERO).is_err(),
            "neither was queued"
        );
        assert_eq!(share.in_use(), 0, "nor holds its slot");
    }

    /// A session's resync waiting for room in a full queue, with `cause`
    /// run 50 ms in: how the wait ended, well before its minute was up,
    /// and what `cause` gave.
    async fn waiting_until<T>(
        engine: &EngineHandle,
        share: &SessionShare,
        session: (&quinn::Connection, &PlayerSlot),
        cause: impl std::future::Future<Output = T>,
    ) -> (Result<(), End>, T) {
        let (_trigger, mut shutdown) = crate::shutdown::channel();
        let (_kick, mut kicked) = oneshot::channel();
        let started = std::time::Instant::now();
        let delivering = async {
            let ending = must_end(&mut shutdown, &mut kicked, None, Some(session));
            deliver_unless(
                ending,
                engine,
                share,
                resync(2),
                both(Duration::from_secs(60)),
            )
            .await
        };
        let cause = async {
            tokio::time::sleep(Duration::from_millis(50)).await;
            cause.await
        };
        let both = tokio::join!(delivering, cause);
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "it did not wait"
        );
        both
    }

    /// Both of [`deliver`]'s waits `d` long.
    fn both(d: Duration) -> Waits {
        Waits { share: d, queue: d }
    }

    #[tokio::test]
    async fn a_session_at_its_share_waits_while_others_still_queue() {
        // Room for 8 in the queue, 2 of them a session's.
        let (engine, rx) = crate::engine::inbox_channel(8, 8);
        let engine = engine.with_session_commands(2);
        let (flooder, honest) = (engine.session_share(), engine.session_share());
        let patience = both(Duration::from_millis(50));
        for _ in 0..2 {
            assert!(deliver(&engine, &flooder, resync(1), patience)
                .await
                .is_ok());
        }
        // The flooder's third waits for the engine, though the queue has
        // room, and gives up when the engine takes nothing.
        assert!(matches!(
            deliver(&engine, &flooder, resync(1), patience).await,
            Err(End::Refused(ErrorCode::TooManyConnections, _))
        ));
        // Another session queues meanwhile.
        assert!(deliver(&engine, &honest, resync(2), patience).await.is_ok());
        assert_eq!((flooder.in_use(), honest.in_use()), (2, 1));
        // Once the engine takes one of the flooder's, it may queue one more.
        assert_eq!(resynced(&rx, Duration::ZERO), Some(1));
        assert_eq!(flooder.in_use(), 1, "given back when taken");
        assert!(deliver(&engine, &flooder, resync(1), patience)
            .await
            .is_ok());
        let order: Vec<_> = std::iter::from_fn(|| resynced(&rx, Duration::ZERO)).collect();
        assert_eq!(order, vec![1, 2, 1]);
        assert_eq!((flooder.in_use(), honest.in_use()), (0, 0));
    }

    /// A datagram of session 7, its first view paid.
    fn position(
        engine: &EngineHandle,
        latest: &LatestPosition,
        tokens: &mut TokenBucket,
        bytes: Bytes,
    ) {
        if offer_position(latest, &bytes) {
            queue_position(7, engine, latest, tokens);
        }
    }

    #[test]
    fn a_position_flood_queues_one_command_per_session_and_keeps_the_newest() {
        let (engine, rx) = crate::engine::inbox_channel(8, 8);
        let latest = LatestPosition::default();
        // Two commands' worth of tokens, never refilled.
        let cfg = BucketConfig {
            capacity: 2,
            per_second: 0,
        };
        let mut tokens = TokenBucket::new(cfg, now_ms());
        for seq in 1..=10_000u32 {
            let update = PositionUpdate {
                seq,
                pos: strata_terrain::edit::FixedVec3::from_voxels(seq as i32 * 1000, 40, 0),
            };
            let bytes = strata_protocol::encode(&update, Direction::ClientToServer).unwrap();
            position(&engine, &latest, &mut tokens, Bytes::from(bytes));
        }
        let next = || rx.recv_timeout(Duration::ZERO);
        assert!(matches!(next(), Ok(Command::Position { session: 7 })));
        assert!(next().is_err(), "one command for 10,000 datagrams");
        assert_eq!(latest.take().map(|u| u.seq), Some(10_000));
        // Once the engine took it, the next datagram asks again, with the
        // second token; the one after that finds none and is dropped.
        let mut again = |seq| {
            let update = PositionUpdate {
                seq,
                pos: strata_terrain::edit::FixedVec3::from_voxels(0, 40, 0),
            };
            let bytes = strata_protocol::encode(&update, Direction::ClientToServer).unwrap();
            position(&engine, &latest, &mut tokens, Bytes::from(bytes));
        };
        again(10_001);
        assert!(matches!(next(), Ok(Command::Position { session: 7 })));
        assert_eq!(latest.take().map(|u| u.seq), Some(10_001));
        again(10_002);
        assert!(next().is_err(), "no token: no command");
        assert_eq!(latest.take(), None, "and nothing left pending");
    }
}
