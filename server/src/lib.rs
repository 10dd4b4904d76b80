//! Strata's authoritative server: validation, ordering, durable storage,
//! deltas, collision meshes, networking and the admin CLI's commands.
//!
//! The `sequencer` is the synchronous core; the `engine` thread drives it
//! and the `store`; `net` moves bytes between QUIC and the engine.

pub mod admin;
pub mod app;
pub mod auth;
pub use strata_protocol::client_tls;
pub mod cluster;
pub mod collision;
pub mod config;
pub mod console;
pub mod datadir;
pub mod durable;
pub mod engine;
pub mod health;
pub mod heightmap;
pub mod interest;
pub mod log_every;
pub mod mesh_buffers;
pub mod metrics;
pub mod net;
pub mod sequencer;
pub mod shutdown;
pub mod snapshot;
pub mod store;
pub mod stored_zones;
pub mod structures;
pub mod tls;
pub mod validate;
