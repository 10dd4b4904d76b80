//! Strata's authoritative server: validation, ordering, durable storage,
//! deltas, collision meshes, and the admin CLI's commands.

pub mod admin;
pub mod auth;
pub mod config;
pub mod datadir;
pub mod store;
pub mod tls;
