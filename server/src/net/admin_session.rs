//! One admin connection (ALPN `strata-admin/1`): Hello with an admin-role
//! token, then requests answered in order on the same stream. A token of
//! any other role is refused before anything else is read or sent.
//!
//! Player connections never come here: the endpoint routes by ALPN, and
//! the player session decodes only `ClientMessage`.
//!
//! The token is checked again before each request and every
//! [`ADMIN_RECHECK_PERIOD`]: an admin session that expires, is banned or
//! revoked ends, as the engine, which does not know admin sessions, cannot
//! kick it.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

use strata_protocol::admin::{
    AccessSpec, AdminRequest, AdminResponse, AdminWelcome, ServerStats, ADMIN_PROTOCOL_VERSION,
};
use strata_protocol::io::{FramedReader, ReadError};
use strata_protocol::{encode_frame, Direction, ErrorCode, FrameBuffer, FrameError, Role};
use tokio::sync::{mpsc, oneshot};
use tracing::{debug, info, warn, Instrument};

use super::session::{
    accept_first_stream, check_token, close_code, read_error_code, SessionContext, DRAIN_TIMEOUT,
};
use crate::auth::{unix_now, AccessError, AccessList, AuthError, Claims, ACCESS_BLOB};
use crate::engine::admin::{AdminCommand, SnapshotStart};
use crate::engine::snapshot::PreImages;
use crate::engine::Command;
use crate::shutdown::Shutdown;
use crate::store::{ChunkStore, RawChunk, StoreError};

/// Encoded snapshot frames buffered between the store reader and the socket.
pub const SNAPSHOT_STREAM_QUEUE: usize = 64;
/// Admin logins refused for a player's token: any player can try at will.
static NOT_ADMIN_REFUSALS: crate::log_every::LogEvery =
    crate::log_every::LogEvery::new(crate::log_every::LOG_EVERY);
/// Admin logins refused for a ban or revocation: apart from players', so a
/// flood of banned players hides no admin's.
static DENIED_ADMIN_REFUSALS: crate::log_every::LogEvery =
    crate::log_every::LogEvery::new(crate::log_every::LOG_EVERY);
/// How often an admin session checks its token again (expiry, bans,
/// revocations) while it waits for a request; it also does before each one.
pub const ADMIN_RECHECK_PERIOD: Duration = Duration::from_secs(2);
/// How often every server reads the access list again from its store, so
/// bans and revocations made on another cluster node apply here too.
pub const ACCESS_RELOAD_PERIOD: Duration = Duration::from_secs(5);

/// Reads and swaps one access-list change tries while other writers (nodes
/// of a cluster) keep changing the stored list under it.
pub const ACCESS_WRITE_ATTEMPTS: usize = 8;

type Send = quinn::SendStream;

fn frame(msg: &AdminResponse) -> Result<Vec<u8>, FrameError> {
    encode_frame(msg, Direction::ServerToClient)
}

async fn send(stream: &mut Send, msg: &AdminResponse) -> Result<(), String> {
    let bytes = frame(msg).map_err(|e| e.to_string())?;
    stream.write_all(&bytes).await.map_err(|e| e.to_string())
}

/// Sends an answer, in parts when it is a list too long for one frame.
async fn send_parts(stream: &mut Send, msg: AdminResponse) -> Result<(), String> {
    for part in msg.into_parts() {
        send(stream, &part).await?;
    }
    Ok(())
}

/// Sends `Error`, lets it drain, and closes with the matching code.
async fn refuse(conn: &quinn::Connection, mut stream: Send, code: ErrorCode, message: &str) {
    let msg = AdminResponse::Error {
        code,
        message: message.to_string(),
    };
    let _ = tokio::time::timeout(DRAIN_TIMEOUT, async {
        let _ = send(&mut stream, &msg).await;
        let _ = stream.finish();
        let _ = stream.stopped().await;
    })
    .await;
    conn.close(close_code(code), message.as_bytes());
}

/// Runs one admin connection to completion.
pub async fn run(
    conn: quinn::Connection,
    session: u64,
    ctx: Arc<SessionContext>,
    shutdown: Shutdown,
    handshake: super::admission::Handshake,
) {
    let deadline = handshake.deadline;
    let Some((stream, recv)) = accept_first_stream(&conn, "admin stream", deadline).await else {
        return;
    };
    let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ClientToServer));
    let hello = match tokio::time::timeout_at(deadline, reader.next::<AdminRequest>()).await {
        Ok(Ok(Some(AdminRequest::Hello(h)))) => h,
        Ok(Ok(Some(_))) => {
            let msg = "first message must be Hello";
            return refuse(&conn, stream, ErrorCode::NotAuthenticated, msg).await;
        }
        Ok(Ok(None)) => return,
        Ok(Err(e)) => return refuse(&conn, stream, read_error_code(&e), &e.to_string()).await,
        Err(_) => {
            return refuse(
                &conn,
                stream,
                ErrorCode::NotAuthenticated,
                "no Hello in time",
            )
            .await
        }
    };
    if hello.protocol_version != ADMIN_PROTOCOL_VERSION {
        let msg = format!(
            "admin protocol version {} is not supported; this server speaks {ADMIN_PROTOCOL_VERSION}",
            hello.protocol_version
        );
        return refuse(&conn, stream, ErrorCode::UnsupportedVersion, &msg).await;
    }
    let claims = match check_token(&ctx, &hello.token) {
        Ok(c) => c,
        Err((code, message)) => return refuse(&conn, stream, code, &message).await,
    };
    if claims.role != Role::Admin {
        super::session::refused_login("not_admin");
        if let Some(refused) = NOT_ADMIN_REFUSALS.event() {
            warn!(player = %claims.player, refused, "refused a non-admin token on the admin protocol");
        }
        let msg = format!(
            "{}'s token has role {}; the admin protocol needs role admin",
            claims.player,
            claims.role.name()
        );
        return refuse(&conn, stream, ErrorCode::Forbidden, &msg).await;
    }
    if let Err(denied) = ctx.admitted(&claims) {
        super::session::refused_login("denied");
        if let Some(refused) = DENIED_ADMIN_REFUSALS.event() {
            warn!(admin = %claims.player, %denied, refused, "refused a denied admin");
        }
        return refuse(&conn, stream, ErrorCode::Forbidden, &denied.to_string()).await;
    }
    // Held until the session ends; players cannot take these.
    let _slot = match handshake.admit_admin() {
        Ok(slot) => slot,
        Err(why) => {
            let code = ErrorCode::TooManyConnections;
            return refuse(&conn, stream, code, why.message()).await;
        }
    };
    let span = tracing::info_span!("admin", id = session, admin = %claims.player);
    serve(conn, ctx, shutdown, stream, reader, claims)
        .instrument(span)
        .await
}

/// Whether an admin's claims still hold now, as the console checks its
/// long-lived requests (`console::auth::still_admitted`): unexpired, not
/// revoked, not banned. If not, the code and message to close with.
fn recheck(ctx: &SessionContext, claims: &Claims) -> Result<(), (ErrorCode, String)> {
    if unix_now() >= claims.expires_at {
        let expired = AuthError::Expired {
            expired_at: claims.expires_at,
        };
        return Err((ErrorCode::ExpiredToken, expired.to_string()));
    }
    ctx.admitted(claims)
        .map_err(|denied| (ErrorCode::Forbidden, denied.to_string()))
}

async fn serve(
    conn: quinn::Connection,
    ctx: Arc<SessionContext>,
    mut shutdown: Shutdown,
    mut stream: Send,
    mut reader: FramedReader<quinn::RecvStream>,
    claims: Claims,
) {
    let last_seq = match ask(&ctx, AdminCommand::Stats).await {
        Ok(s) => s.last_seq,
        Err(m) => return refuse(&conn, stream, ErrorCode::TooManyConnections, &m).await,
    };
    let welcome = AdminResponse::Welcome(AdminWelcome {
        admin: claims.player.clone(),
        last_seq,
        world_seed: ctx.world_seed,
        generator_version: ctx.generator_version,
    });
    if send(&mut stream, &welcome).await.is_err() {
        return;
    }
    info!("admin session started");
    let start = tokio::time::Instant::now() + ADMIN_RECHECK_PERIOD;
    let mut tick = tokio::time::interval_at(start, ADMIN_RECHECK_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let req = tokio::select! {
            r = reader.next::<AdminRequest>() => r,
            _ = tick.tick() => {
                if let Err((code, message)) = recheck(&ctx, &claims) {
                    warn!(reason = %message, "admin session ended: its token no longer holds");
                    return refuse(&conn, stream, code, &message).await;
                }
                continue;
            }
            _ = shutdown.wait() => {
                return refuse(&conn, stream, ErrorCode::ShuttingDown, "server is shutting down").await;
            }
        };
        let req = match req {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(ReadError::Io(e)) => return debug!(error = %e, "admin stream ended"),
            Err(e) => return refuse(&conn, stream, read_error_code(&e), &e.to_string()).await,
        };
        if let Err((code, message)) = recheck(&ctx, &claims) {
            warn!(reason = %message, "refused a request: the admin's token no longer holds");
            return refuse(&conn, stream, code, &message).await;
        }
        let result = match req {
            AdminRequest::Hello(_) => {
                let msg = "Hello was already received";
                return refuse(&conn, stream, ErrorCode::Malformed, msg).await;
            }
            AdminRequest::Snapshot { max_pending_chunks } => {
                match snapshot(&ctx, &mut stream, max_pending_chunks as usize, &claims).await {
                    Ok(Some((code, message))) => {
                        warn!(reason = %message, "admin session ended mid-snapshot: its token no longer holds");
                        // The stream may end in half a frame: the close says why.
                        let _ = stream.reset(quinn::VarInt::from_u32(0));
                        return conn.close(close_code(code), message.as_bytes());
                    }
                    Ok(None) => Ok(()),
                    Err(e) => Err(e),
                }
            }
            other => match answer(&ctx, other).await {
                Ok(resp) => send_parts(&mut stream, resp).await,
                // The engine stalled or is stopping: the admin is told why.
                Err(e) => return refuse(&conn, stream, ErrorCode::Internal, &e).await,
            },
        };
        if let Err(e) = result {
            return debug!(error = %e, "admin session ends");
        }
    }
    let _ = stream.finish();
    let _ = tokio::time::timeout(DRAIN_TIMEOUT, stream.stopped()).await;
    conn.close(quinn::VarInt::from_u32(0), b"bye");
    info!("admin session ended");
}

/// Longest an admin request waits for the engine's answer (a stalled
/// commit, say). Past it the request fails, and the write turns its caller
/// holds (the access list's, the zones') are let go; a change already
/// stored still reaches every node by the next reload.
pub const ENGINE_ANSWER_LIMIT: std::time::Duration = std::time::Duration::from_secs(10);

/// Sends a command to the engine and waits for its answer, at most
/// [`ENGINE_ANSWER_LIMIT`].
pub(crate) async fn ask<T>(
    ctx: &SessionContext,
    make: impl FnOnce(oneshot::Sender<T>) -> AdminCommand,
) -> Result<T, String> {
    let (tx, rx) = oneshot::channel();
    if !ctx.engine.try_send(Command::Admin(make(tx))) {
        return Err("server is overloaded".into());
    }
    match tokio::time::timeout(ENGINE_ANSWER_LIMIT, rx).await {
        Ok(answer) => answer.map_err(|_| "server is shutting down".to_string()),
        Err(_) => Err(format!(
            "the engine did not answer within {} s; a change asked for may or may not have been made",
            ENGINE_ANSWER_LIMIT.as_secs()
        )),
    }
}

/// [`ask`] for a command that must not be dropped on a full queue: offered
/// again until queued, for [`ENGINE_ANSWER_LIMIT`] at most.
async fn ask_until_queued<T>(
    ctx: &SessionContext,
    make: impl FnOnce(oneshot::Sender<T>) -> AdminCommand,
) -> Result<T, String> {
    let (tx, rx) = oneshot::channel();
    let mut cmd = Command::Admin(make(tx));
    let deadline = tokio::time::Instant::now() + ENGINE_ANSWER_LIMIT;
    loop {
        match ctx.engine.offer(cmd) {
            Ok(()) => break,
            Err(TrySendError::Disconnected(_)) => return Err("server is shutting down".into()),
            Err(TrySendError::Full(back)) if tokio::time::Instant::now() < deadline => cmd = back,
            Err(TrySendError::Full(_)) => {
                return Err(format!(
                    "the engine took no command for {} s; the change is stored, but its sessions \
                     were not ended",
                    ENGINE_ANSWER_LIMIT.as_secs()
                ))
            }
        }
        tokio::time::sleep(crate::net::session::ENGINE_RETRY).await;
    }
    match tokio::time::timeout(ENGINE_ANSWER_LIMIT, rx).await {
        Ok(answer) => answer.map_err(|_| "server is shutting down".to_string()),
        Err(_) => Err(format!(
            "the engine did not answer within {} s; the change is stored",
            ENGINE_ANSWER_LIMIT.as_secs()
        )),
    }
}

use crate::stored_zones::ZoneChange;
use std::sync::mpsc::TrySendError;

fn refused(message: String) -> AdminResponse {
    AdminResponse::Refused { message }
}

/// Answers one non-streaming request. `Err` ends the session. The web
/// console's admin actions come through here too, so both behave alike.
pub(crate) async fn answer(
    ctx: &Arc<SessionContext>,
    req: AdminRequest,
) -> Result<AdminResponse, String> {
    Ok(match req {
        AdminRequest::Stats => {
            let engine = ask(ctx, AdminCommand::Stats).await?;
            let store = ctx.store.clone();
            let stored = tokio::task::spawn_blocking(move || store_figures(&*store))
                .await
                .map_err(|e| e.to_string())?;
            match stored {
                Ok((extent, store_bytes)) => AdminResponse::Stats(ServerStats {
                    last_seq: engine.last_seq,
                    modified_chunks: engine.modified_chunks,
                    modified_extent: extent,
                    resident_chunks: engine.resident_chunks,
                    store_bytes,
                    sessions: engine.sessions,
                    queued_edits: engine.queued_edits,
                    world_seed: ctx.world_seed,
                    generator_version: ctx.generator_version,
                }),
                Err(e) => refused(format!("store read failed: {e}")),
            }
        }
        AdminRequest::Players => AdminResponse::Players(ask(ctx, AdminCommand::Players).await?),
        AdminRequest::Kick { player } => AdminResponse::Kicked {
            sessions: ask(ctx, |reply| AdminCommand::Kick { player, reply }).await?,
        },
        AdminRequest::Zones => AdminResponse::Zones(ask(ctx, AdminCommand::Zones).await?),
        AdminRequest::ZoneAdd(z) => {
            let zone = crate::validate::zones::Zone {
                name: z.name,
                min: z.min,
                max: z.max,
            };
            super::admin_zones::answer(ctx, ZoneChange::Add(zone)).await?
        }
        AdminRequest::ZoneRemove { name } => {
            super::admin_zones::answer(ctx, ZoneChange::Remove(name)).await?
        }
        AdminRequest::InspectChunk { pos } => {
            match ask(ctx, |reply| AdminCommand::Chunk { pos, reply }).await? {
                Ok((version, data)) => AdminResponse::Chunk { pos, version, data },
                Err(m) => refused(m),
            }
        }
        AdminRequest::Access => access_answer(ctx, |_, _| Ok(None)).await?,
        AdminRequest::Ban { player, until } => {
            access_answer(ctx, |list, now| {
                list.ban(&player, until, now)?;
                Ok(Some(player.clone()))
            })
            .await?
        }
        AdminRequest::Unban { player } => {
            access_answer(ctx, |list, _| {
                list.unban(&player);
                Ok(None)
            })
            .await?
        }
        AdminRequest::RevokeTokens { player } => {
            access_answer(ctx, |list, now| {
                list.revoke(&player, now)?;
                Ok(Some(player.clone()))
            })
            .await?
        }
        AdminRequest::Hello(_) | AdminRequest::Snapshot { .. } => {
            unreachable!("handled by the session loop")
        }
    })
}

/// Applies `change` to the access list as the store holds it now (not to
/// this server's copy: another cluster node may have changed it since, and
/// writing the copy back would undo that), persists it (fsynced) only if
/// the store still holds what was read (else reads and applies again, up
/// to [`ACCESS_WRITE_ATTEMPTS`] times), makes it current, and ends the
/// live sessions of the player `change` names. A refused or failed change
/// leaves the store as it was.
async fn access_answer(
    ctx: &Arc<SessionContext>,
    change: impl Fn(&mut AccessList, u64) -> Result<Option<String>, AccessError>,
) -> Result<AdminResponse, String> {
    let _one_writer = ctx.access_writes.lock().await;
    for _ in 0..ACCESS_WRITE_ATTEMPTS {
        let (raw, mut list) = match stored_access(ctx).await {
            Ok(read) => read,
            Err(m) => return Ok(refused(m)),
        };
        adopt(ctx, list.clone()).await?;
        let before = list.clone();
        let kick = match change(&mut list, unix_now()) {
            Ok(k) => k,
            Err(e) => return Ok(refused(e.to_string())),
        };
        if list != before {
            let store = ctx.store.clone();
            let blob = list.to_blob();
            let saved = tokio::task::spawn_blocking(move || {
                store.swap_blob(ACCESS_BLOB, raw.as_deref(), &blob)
            })
            .await
            .map_err(|e| e.to_string())?;
            match saved {
                Ok(true) => {}
                // Another node wrote between the read and the swap.
                Ok(false) => continue,
                Err(e) => return Ok(refused(format!("store write failed: {e}"))),
            }
            *ctx.access.write().unwrap_or_else(|e| e.into_inner()) = list.clone();
        }
        // The change is stored: its kick must reach the engine (a full
        // queue would leave the banned player playing, and the next reload
        // finds nothing new to kick for).
        let kicked = match kick {
            Some(player) => {
                ask_until_queued(ctx, |reply| AdminCommand::Kick { player, reply }).await?
            }
            None => 0,
        };
        return Ok(AdminResponse::Access(access_spec(&list, kicked)));
    }
    Ok(refused(format!(
        "the stored access list changed under this change {ACCESS_WRITE_ATTEMPTS} times; nothing was written, try again"
    )))
}

/// The access list as the store holds it now, with its stored bytes.
async fn stored_access(ctx: &SessionContext) -> Result<(Option<Vec<u8>>, AccessList), String> {
    let store = ctx.store.clone();
    let blob = tokio::task::spawn_blocking(move || store.get_blob(ACCESS_BLOB))
        .await
        .map_err(|e| e.to_string())?;
    ctx.health.report(crate::health::StoreWork::Access, &blob);
    let blob = blob.map_err(|e| format!("store read failed: {e}"))?;
    let list = AccessList::from_blob(blob.as_deref()).map_err(|e| e.to_string())?;
    Ok((blob, list))
}

/// Makes `stored` the current list and ends the live sessions of the
/// players it bans or revokes anew (changes made elsewhere, e.g. on another
/// node). Called under `access_writes`.
async fn adopt(ctx: &SessionContext, stored: AccessList) -> Result<(), String> {
    let (renewed, previous) = {
        let mut current = ctx.access.write().unwrap_or_else(|e| e.into_inner());
        if *current == stored {
            return Ok(());
        }
        let renewed = renewed_players(&current, &stored);
        let previous = std::mem::replace(&mut *current, stored.clone());
        (renewed, previous)
    };
    // Every kick is queued before any answer is awaited: a stalled engine
    // delays them, never drops one.
    let mut answers = Vec::with_capacity(renewed.len());
    for player in renewed {
        info!(%player, "access list changed elsewhere: ending the player's sessions");
        let (reply, answer) = oneshot::channel();
        if !ctx
            .engine
            .try_send(Command::Admin(AdminCommand::Kick { player, reply }))
        {
            // Not queued: the old list goes back, so the next reload sees
            // the change again and kicks again.
            let mut current = ctx.access.write().unwrap_or_else(|e| e.into_inner());
            if *current == stored {
                *current = previous;
            }
            return Err("server is overloaded".into());
        }
        answers.push(answer);
    }
    // One deadline for them all.
    let until = tokio::time::Instant::now() + ENGINE_ANSWER_LIMIT;
    for answer in answers {
        let _ = tokio::time::timeout_at(until, answer).await;
    }
    Ok(())
}

/// Players whose ban or revocation `new` adds or changes from `old`.
fn renewed_players(old: &AccessList, new: &AccessList) -> BTreeSet<String> {
    let bans = new
        .bans
        .iter()
        .filter(|(p, until)| old.bans.get(*p) != Some(until))
        .map(|(p, _)| p.clone());
    let revoked = new
        .revoked_before
        .iter()
        .filter(|(p, before)| old.revoked_before.get(*p) != Some(before))
        .map(|(p, _)| p.clone());
    bans.chain(revoked).collect()
}

/// Reads the stored access list every [`ACCESS_RELOAD_PERIOD`] and adopts
/// it, until shutdown. A failed read keeps the current list.
pub async fn reload_access(ctx: Arc<SessionContext>, mut shutdown: Shutdown) {
    ctx.health
        .expect_every(crate::health::StoreWork::Access, ACCESS_RELOAD_PERIOD);
    let start = tokio::time::Instant::now() + ACCESS_RELOAD_PERIOD;
    let mut tick = tokio::time::interval_at(start, ACCESS_RELOAD_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = shutdown.wait() => return,
        }
        let _one_writer = ctx.access_writes.lock().await;
        let adopted = match stored_access(&ctx).await {
            Ok((_, stored)) => adopt(&ctx, stored).await,
            Err(e) => Err(e),
        };
        if let Err(e) = adopted {
            warn!(error = %e, "reloading the access list failed");
        }
    }
}

/// The wire form of an access list.
pub fn access_spec(list: &AccessList, kicked: u32) -> AccessSpec {
    AccessSpec {
        bans: list.bans.iter().map(|(p, u)| (p.clone(), *u)).collect(),
        revoked_before: list
            .revoked_before
            .iter()
            .map(|(p, t)| (p.clone(), *t))
            .collect(),
        kicked,
    }
}

/// Extent of the modified chunks and the store's size on disk.
pub fn store_figures(
    store: &dyn ChunkStore,
) -> Result<
    (
        Option<(strata_terrain::ChunkPos, strata_terrain::ChunkPos)>,
        u64,
    ),
    StoreError,
> {
    let mut extent: Option<(strata_terrain::ChunkPos, strata_terrain::ChunkPos)> = None;
    for item in store.modified_chunks() {
        let (p, _) = item?;
        extent = Some(match extent {
            None => (p, p),
            Some((lo, hi)) => (
                strata_terrain::ChunkPos::new(lo.x.min(p.x), lo.y.min(p.y), lo.z.min(p.z)),
                strata_terrain::ChunkPos::new(hi.x.max(p.x), hi.y.max(p.y), hi.z.max(p.z)),
            ),
        });
    }
    Ok((extent, store.size_on_disk()?))
}

/// Registers a snapshot with the engine: the outer `Err` when the engine
/// cannot be asked, the inner one when it refuses.
pub(crate) async fn begin_snapshot(
    ctx: &SessionContext,
    limit: usize,
) -> Result<Result<SnapshotStart, String>, String> {
    ask(ctx, |reply| AdminCommand::SnapshotBegin {
        max_pending_chunks: limit,
        world_seed: ctx.world_seed,
        generator_version: ctx.generator_version,
        generator_params: ctx.generator_params.clone(),
        reply,
    })
    .await
}

/// Resolves once `claims` no longer hold ([`recheck`], every
/// [`ADMIN_RECHECK_PERIOD`]), with the code and message to close with.
async fn revoked(ctx: &SessionContext, claims: &Claims) -> (ErrorCode, String) {
    let start = tokio::time::Instant::now() + ADMIN_RECHECK_PERIOD;
    let mut tick = tokio::time::interval_at(start, ADMIN_RECHECK_PERIOD);
    loop {
        tick.tick().await;
        if let Err(why) = recheck(ctx, claims) {
            return why;
        }
    }
}

/// Streams a consistent snapshot: registers it with the engine, reads the
/// store on a blocking thread through the pre-images, and writes each
/// chunk as it comes (bounded queue). A refusal is a `Refused` response.
/// The admin's claims are checked again while it runs (a whole world
/// takes long, and a slow reader longer): `Some` is why the session must
/// end, the snapshot cut short.
async fn snapshot(
    ctx: &Arc<SessionContext>,
    stream: &mut Send,
    limit: usize,
    claims: &Claims,
) -> Result<Option<(ErrorCode, String)>, String> {
    let start = match begin_snapshot(ctx, limit).await? {
        Ok(s) => s,
        Err(m) => return send(stream, &refused(m)).await.map(|()| None),
    };
    send(stream, &AdminResponse::SnapshotBegin(start.info)).await?;
    let (tx, mut rx) = mpsc::channel::<Vec<u8>>(SNAPSHOT_STREAM_QUEUE);
    let store = ctx.store.clone();
    let pre = start.preimages;
    let reader = tokio::task::spawn_blocking(move || read_snapshot(&*store, &pre, &tx));
    let mut write_error = None;
    let mut ended = None;
    let revoked = revoked(ctx, claims);
    tokio::pin!(revoked);
    loop {
        let bytes = tokio::select! {
            b = rx.recv() => b,
            why = &mut revoked => {
                ended = Some(why);
                break;
            }
        };
        let Some(bytes) = bytes else {
            break;
        };
        tokio::select! {
            written = stream.write_all(&bytes) => {
                if let Err(e) = written {
                    // Dropping the receiver stops the reader at its next send.
                    write_error = Some(e.to_string());
                    break;
                }
            }
            // A client that reads nothing holds the write: checked too.
            why = &mut revoked => {
                ended = Some(why);
                break;
            }
        }
    }
    drop(rx);
    let outcome = reader.await.map_err(|e| e.to_string())?;
    if ended.is_some() {
        return Ok(ended);
    }
    if let Some(e) = write_error {
        return Err(e);
    }
    match outcome {
        Ok(chunks) => {
            info!(chunks, "snapshot sent");
            send(stream, &AdminResponse::SnapshotEnd { chunks }).await
        }
        Err(m) => {
            warn!(reason = %m, "snapshot aborted");
            send(stream, &refused(format!("snapshot aborted: {m}"))).await
        }
    }
    .map(|()| None)
}

/// Walks the store's chunk records, resolving each through the pre-images,
/// and queues encoded `SnapshotChunk` frames. Returns the chunk count.
fn read_snapshot(
    store: &dyn ChunkStore,
    pre: &Arc<PreImages>,
    tx: &mpsc::Sender<Vec<u8>>,
) -> Result<u64, String> {
    walk_snapshot(store, pre, |c| {
        let msg = AdminResponse::SnapshotChunk {
            pos: c.pos,
            version: c.version,
            data: c.encoded,
        };
        let bytes = frame(&msg).map_err(|e| e.to_string())?;
        tx.blocking_send(bytes)
            .map_err(|_| "the admin connection went away".to_string())
    })
}

/// Walks the store's chunk records, resolving each through the pre-images,
/// and hands each chunk of the snapshot to `each` (an `Err` stops the
/// walk). Returns the chunk count.
pub(crate) fn walk_snapshot(
    store: &dyn ChunkStore,
    pre: &Arc<PreImages>,
    mut each: impl FnMut(RawChunk) -> Result<(), String>,
) -> Result<u64, String> {
    let mut count = 0u64;
    for item in store.raw_chunks() {
        let read = item.map_err(|e| format!("store read failed: {e}"))?;
        if let Some(reason) = pre.aborted() {
            return Err(reason);
        }
        let Some(c) = pre.resolve(read) else {
            continue; // first written after the snapshot's seq
        };
        each(c)?;
        count += 1;
    }
    // A chunk may have been aborted after its last read: report it.
    match pre.aborted() {
        Some(reason) => Err(reason),
        None => Ok(count),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A kick (the sessions of a player just banned) offered to a full
    /// queue is offered again until the engine takes it, not dropped.
    #[tokio::test]
    async fn a_kick_waits_for_room_in_a_full_queue() {
        let dir = tempfile::tempdir().unwrap();
        let (ctx, inbox) = crate::net::session::test_context(dir.path(), 1);
        let (filler, _) = oneshot::channel();
        assert!(ctx
            .engine
            .try_send(Command::Admin(AdminCommand::Stats(filler))));
        let engine = async {
            tokio::time::sleep(Duration::from_millis(100)).await;
            // The command that filled the queue, then the kick.
            let first = inbox.recv_timeout(Duration::ZERO).unwrap();
            assert!(matches!(first, Command::Admin(AdminCommand::Stats(_))));
            let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
            loop {
                match inbox.recv_timeout(Duration::ZERO) {
                    Ok(Command::Admin(AdminCommand::Kick { player, reply })) => {
                        assert_eq!(player, "mallory");
                        let _ = reply.send(1);
                        return;
                    }
                    Ok(other) => panic!("not a kick: {other:?}"),
                    Err(_) => {
                        assert!(tokio::time::Instant::now() < deadline, "no kick came");
                        tokio::time::sleep(Duration::from_millis(5)).await;
                    }
                }
            }
        };
        let ask = ask_until_queued(&ctx, |reply| AdminCommand::Kick {
            player: "mallory".into(),
            reply,
        });
        let (kicked, ()) = tokio::join!(ask, engine);
        assert_eq!(kicked, Ok(1));
    }
}
