//! Strata's authoritative server: validation, ordering, durable storage,
//! deltas, collision meshes, and the admin CLI's commands.

pub mod admin;
pub mod store;
