//! The boundary without a server: null pointers, a refused connection and
//! bad arguments are status codes with messages, never crashes.

use crate::common::ffi::last_error;

use std::ffi::CString;
use std::ptr::{null, null_mut};

use strata::*;

/// `strata_connect_with` to a closed port, with a junk token and
/// certificate: only argument checks can answer it OK.
///
/// # Safety
/// As `strata_connect_with`'s for `options` and `out_session`.
unsafe fn connect_with_junk(
    options: *const StrataConnectOptions,
    out_session: *mut *mut StrataSession,
) -> StrataStatus {
    let (addr, token, cert) = (c"127.0.0.1:9", c"v1.x.y", [1u8, 2, 3]);
    // SAFETY: valid strings and 3 readable bytes; the caller answers for
    // the rest.
    unsafe {
        strata_connect_with(
            addr.as_ptr(),
            cert.as_ptr(),
            3,
            token.as_ptr(),
            options,
            out_session,
        )
    }
}

#[test]
fn null_pointers_are_invalid_arguments() {
    let mut ev = std::mem::MaybeUninit::<StrataEvent>::uninit();
    // SAFETY: a null session is what is being tested; `ev` is writable.
    let st = unsafe { strata_poll(null(), ev.as_mut_ptr()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "session is null");
    // SAFETY: null out pointers are what is being tested.
    let st = unsafe { strata_chunk_of(1.0, 2.0, 3.0, null_mut()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    let mut c = [0i32; 3];
    // SAFETY: `c` holds 3 writable i32.
    let st = unsafe { strata_chunk_of(-0.5, 40.0, 70.0, c.as_mut_ptr()) };
    assert_eq!((st, c), (StrataStatus::Ok, [-1, 1, 2]));
    let mut s = null_mut();
    // SAFETY: a writable out pointer; null options are what is tested.
    let st = unsafe { connect_with_junk(null(), &mut s) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "options is null");
    // SAFETY: null is ignored by both.
    unsafe {
        strata_session_free(null_mut());
        strata_mesh_free(null_mut());
    }
}

#[test]
fn a_bad_certificate_or_address_is_a_status_with_a_message() {
    let addr = CString::new("127.0.0.1:9").unwrap();
    let token = CString::new("v1.x.y").unwrap();
    let junk = [1u8, 2, 3];
    let mut s = null_mut();
    // SAFETY: valid strings, 3 readable bytes, a writable out pointer.
    let st = unsafe { strata_connect(addr.as_ptr(), junk.as_ptr(), 3, token.as_ptr(), 0, &mut s) };
    assert_eq!(st, StrataStatus::Tls, "{}", last_error());
    assert!(s.is_null());
    // Any byte is a sound `predict` (a foreign `true` may be 0xff).
    // SAFETY: as above.
    let st = unsafe {
        strata_connect(
            addr.as_ptr(),
            junk.as_ptr(),
            3,
            token.as_ptr(),
            0xff,
            &mut s,
        )
    };
    assert_eq!(st, StrataStatus::Tls, "{}", last_error());
    let nowhere = CString::new("no-such-host.invalid:4433").unwrap();
    // SAFETY: as above.
    let st = unsafe {
        strata_connect(
            nowhere.as_ptr(),
            junk.as_ptr(),
            3,
            token.as_ptr(),
            0,
            &mut s,
        )
    };
    assert_eq!(st, StrataStatus::Connect, "{}", last_error());
    assert!(last_error().contains("no-such-host.invalid"));
}

#[test]
fn forget_and_resync_check_their_pointers() {
    // SAFETY: a null session is what is being tested.
    let st = unsafe { strata_forget(null(), null(), 0) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "session is null");
    // A count past the limit (here one gone negative in C) is refused
    // before any pointer is read.
    // SAFETY: nothing is read: the count is refused first.
    let st = unsafe { strata_forget(null(), null(), usize::MAX) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert!(
        last_error().contains("at most 1024 at once"),
        "{}",
        last_error()
    );
    // SAFETY: as above.
    let st = unsafe { strata_resync(null(), 0, 0, 0) };
    assert_eq!(st, StrataStatus::InvalidArgument);
}

#[test]
fn misaligned_pointers_are_invalid_arguments() {
    // Room for a value one byte past an aligned start.
    let mut buf = [0u64; 8];
    let odd = buf.as_mut_ptr().cast::<u8>().wrapping_add(1);
    // SAFETY: the out pointer is misaligned, which is what is tested: the
    // call refuses it before writing.
    let st = unsafe { strata_chunk_of(1.0, 2.0, 3.0, odd.cast::<i32>()) };
    assert_eq!(st, StrataStatus::InvalidArgument);
    assert_eq!(last_error(), "out_chunk is misaligned");
    assert_eq!(buf, [0; 8], "nothing was written");
    // A misaligned options struct is refused before any connection.
    let mut s = null_mut();
    // SAFETY: a writable out pointer; the misaligned options (inside
    // `buf`, readable) are what is tested.
    let st = unsafe { connect_with_junk(odd.cast::<StrataConnectOptions>().cast_const(), &mut s) };
    assert_eq!(st, StrataStatus::InvalidArgument, "{}", last_error());
    assert_eq!(last_error(), "options is misaligned");
    // A misaligned out_session likewise.
    let options = StrataConnectOptions {
        size: std::mem::size_of::<StrataConnectOptions>() as u32,
        predict: 0,
        capabilities: 0,
    };
    // SAFETY: live options; the misaligned out pointer (inside `buf`,
    // writable) is what is tested.
    let st = unsafe { connect_with_junk(&options, odd.cast::<*mut StrataSession>()) };
    assert_eq!(st, StrataStatus::InvalidArgument, "{}", last_error());
    assert_eq!(last_error(), "out_session is misaligned");
    assert_eq!(buf, [0; 8], "nothing was written");
}

/// `StrataConnectOptions.size` lets options grow without breaking callers:
/// a size below the first layout (the layout before `size` existed reads
/// so) and bytes set past the options this library knows are refused; a
/// larger struct whose extra bytes are 0 is read as this library's own.
#[test]
fn options_are_read_as_long_as_the_caller_says() {
    assert_eq!(strata_abi_version(), STRATA_ABI_VERSION);
    let ours = std::mem::size_of::<StrataConnectOptions>();
    // A newer header's options: ours, then 8 bytes of options unknown here.
    #[repr(C, align(4))]
    struct Newer([u8; 32]);
    let newer = |size: usize, tail: u8| {
        let mut n = Newer([0; 32]);
        n.0[..4].copy_from_slice(&(size as u32).to_ne_bytes());
        n.0[ours] = tail;
        n
    };
    let connect = |o: &Newer| {
        let mut s = null_mut();
        // SAFETY: `o` holds `size` (at most 32) readable bytes, aligned
        // as the options; `s` is writable.
        unsafe { connect_with_junk((o as *const Newer).cast(), &mut s) }
    };
    for (size, tail, refused) in [
        (0, 0, Some("options.size is 0")),
        (1, 0, Some("options.size is 1")),
        (11, 0, Some("options.size is 11")),
        (5000, 0, Some("options.size is 5000")),
        (
            ours + 8,
            7,
            Some("options sets fields this library does not know"),
        ),
        // The byte past the caller's size is not read.
        (ours, 7, None),
        (ours + 8, 0, None),
        (12, 0, None),
    ] {
        let st = connect(&newer(size, tail));
        match refused {
            Some(why) => {
                assert_eq!(st, StrataStatus::InvalidArgument, "size {size}");
                assert!(last_error().starts_with(why), "{}", last_error());
            }
            // Past the argument checks: the junk certificate fails.
            None => assert_ne!(
                st,
                StrataStatus::InvalidArgument,
                "size {size}: {}",
                last_error()
            ),
        }
    }
}
