//! Sessions: connect, position, interest, edits, events, welcome, stats.

use std::ffi::c_char;
use std::mem::MaybeUninit;
use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::Mutex;

use strata_client::glam::{DVec3, IVec3};
use strata_client::protocol::{PositionRefusal, RejectReason, Start};
use strata_client::terrain::Edit;
use strata_client::{edits, ClientError, Event, Session, SessionError, SessionOptions};

use crate::ptr::{bytes, items, shared, text, writable};
use crate::status::{call, call_quiet, Failure, StrataStatus};
use crate::types::*;

/// One connected player. Opaque: made by `strata_connect`, freed by
/// `strata_session_free`.
#[derive(Debug)]
pub struct StrataSession {
    pub(crate) session: Session,
    /// The changes of the last EDIT_ACCEPTED event polled, which the event
    /// points into.
    last_changes: Mutex<Vec<StrataChunkVersion>>,
}

// The header promises calls from any thread.
const _: () = {
    const fn shareable<T: Send + Sync>() {}
    shareable::<StrataSession>();
};

/// # Safety
/// `p` is null or a live session from `strata_connect`.
pub(crate) unsafe fn session<'a>(p: *const StrataSession) -> Result<&'a Session, Failure> {
    // SAFETY: forwarded from the caller.
    Ok(&unsafe { shared(p, "session") }?.session)
}

/// Most addresses of one name tried, one after another.
const MAX_ADDRESSES_TRIED: usize = 4;

/// Every address `address` resolves to, IPv4 first (a server listens on
/// 127.0.0.1 by default, and "localhost" often resolves to ::1 first),
/// at most [`MAX_ADDRESSES_TRIED`].
fn resolve(address: &str) -> Result<Vec<SocketAddr>, Failure> {
    let fail = |why: String| Failure::new(StrataStatus::Connect, why);
    let found = address
        .to_socket_addrs()
        .map_err(|e| fail(format!("cannot resolve {address}: {e}")))?;
    let addrs = to_try(found);
    if addrs.is_empty() {
        return Err(fail(format!("{address} resolves to no address")));
    }
    Ok(addrs)
}

/// `found` without repeats, IPv4 first (each family in its order), at
/// most [`MAX_ADDRESSES_TRIED`].
fn to_try(found: impl Iterator<Item = SocketAddr>) -> Vec<SocketAddr> {
    let mut addrs: Vec<SocketAddr> = Vec::new();
    for a in found {
        if !addrs.contains(&a) {
            addrs.push(a);
        }
    }
    addrs.sort_by_key(|a| a.is_ipv6());
    addrs.truncate(MAX_ADDRESSES_TRIED);
    addrs
}

/// Whether another of a name's addresses may do better than this failure:
/// nothing answered there, or not in time.
fn try_next(e: &SessionError) -> bool {
    matches!(
        e,
        SessionError::Client(ClientError::Connect(_) | ClientError::Timeout(_))
    )
}

/// Connects to `address` ("host:port"), trusting only the server
/// certificate `cert_der` (`cert_len` bytes of DER, e.g. the server's
/// data/cert.der), and logs in with `token`. With `predict` nonzero (a byte:
/// any value is sound from any language), the player's
/// own edits show at once and are reconciled with the server's verdicts.
/// Blocks until the server welcomes the player (10 s at most for each
/// address the name resolves to: IPv4 ones first, the next tried only when
/// nothing answered at one, at most 4; name lookup comes on top). On success
/// `*out` is a new session the caller owns; on any other status it is NULL
/// (when `out` itself is not), which `strata_session_free` ignores.
///
/// # Safety
/// `address` and `token` are NUL-terminated strings, `cert_der` points to
/// `cert_len` bytes, `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_connect(
    address: *const c_char,
    cert_der: *const u8,
    cert_len: usize,
    token: *const c_char,
    predict: u8,
    out_session: *mut *mut StrataSession,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let dst = unsafe { null_first(out_session) }?;
        // SAFETY: the caller's contract above.
        let (address, cert, token) = unsafe {
            (
                text(address, "address")?,
                bytes(cert_der, cert_len, "cert_der")?,
                text(token, "token")?,
            )
        };
        let opts = SessionOptions {
            predict: predict != 0,
            ..SessionOptions::default()
        };
        connect(address, cert, token, (opts, false), dst)
    })
}

/// `strata_connect` with options: prediction and capability bits
/// (`STRATA_CAP_SNAPSHOTS` for a client that never runs the generator,
/// `STRATA_CAP_OP_REPLAY` to replay edits instead of taking deltas).
///
/// # Safety
/// As `strata_connect`; `options` points to a `StrataConnectOptions`
/// zeroed and then set, whose `size` bytes are readable.
#[no_mangle]
pub unsafe extern "C" fn strata_connect_with(
    address: *const c_char,
    cert_der: *const u8,
    cert_len: usize,
    token: *const c_char,
    options: *const StrataConnectOptions,
    out_session: *mut *mut StrataSession,
) -> StrataStatus {
    let args = (address, cert_der, cert_len, token);
    // SAFETY: the caller's contract above.
    unsafe { connect_options(args, options, false, out_session) }
}

/// `strata_connect_with` for a cluster of servers sharing one world:
/// `address` is any one node. The session connects to the other nodes that
/// node names, sends the position to all of them, each edit to the node
/// that writes its region (a region's edits in the order given; a node that
/// stops answering holds up only its regions' edits), and reads each chunk from that node's copy. When a region
/// moves to another node, its chunks come as CHUNK_CHANGED events. Every
/// other call works as on one server.
///
/// # Safety
/// As `strata_connect_with`.
#[no_mangle]
pub unsafe extern "C" fn strata_connect_cluster(
    address: *const c_char,
    cert_der: *const u8,
    cert_len: usize,
    token: *const c_char,
    options: *const StrataConnectOptions,
    out_session: *mut *mut StrataSession,
) -> StrataStatus {
    let args = (address, cert_der, cert_len, token);
    // SAFETY: the caller's contract above.
    unsafe { connect_options(args, options, true, out_session) }
}

/// `strata_connect_with` and `strata_connect_cluster`.
///
/// # Safety
/// As `strata_connect_with`.
unsafe fn connect_options(
    (address, cert_der, cert_len, token): (*const c_char, *const u8, usize, *const c_char),
    options: *const StrataConnectOptions,
    cluster: bool,
    out_session: *mut *mut StrataSession,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let dst = unsafe { null_first(out_session) }?;
        // SAFETY: the caller's contract above.
        let (address, cert, token, o) = unsafe {
            (
                text(address, "address")?,
                bytes(cert_der, cert_len, "cert_der")?,
                text(token, "token")?,
                read_options(options)?,
            )
        };
        let opts = SessionOptions {
            predict: o.predict != 0,
            capabilities: o.capabilities,
            ..SessionOptions::default()
        };
        connect(address, cert, token, (opts, cluster), dst)
    })
}

/// The size of `StrataConnectOptions`' first layout (`size`, `predict`,
/// `capabilities`): the least a caller's `size` may say.
const OPTIONS_FIRST_SIZE: u32 = 12;
/// The most bytes a caller's `size` may say: far past any options this
/// library will have.
const OPTIONS_MAX_SIZE: u32 = 4096;

/// The caller's options as this library knows them: `options->size` bytes
/// read, those past this library's options checked to be 0, and options
/// past the caller's size left 0.
///
/// # Safety
/// `options` is null, misaligned, or points to `options->size` readable,
/// initialized bytes (the header's rule: zero the struct, then set it).
unsafe fn read_options(
    options: *const StrataConnectOptions,
) -> Result<StrataConnectOptions, Failure> {
    // SAFETY: forwarded from the caller; `size` is the first field.
    let size = *unsafe { shared(options.cast::<u32>(), "options") }?;
    if !(OPTIONS_FIRST_SIZE..=OPTIONS_MAX_SIZE).contains(&size) {
        return Err(Failure::invalid(format!(
            "options.size is {size}: set it to sizeof(StrataConnectOptions) \
             ({OPTIONS_FIRST_SIZE} to {OPTIONS_MAX_SIZE})"
        )));
    }
    // SAFETY: forwarded from the caller: `size` readable bytes.
    let raw = unsafe { bytes(options.cast::<u8>(), size as usize, "options") }?;
    let ours = size_of::<StrataConnectOptions>();
    if raw.iter().skip(ours).any(|b| *b != 0) {
        return Err(Failure::invalid(format!(
            "options sets fields this library does not know (its options \
             end at byte {ours}, the caller's at {size}): a newer header"
        )));
    }
    let mut o = MaybeUninit::<StrataConnectOptions>::zeroed();
    let n = raw.len().min(ours);
    // SAFETY: `n` bytes fit both the caller's options and `o`; every
    // field is an integer, for which any bytes are a value.
    let o = unsafe {
        std::ptr::copy_nonoverlapping(raw.as_ptr(), o.as_mut_ptr().cast::<u8>(), n);
        o.assume_init()
    };
    Ok(o)
}

/// The ABI this library was built with (`STRATA_ABI_VERSION` of its
/// header): a program built against another header must not call the rest.
#[no_mangle]
pub extern "C" fn strata_abi_version() -> u32 {
    STRATA_ABI_VERSION
}

/// `*out_session`, set to NULL: it stays so unless the connect succeeds
/// (a caller that frees it whatever the status frees nothing).
///
/// # Safety
/// `out_session` is null (refused) or writable.
unsafe fn null_first<'a>(
    out_session: *mut *mut StrataSession,
) -> Result<&'a mut MaybeUninit<*mut StrataSession>, Failure> {
    // SAFETY: forwarded from the caller.
    let dst = unsafe { writable(out_session, "out_session") }?;
    dst.write(std::ptr::null_mut());
    Ok(dst)
}

/// Connects (to a cluster when `cluster`) and hands the new session to
/// `*dst`.
fn connect(
    address: &str,
    cert: &[u8],
    token: &str,
    (opts, cluster): (SessionOptions, bool),
    dst: &mut MaybeUninit<*mut StrataSession>,
) -> Result<(), Failure> {
    let addrs = resolve(address)?;
    let mut result = Err(Failure::new(StrataStatus::Connect, "no address tried"));
    for (i, addr) in addrs.iter().enumerate() {
        let attempt = if cluster {
            Session::connect_cluster(*addr, cert, token, opts.clone())
        } else {
            Session::connect(*addr, cert, token, opts.clone())
        };
        match attempt {
            Ok(s) => {
                result = Ok(s);
                break;
            }
            Err(e) if try_next(&e) && i + 1 < addrs.len() => {}
            Err(e) => {
                result = Err(e.into());
                break;
            }
        }
    }
    let session = result?;
    let boxed = Box::new(StrataSession {
        session,
        last_changes: Mutex::default(),
    });
    dst.write(Box::into_raw(boxed));
    Ok(())
}

/// Closes the connection politely (waiting at most 2 s) and frees the
/// session. Null is ignored. No other call on the session may be running
/// or follow.
///
/// # Safety
/// `s` is null or a live session from `strata_connect`, not used again.
#[no_mangle]
pub unsafe extern "C" fn strata_session_free(s: *mut StrataSession) {
    if s.is_null() {
        return;
    }
    call_quiet(|| {
        // SAFETY: a live session from `Box::into_raw`, given back once.
        let boxed = unsafe { Box::from_raw(s) };
        boxed.session.close();
    });
}

/// The server's greeting.
///
/// # Safety
/// `s` is a live session; `out` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_welcome(
    s: *const StrataSession,
    out_welcome: *mut StrataWelcome,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let (w, dst) = unsafe { (session(s)?.welcome(), writable(out_welcome, "out_welcome")?) };
        let mut welcome = StrataWelcome {
            session: w.session,
            world_seed: w.world_seed,
            last_seq: w.last_seq,
            view_radius: w.view_radius,
            resume: 0,
            resume_feet: [0.0; 3],
            spawn_x: 0,
            spawn_z: 0,
            spawn_radius: 0,
        };
        match w.start {
            Start::Resume { feet } => {
                welcome.resume = 1;
                welcome.resume_feet = feet.to_f64();
            }
            Start::Spawn { x, z, radius } => {
                (welcome.spawn_x, welcome.spawn_z, welcome.spawn_radius) = (x, z, radius);
            }
        }
        dst.write(welcome);
        Ok(())
    })
}

/// Reports the player's feet position in voxels (an unreliable datagram:
/// send it every frame or so). The view follows it; one `strata_subscribe`
/// asked moves with it once the feet pass its reach (see there).
///
/// # Safety
/// `s` is a live session.
#[no_mangle]
pub unsafe extern "C" fn strata_set_position(
    s: *const StrataSession,
    x: f64,
    y: f64,
    z: f64,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let session = unsafe { session(s) }?;
        Ok(session.set_position(DVec3::new(x, y, z))?)
    })
}

/// Asks for the chunks within `radius` chunks of chunk (`cx`, `cy`, `cz`)
/// (capped at the view radius). The whole cube must lie within the view
/// radius plus the hysteresis (in chunks) of the player; positions then
/// move it only when it would reach farther (to the feet, keeping its
/// radius). A centre outside the world (a coordinate past ±131072 chunks)
/// is STRATA_STATUS_INVALID_ARGUMENT; after DISCONNECTED,
/// STRATA_STATUS_CLOSED.
///
/// # Safety
/// `s` is a live session.
#[no_mangle]
pub unsafe extern "C" fn strata_subscribe(
    s: *const StrataSession,
    cx: i32,
    cy: i32,
    cz: i32,
    radius: u8,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let session = unsafe { session(s) }?;
        Ok(session.subscribe(IVec3::new(cx, cy, cz), radius)?)
    })
}

/// Drops `count` chunks the game no longer wants (at most 1024):
/// `chunks` holds `count` (x, y, z) chunk coordinates. They stop being
/// held at once, and the server stops sending their updates until
/// `strata_resync`, or until they leave the view and come back. After
/// DISCONNECTED, STRATA_STATUS_CLOSED.
///
/// # Safety
/// `s` is a live session; `chunks` points to `count` `int32_t[3]`.
#[no_mangle]
pub unsafe extern "C" fn strata_forget(
    s: *const StrataSession,
    chunks: *const [i32; 3],
    count: usize,
) -> StrataStatus {
    call(|| {
        // Checked before anything is read: a count past the limit is
        // refused, never read beyond the caller's buffer.
        let max = strata_client::protocol::limits::MAX_FORGET_CHUNKS;
        if count > max {
            return Err(Failure::invalid(format!(
                "{count} chunks to forget; at most {max} at once"
            )));
        }
        // SAFETY: the caller's contract above.
        let (session, chunks) = unsafe { (session(s)?, items(chunks, count, "chunks")?) };
        let chunks: Vec<IVec3> = chunks.iter().map(|c| IVec3::from_array(*c)).collect();
        Ok(session.forget(&chunks)?)
    })
}

/// Asks the server to send chunk (`cx`, `cy`, `cz`) again: one forgotten
/// with `strata_forget`, or one whose copy looks wrong. It must be in view.
/// After DISCONNECTED, STRATA_STATUS_CLOSED.
///
/// # Safety
/// `s` is a live session.
#[no_mangle]
pub unsafe extern "C" fn strata_resync(
    s: *const StrataSession,
    cx: i32,
    cy: i32,
    cz: i32,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let session = unsafe { session(s) }?;
        Ok(session.resync(IVec3::new(cx, cy, cz))?)
    })
}

fn to_edit(e: &StrataEdit) -> Result<Edit, Failure> {
    let center = DVec3::from_array(e.center);
    let (min, max) = (IVec3::from_array(e.min), IVec3::from_array(e.max));
    let bad = |e: edits::EditBuildError| Failure::invalid(e.to_string());
    Ok(match e.kind {
        k if k == StrataEditKind::Mine as u32 => {
            edits::mine(center, e.radius, e.strength).map_err(bad)?
        }
        k if k == StrataEditKind::Explode as u32 => {
            edits::explode(center, e.radius, e.power).map_err(bad)?
        }
        k if k == StrataEditKind::Build as u32 => {
            edits::build(center, e.radius, e.material, e.strength).map_err(bad)?
        }
        k if k == StrataEditKind::FillBox as u32 => edits::fill_box(min, max, e.material),
        k if k == StrataEditKind::ClearBox as u32 => edits::clear_box(min, max),
        k if k == StrataEditKind::PlaceStructure as u32 => {
            edits::place_structure(e.structure, min, e.rotation)
        }
        k if k == StrataEditKind::Smooth as u32 => {
            edits::smooth(center, e.radius, e.strength).map_err(bad)?
        }
        k => return Err(Failure::invalid(format!("unknown edit kind {k}"))),
    })
}

/// Sends an edit without waiting: `*out_ticket` names it in the
/// EDIT_ACCEPTED, EDIT_REJECTED or EDIT_FAILED event that `strata_poll`
/// will return for it (exactly one). Edits reach the server in call order
/// (on a cluster, those of one region in call order: the region of each
/// edit's centre, box corner or origin).
/// After DISCONNECTED, STRATA_STATUS_CLOSED (no ticket).
///
/// # Safety
/// `s` is a live session; `edit` points to a `StrataEdit`; `out_ticket`
/// is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_edit(
    s: *const StrataSession,
    edit: *const StrataEdit,
    out_ticket: *mut u64,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let (session, edit, dst) = unsafe {
            (
                session(s)?,
                shared(edit, "edit")?,
                writable(out_ticket, "out_ticket")?,
            )
        };
        dst.write(session.edit(to_edit(edit)?)?);
        Ok(())
    })
}

fn reject_code(r: &RejectReason) -> StrataReject {
    match r {
        RejectReason::NotPermitted { .. } => StrataReject::NotPermitted,
        RejectReason::RadiusTooLarge { .. } => StrataReject::RadiusTooLarge,
        RejectReason::PowerTooLarge { .. } => StrataReject::PowerTooLarge,
        RejectReason::OutOfReach { .. } => StrataReject::OutOfReach,
        RejectReason::NoLineOfSight => StrataReject::NoLineOfSight,
        RejectReason::RateLimited => StrataReject::RateLimited,
        RejectReason::VolumeRateLimited => StrataReject::VolumeRateLimited,
        RejectReason::OutOfBounds => StrataReject::OutOfBounds,
        RejectReason::ProtectedZone { .. } => StrataReject::ProtectedZone,
        RejectReason::NoPosition => StrataReject::NoPosition,
        RejectReason::Invalid { .. } => StrataReject::Invalid,
        RejectReason::Busy => StrataReject::Busy,
        RejectReason::RegionElsewhere { .. } => StrataReject::RegionElsewhere,
        RejectReason::NodeFull { .. } => StrataReject::NodeFull,
    }
}

fn refusal_code(r: &PositionRefusal) -> StrataPositionRefusal {
    match r {
        PositionRefusal::TooFast { .. } => StrataPositionRefusal::TooFast,
        PositionRefusal::InsideSolid { .. } => StrataPositionRefusal::InsideSolid,
        PositionRefusal::OutsideSpawn { .. } => StrataPositionRefusal::OutsideSpawn,
        PositionRefusal::OutOfBounds => StrataPositionRefusal::OutOfBounds,
        PositionRefusal::PathBlocked { .. } => StrataPositionRefusal::PathBlocked,
        PositionRefusal::TooHigh { .. } => StrataPositionRefusal::TooHigh,
    }
}

fn empty_event() -> StrataEvent {
    StrataEvent {
        kind: StrataEventKind::None,
        ticket: 0,
        seq: 0,
        changes: std::ptr::null(),
        changes_len: 0,
        reject: StrataReject::None,
        chunk: [0; 3],
        error_code: 0,
        message: [0; STRATA_MESSAGE_LEN],
        position_refusal: StrataPositionRefusal::None,
        radius: 0,
        held: [0.0; 3],
        held_known: 0,
    }
}

/// Copies `text` into the event's message, truncated on a character
/// boundary and NUL-terminated.
fn set_message(ev: &mut StrataEvent, text: &str) {
    let mut n = text.len().min(STRATA_MESSAGE_LEN - 1);
    while !text.is_char_boundary(n) {
        n -= 1;
    }
    for (dst, &b) in ev.message.iter_mut().zip(&text.as_bytes()[..n]) {
        *dst = b as c_char;
    }
    ev.message[n] = 0;
}

/// `sizeof(StrataEvent)` as this library was built: a binding that mirrors
/// the struct (C#, Python) checks its own against it before polling, since
/// `strata_poll` writes this many bytes.
#[no_mangle]
pub extern "C" fn strata_event_size() -> usize {
    std::mem::size_of::<StrataEvent>()
}

/// Takes the next event into `*out_event`, or sets its kind to
/// STRATA_EVENT_KIND_NONE when nothing happened. Never waits: call it every
/// frame until it returns NONE. An EDIT_ACCEPTED event's `changes` stay
/// valid until the next `strata_poll` on this session, from any thread.
/// DISCONNECTED is the last event: every poll after it returns NONE.
///
/// # Safety
/// `s` is a live session; `out_event` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_poll(
    s: *const StrataSession,
    out_event: *mut StrataEvent,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let (handle, dst) = unsafe { (shared(s, "session")?, writable(out_event, "out_event")?) };
        let mut ev = empty_event();
        let mut last = handle
            .last_changes
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        last.clear();
        match handle.session.poll() {
            None => {}
            Some(Event::EditAccepted {
                ticket,
                seq,
                changes,
            }) => {
                last.extend(changes.iter().map(|c| StrataChunkVersion {
                    chunk: [c.pos.x, c.pos.y, c.pos.z],
                    version: c.version,
                }));
                ev.kind = StrataEventKind::EditAccepted;
                (ev.ticket, ev.seq) = (ticket, seq);
                (ev.changes, ev.changes_len) = (last.as_ptr(), last.len());
            }
            Some(Event::EditRejected { ticket, reason }) => {
                ev.kind = StrataEventKind::EditRejected;
                ev.ticket = ticket;
                ev.reject = reject_code(&reason);
                let label = strata_client::protocol::reject_label(&reason);
                set_message(&mut ev, &format!("{label}: {reason:?}"));
            }
            Some(Event::EditFailed { ticket, error }) => {
                ev.kind = StrataEventKind::EditFailed;
                ev.ticket = ticket;
                set_message(&mut ev, &error);
            }
            Some(Event::ChunkChanged { pos }) => {
                ev.kind = StrataEventKind::ChunkChanged;
                ev.chunk = [pos.x, pos.y, pos.z];
            }
            Some(Event::PositionRefused { seq, reason, at }) => {
                ev.kind = StrataEventKind::PositionRefused;
                ev.seq = u64::from(seq);
                ev.position_refusal = refusal_code(&reason);
                if let Some(at) = at {
                    (ev.held, ev.held_known) = (at.to_f64(), 1);
                }
                set_message(&mut ev, &format!("{reason:?}"));
            }
            Some(Event::ViewLoaded { center, radius }) => {
                ev.kind = StrataEventKind::ViewLoaded;
                ev.chunk = [center.x, center.y, center.z];
                ev.radius = radius;
            }
            Some(Event::Disconnected { code, message }) => {
                ev.kind = StrataEventKind::Disconnected;
                ev.error_code = code.map_or(0, |c| c.close_code());
                set_message(&mut ev, &message);
            }
        }
        dst.write(ev);
        Ok(())
    })
}

/// The replica's counters.
///
/// # Safety
/// `s` is a live session; `out_stats` is writable.
#[no_mangle]
pub unsafe extern "C" fn strata_stats(
    s: *const StrataSession,
    out_stats: *mut StrataStats,
) -> StrataStatus {
    call(|| {
        // SAFETY: the caller's contract above.
        let (session, dst) = unsafe { (session(s)?, writable(out_stats, "out_stats")?) };
        let r = session.stats();
        let stats = StrataStats {
            chunks_held: session.held_chunks() as u64,
            deltas: r.deltas,
            snapshots: r.snapshots,
            generated: r.generated,
            meshes_checked: r.meshes_checked,
            mesh_mismatches: r.mesh_mismatches,
            hash_mismatches: r.hash_mismatches,
            op_chunks: r.op_chunks,
            op_fallbacks: r.op_gaps + r.op_mismatches,
        };
        dst.write(stats);
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::CStr;

    #[test]
    fn a_long_message_is_cut_on_a_char_boundary() {
        let mut ev = empty_event();
        set_message(&mut ev, &"é".repeat(200));
        let bytes: Vec<u8> = ev.message.iter().map(|&c| c as u8).collect();
        let message = CStr::from_bytes_until_nul(&bytes).expect("NUL-terminated");
        assert_eq!(message.to_str(), Ok("é".repeat(127).as_str()));
    }

    /// A failed connect or mesh leaves NULL behind, whatever the caller's
    /// variable held: freeing it whatever the status frees nothing.
    #[test]
    fn failures_leave_null_out_pointers() {
        let garbage = std::ptr::NonNull::<u8>::dangling().as_ptr();
        let mut session = garbage.cast::<StrataSession>();
        let cert = [0u8; 4];
        // SAFETY: valid strings, a 4-byte certificate, a writable out.
        let status = unsafe {
            strata_connect(
                c"not an address".as_ptr(),
                cert.as_ptr(),
                cert.len(),
                c"token".as_ptr(),
                0,
                &mut session,
            )
        };
        assert_ne!(status, StrataStatus::Ok);
        assert!(session.is_null());
        // Refused before anything is read too (a null address).
        session = garbage.cast();
        // SAFETY: a null address is refused; the rest as above.
        let status = unsafe {
            strata_connect(
                std::ptr::null(),
                cert.as_ptr(),
                4,
                c"t".as_ptr(),
                0,
                &mut session,
            )
        };
        assert_eq!(status, StrataStatus::InvalidArgument);
        assert!(session.is_null());
        // SAFETY: null, which it ignores.
        unsafe { strata_session_free(session) };
        let mut mesh = garbage.cast::<crate::chunk::StrataMesh>();
        // SAFETY: a null session is refused; the out pointer is writable.
        let status =
            unsafe { crate::chunk::strata_mesh(std::ptr::null(), 0, 0, 0, 0, 0, &mut mesh) };
        assert_eq!(status, StrataStatus::InvalidArgument);
        assert!(mesh.is_null());
    }

    #[test]
    fn addresses_are_tried_ipv4_first_without_repeats_and_few() {
        let a = |s: &str| s.parse::<SocketAddr>().unwrap();
        let found = [
            a("[::1]:4433"),
            a("127.0.0.1:4433"),
            a("[::1]:4433"),
            a("10.0.0.1:4433"),
            a("[fe80::1]:4433"),
            a("10.0.0.2:4433"),
            a("10.0.0.3:4433"),
        ];
        assert_eq!(
            to_try(found.into_iter()),
            [
                a("127.0.0.1:4433"),
                a("10.0.0.1:4433"),
                a("10.0.0.2:4433"),
                a("10.0.0.3:4433")
            ]
        );
        assert_eq!(resolve("localhost:4433").unwrap()[0].port(), 4433);
        assert!(resolve("no-such-host.invalid:1").is_err());
    }
}
