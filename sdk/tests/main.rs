//! strata-sdk's integration tests, one module per file beside this one, in
//! one test binary. Run one file's tests with
//! `cargo test -p strata-sdk --test integration -- session::`.

mod common;

mod boundary;
mod cluster;
mod examples;
mod header;
mod hostile;
mod out_pointers;
mod session;
