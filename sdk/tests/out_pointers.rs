//! Out-pointers are checked before any work, against a real server: a
//! call with a null one returns INVALID_ARGUMENT and does nothing else (no
//! edit sent, no event taken, no login).

use crate::common::ffi::{connect, dig, last_error, poll};
use crate::common::Server;

use std::ffi::CString;
use std::ptr::null_mut;
use std::time::{Duration, Instant};

use strata::*;

const WAIT: Duration = Duration::from_secs(10);

/// Sends `dig()` on live session `s`; its ticket.
fn edit(s: *mut StrataSession) -> u64 {
    let mut ticket = 0;
    // SAFETY: `s` is live, the edit readable, `ticket` writable.
    let st = unsafe { strata_edit(s, &dig(), &mut ticket) };
    assert_eq!(st, StrataStatus::Ok, "{}", last_error());
    ticket
}

fn is_verdict(ev: &StrataEvent) -> bool {
    use StrataEventKind::*;
    matches!(ev.kind, EditAccepted | EditRejected | EditFailed)
}

/// Polls until the verdict of `ticket` comes; panics after [`WAIT`].
fn wait_verdict(s: *mut StrataSession, ticket: u64) -> StrataEvent {
    let start = Instant::now();
    while start.elapsed() < WAIT {
        let ev = poll(s);
        if is_verdict(&ev) && ev.ticket == ticket {
            return ev;
        }
        if ev.kind == StrataEventKind::None {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    panic!("no verdict for edit {ticket}");
}

#[test]
fn an_edit_with_a_null_ticket_pointer_is_not_sent() {
    let server = Server::start();
    let s = connect(&server, "null-ticket");
    // SAFETY: `s` is live and the edit readable; the null ticket is tested.
    let st = unsafe { strata_edit(s, &dig(), null_mut()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "out_ticket is null");
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(2) {
        let ev = poll(s);
        assert!(!is_verdict(&ev), "a verdict for a refused call: {ev:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    // The next edit gets the first ticket, and its verdict comes.
    let ticket = edit(s);
    assert_eq!(ticket, 1, "the refused call took no ticket");
    let ev = wait_verdict(s, ticket);
    assert_eq!(ev.reject, StrataReject::NoPosition, "{ev:?}");
    // SAFETY: `s` is live and nothing else uses it.
    unsafe { strata_session_free(s) };
}

#[test]
fn a_poll_with_a_null_event_pointer_takes_no_event() {
    let server = Server::start();
    let s = connect(&server, "null-event");
    let ticket = edit(s);
    // Long enough for the verdict to arrive: each call would have taken it.
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(1) {
        // SAFETY: `s` is live; the null event is what is tested.
        let st = unsafe { strata_poll(s, null_mut()) };
        assert_eq!(st, StrataStatus::InvalidArgument);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(last_error(), "out_event is null");
    let ev = wait_verdict(s, ticket);
    assert_eq!(ev.kind, StrataEventKind::EditRejected, "{ev:?}");
    // SAFETY: `s` is live and nothing else uses it.
    unsafe { strata_session_free(s) };
}

#[test]
fn a_connect_with_a_null_session_pointer_does_not_log_in() {
    let server = Server::start();
    // A socket that never answers: a login attempt would wait 10 s.
    let silent = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let addr = CString::new(silent.local_addr().unwrap().to_string()).unwrap();
    let token = CString::new(server.token("null-session")).unwrap();
    let cert = &server.running.cert_der;
    let options = StrataConnectOptions {
        size: std::mem::size_of::<StrataConnectOptions>() as u32,
        predict: 0,
        capabilities: 0,
    };
    let start = Instant::now();
    // SAFETY: NUL-terminated strings, `cert.len()` readable bytes, live
    // options; the null out pointers are what is tested.
    let statuses = unsafe {
        [
            strata_connect(
                addr.as_ptr(),
                cert.as_ptr(),
                cert.len(),
                token.as_ptr(),
                0,
                null_mut(),
            ),
            strata_connect_cluster(
                addr.as_ptr(),
                cert.as_ptr(),
                cert.len(),
                token.as_ptr(),
                &options,
                null_mut(),
            ),
        ]
    };
    assert_eq!(statuses, [StrataStatus::InvalidArgument; 2]);
    assert_eq!(last_error(), "out_session is null");
    assert!(
        start.elapsed() < Duration::from_secs(1),
        "{:?}",
        start.elapsed()
    );
}

#[test]
fn misaligned_out_pointers_are_refused_not_skipped() {
    let server = Server::start();
    let s = connect(&server, "misaligned");
    let mut buf = [0u64; 16];
    let odd = buf.as_mut_ptr().cast::<u8>().wrapping_add(4);
    // SAFETY: `s` is live; the misaligned out pointer is what is tested.
    let st = unsafe { strata_welcome(s, odd.cast::<StrataWelcome>()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "out_welcome is misaligned");
    // A null `out_version` is skipped; a misaligned one is an error, not
    // skipped, even for a chunk not held.
    // SAFETY: as above; null buffers are skipped.
    let st = unsafe { strata_chunk_read(s, 0, 0, 0, null_mut(), null_mut(), 0, odd.cast::<u64>()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "out_version is misaligned");
    assert_eq!(buf, [0; 16], "nothing was written");
    // SAFETY: `s` is live and nothing else uses it.
    unsafe { strata_session_free(s) };
}
