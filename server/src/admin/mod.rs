//! `strata-admin` commands. The binary only parses arguments and prints;
//! the work lives here so it can be tested without a process.

pub mod export;
pub mod generate;
pub mod mesh_cmd;
pub mod obj;
pub mod ply;
pub mod token_cmd;
pub mod verify_acks;
