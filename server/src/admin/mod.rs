//! Offline administration commands behind the `strata-admin` binary. The
//! binary only parses arguments and prints; the work lives here so it can be
//! tested without a process.

pub mod export;
pub mod mesh_cmd;
pub mod obj;
pub mod ply;
