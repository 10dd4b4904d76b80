//! `strata-admin` commands. The binary only parses arguments and prints;
//! the work lives here so it can be tested without a process.

pub mod access_cmd;
pub mod check;
pub mod cluster_cmd;
pub mod export;
pub mod export_mesh;
pub mod generate;
pub mod glb;
pub mod inspect;
pub mod map;
pub mod mesh_cmd;
pub mod obj;
pub mod players;
pub mod ply;
pub mod remote;
pub mod render_map;
pub mod snapshot_cmd;
pub mod stale_outputs;
pub mod stats;
pub mod token_cmd;
pub mod verify_acks;
pub mod world_source;
pub mod zones_cmd;
