//! The C ABI's calls as the tests make them: each asserts OK (with the
//! library's message) and returns what it wrote.

use std::ffi::{CStr, CString};
use std::mem::MaybeUninit;
use std::ptr::null_mut;

use strata::*;

use super::Server;

/// The calling thread's last error message.
pub fn last_error() -> String {
    // SAFETY: the library's NUL-terminated string, read at once.
    unsafe { CStr::from_ptr(strata_last_error_message()) }
        .to_string_lossy()
        .into_owned()
}

/// `strata_connect` (no prediction) to `server` as `player`.
pub fn connect(server: &Server, player: &str) -> *mut StrataSession {
    let addr = CString::new(server.address()).unwrap();
    let token = CString::new(server.token(player)).unwrap();
    let cert = &server.running.cert_der;
    let mut s = null_mut();
    // SAFETY: NUL-terminated strings, `cert.len()` readable bytes and a
    // writable out pointer.
    let st = unsafe {
        strata_connect(
            addr.as_ptr(),
            cert.as_ptr(),
            cert.len(),
            token.as_ptr(),
            0,
            &mut s,
        )
    };
    assert_eq!(st, StrataStatus::Ok, "{}", last_error());
    s
}

/// `strata_connect_with` to `addr`, trusting `cert`.
pub fn connect_with(
    addr: &str,
    cert: &[u8],
    token: &str,
    options: &StrataConnectOptions,
) -> *mut StrataSession {
    let addr = CString::new(addr).unwrap();
    let token = CString::new(token).unwrap();
    let mut s = null_mut();
    // SAFETY: NUL-terminated strings, `cert.len()` readable bytes, live
    // options and a writable out pointer.
    let st = unsafe {
        strata_connect_with(
            addr.as_ptr(),
            cert.as_ptr(),
            cert.len(),
            token.as_ptr(),
            options,
            &mut s,
        )
    };
    assert_eq!(st, StrataStatus::Ok, "{}", last_error());
    s
}

/// The next event of live session `s` (kind NONE when there is none).
pub fn poll(s: *mut StrataSession) -> StrataEvent {
    let mut ev = MaybeUninit::<StrataEvent>::uninit();
    // SAFETY: `s` is live; `ev` is writable.
    let st = unsafe { strata_poll(s, ev.as_mut_ptr()) };
    assert_eq!(st, StrataStatus::Ok, "{}", last_error());
    // SAFETY: written by the call above.
    unsafe { ev.assume_init() }
}

/// The counters of live session `s`.
pub fn stats(s: *mut StrataSession) -> StrataStats {
    let mut out = MaybeUninit::<StrataStats>::uninit();
    // SAFETY: `s` is live; `out` is writable.
    let st = unsafe { strata_stats(s, out.as_mut_ptr()) };
    assert_eq!(st, StrataStatus::Ok, "{}", last_error());
    // SAFETY: written by the call above.
    unsafe { out.assume_init() }
}

/// A dig at (3.5, 40.5, 3.5); without a position the server answers it
/// NO_POSITION.
pub fn dig() -> StrataEdit {
    StrataEdit {
        kind: StrataEditKind::Mine as u32,
        center: [3.5, 40.5, 3.5],
        radius: 2.0,
        strength: 255,
        power: 0,
        material: 0,
        min: [0; 3],
        max: [0; 3],
        structure: 0,
        rotation: 0,
    }
}
