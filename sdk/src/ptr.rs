//! Reading the caller's pointers. Each helper turns null, and a pointer not
//! aligned for its type, into `STRATA_STATUS_INVALID_ARGUMENT` instead of
//! undefined behaviour; the rest of each pointer's contract is the
//! caller's, as the header states.

use std::ffi::{c_char, CStr};
use std::mem::MaybeUninit;

use crate::status::Failure;

/// A NUL-terminated UTF-8 string.
///
/// # Safety
/// `p` is null or points to a NUL-terminated string valid for the call.
pub(crate) unsafe fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, Failure> {
    if p.is_null() {
        return Err(Failure::invalid(format!("{what} is null")));
    }
    // SAFETY: non-null, and the caller promises a NUL-terminated string.
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map_err(|_| Failure::invalid(format!("{what} is not UTF-8")))
}

/// A shared reference.
///
/// # Safety
/// `p` is null, misaligned, or points to a live, initialised `T` not
/// written during the call.
pub(crate) unsafe fn shared<'a, T>(p: *const T, what: &str) -> Result<&'a T, Failure> {
    aligned(p, what)?;
    // SAFETY: non-null and aligned (checked above); the caller promises a
    // live `T` there.
    unsafe { p.as_ref() }.ok_or_else(|| Failure::invalid(format!("{what} is null")))
}

/// Refuses a null pointer, or one not aligned for `T` (making a reference
/// of it would be undefined behaviour, whatever it points to).
fn aligned<T>(p: *const T, what: &str) -> Result<(), Failure> {
    if p.is_null() {
        return Err(Failure::invalid(format!("{what} is null")));
    }
    if !p.is_aligned() {
        return Err(Failure::invalid(format!("{what} is misaligned")));
    }
    Ok(())
}

/// Where to write a result, checked for null before the call does any
/// work; written with `MaybeUninit::write`, which drops no old value.
///
/// # Safety
/// `p` is null, misaligned, or points to writable memory for a `T`, not
/// accessed otherwise during the call.
pub(crate) unsafe fn writable<'a, T>(
    p: *mut T,
    what: &str,
) -> Result<&'a mut MaybeUninit<T>, Failure> {
    aligned(p.cast_const(), what)?;
    // SAFETY: non-null and aligned (checked above); the caller promises
    // writable memory for a `T` there; `MaybeUninit<T>` has `T`'s layout
    // and may hold anything.
    unsafe { p.cast::<MaybeUninit<T>>().as_mut() }
        .ok_or_else(|| Failure::invalid(format!("{what} is null")))
}

/// A byte slice.
///
/// # Safety
/// `p` is null (then `len` must be 0) or points to `len` readable bytes.
pub(crate) unsafe fn bytes<'a>(p: *const u8, len: usize, what: &str) -> Result<&'a [u8], Failure> {
    // SAFETY: forwarded from the caller.
    unsafe { items(p, len, what) }
}

/// A slice of `len` values.
///
/// # Safety
/// `p` is null (then `len` must be 0) or points to `len` readable `T`s.
pub(crate) unsafe fn items<'a, T>(p: *const T, len: usize, what: &str) -> Result<&'a [T], Failure> {
    if p.is_null() {
        if len == 0 {
            return Ok(&[]);
        }
        return Err(Failure::invalid(format!("{what} is null")));
    }
    // No slice may span more than isize::MAX bytes (a length gone
    // negative in C, say): refused before one is made.
    if len > isize::MAX as usize / std::mem::size_of::<T>().max(1) {
        return Err(Failure::invalid(format!(
            "{what}: {len} items is no length"
        )));
    }
    if !p.is_aligned() {
        return Err(Failure::invalid(format!("{what} is misaligned")));
    }
    // SAFETY: non-null, aligned, a length that fits, and `len` readable
    // values, as the caller promises.
    Ok(unsafe { std::slice::from_raw_parts(p, len) })
}
