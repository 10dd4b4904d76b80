//! `strata-admin` commands. The binary only parses arguments and prints;
//! the work lives here so it can be tested without a process.

pub mod export;
pub mod generate;
pub mod inspect;
pub mod mesh_cmd;
pub mod obj;
pub mod players;
pub mod ply;
pub mod remote;
pub mod snapshot_cmd;
pub mod stats;
pub mod token_cmd;
pub mod zones_cmd;
