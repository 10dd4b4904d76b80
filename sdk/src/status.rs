//! Every call returns a status; on failure the calling thread's last error
//! message says more. No panic crosses the boundary: [`call`] catches it
//! and returns `Panic`.

use std::cell::RefCell;
use std::ffi::{c_char, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

use strata_client::{ClientError, SessionError};

/// What a call did.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StrataStatus {
    Ok = 0,
    /// A null pointer, a string that is not UTF-8, a number out of range.
    InvalidArgument = 1,
    /// The server certificate is not usable, or TLS could not be set up.
    Tls = 2,
    /// The address could not be resolved or reached.
    Connect = 3,
    /// The server refused or ended the session (bad token, kicked...).
    Refused = 4,
    /// The server broke the protocol.
    Protocol = 5,
    /// The connection has ended.
    Closed = 6,
    /// The server did not answer in time.
    Timeout = 7,
    /// Too much in flight: poll events, then try again.
    Busy = 8,
    /// The chunk is not held (not yet streamed, or out of view).
    NotHeld = 9,
    /// Bad mesh options (LOD above 3, transition faces at LOD 0...).
    Mesh = 10,
    /// The connection's thread could not start.
    Runtime = 11,
    /// A bug inside the library; the session should be freed.
    Panic = 12,
}

/// A failed call: its status and message.
#[derive(Debug)]
pub(crate) struct Failure {
    status: StrataStatus,
    message: String,
}

impl Failure {
    pub(crate) fn new(status: StrataStatus, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Self {
        Self::new(StrataStatus::InvalidArgument, message)
    }
}

impl From<ClientError> for Failure {
    fn from(e: ClientError) -> Self {
        Failure::new(client_status(&e), e.to_string())
    }
}

impl From<SessionError> for Failure {
    fn from(e: SessionError) -> Self {
        let status = match &e {
            SessionError::Client(c) => client_status(c),
            SessionError::Runtime(_) => StrataStatus::Runtime,
            SessionError::Busy => StrataStatus::Busy,
            SessionError::Edit(_) | SessionError::BadPosition => StrataStatus::InvalidArgument,
            SessionError::Mesh(_) => StrataStatus::Mesh,
        };
        Failure::new(status, e.to_string())
    }
}

fn client_status(e: &ClientError) -> StrataStatus {
    match e {
        ClientError::Tls(_) => StrataStatus::Tls,
        ClientError::Connect(_) => StrataStatus::Connect,
        ClientError::Refused { .. } => StrataStatus::Refused,
        ClientError::Protocol(_) | ClientError::Violation(_) => StrataStatus::Protocol,
        ClientError::Closed(_) => StrataStatus::Closed,
        ClientError::Timeout(_) => StrataStatus::Timeout,
        ClientError::TooManyChunks { .. } | ClientError::OutsideWorld { .. } => {
            StrataStatus::InvalidArgument
        }
    }
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    // A NUL inside the message would cut it short in C: drop those bytes.
    let bytes: Vec<u8> = message.bytes().filter(|&b| b != 0).collect();
    let c = CString::new(bytes).unwrap_or_default();
    // Gone while the thread exits (a thread-local destructor calling in):
    // the message is lost, never a panic.
    let _ = LAST_ERROR.try_with(|e| *e.borrow_mut() = c);
}

/// Runs one entry point: its failure or panic becomes a status and this
/// thread's last error message.
pub(crate) fn call(f: impl FnOnce() -> Result<(), Failure>) -> StrataStatus {
    // Unwind safety: after a panic the caller is told Panic and
    // should free the session; a poisoned lock inside makes every later
    // call on it panic again, which is caught here again.
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => StrataStatus::Ok,
        Ok(Err(failure)) => {
            set_last_error(&failure.message);
            failure.status
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            set_last_error(&format!("panic inside libstrata: {what}"));
            StrataStatus::Panic
        }
    }
}

/// Runs an entry point that returns nothing (the frees): a panic is
/// caught, and, as the caller cannot be told, the thread's last error
/// message is left as it was (a pointer to it stays valid).
pub(crate) fn call_quiet(f: impl FnOnce()) {
    let _ = catch_unwind(AssertUnwindSafe(f));
}

/// The message of the last call that failed on this thread (empty if none
/// has). The string belongs to the library and stays valid until the next
/// failing call on this thread.
#[no_mangle]
pub extern "C" fn strata_last_error_message() -> *const c_char {
    LAST_ERROR
        .try_with(|e| e.borrow().as_ptr())
        .unwrap_or(c"".as_ptr())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::CStr;

    fn last() -> String {
        // SAFETY: the library's own NUL-terminated string, read at once.
        unsafe { CStr::from_ptr(strata_last_error_message()) }
            .to_string_lossy()
            .into_owned()
    }

    #[test]
    fn a_panic_becomes_a_status_and_a_message() {
        assert_eq!(call(|| panic!("boom")), StrataStatus::Panic);
        assert_eq!(last(), "panic inside libstrata: boom");
        assert_eq!(
            call(|| Err(Failure::invalid("no\0nul"))),
            StrataStatus::InvalidArgument
        );
        assert_eq!(last(), "nonul");
        assert_eq!(call(|| Ok(())), StrataStatus::Ok);
        assert_eq!(last(), "nonul", "kept until the next failure");
    }

    #[test]
    fn a_failing_call_from_a_thread_exit_destructor_does_not_abort() {
        struct Guard(std::sync::mpsc::Sender<(StrataStatus, String)>);
        impl Drop for Guard {
            fn drop(&mut self) {
                let status = call(|| Err(Failure::invalid("late")));
                let _ = self.0.send((status, last()));
            }
        }
        thread_local! {
            static GUARD: RefCell<Option<Guard>> = const { RefCell::new(None) };
        }
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            // Set before LAST_ERROR, so destroyed after it.
            GUARD.with(|g| *g.borrow_mut() = Some(Guard(tx)));
            assert_eq!(
                call(|| Err(Failure::invalid("early"))),
                StrataStatus::InvalidArgument
            );
        })
        .join()
        .expect("the thread exits cleanly");
        let (status, message) = rx.recv().expect("the guard was dropped");
        assert_eq!(status, StrataStatus::InvalidArgument);
        assert_eq!(message, "", "no message once LAST_ERROR is gone");
    }
}
