//! libstrata: the C ABI of `strata-client`, for game engines in any
//! language. `include/strata.h` is generated from this crate by cbindgen
//! (`cbindgen.toml` holds its preamble: ownership and threading rules), and
//! a test fails when the checked-in header differs from the code.
//!
//! Every entry point runs inside [`status::call`]: no panic crosses the
//! boundary, and a failure is a status code plus a per-thread message.

mod chunk;
mod ptr;
mod session;
mod status;
mod types;

// The entry points, also for Rust callers and tests.
pub use chunk::*;
pub use session::*;
pub use status::{strata_last_error_message, StrataStatus};
pub use types::*;
