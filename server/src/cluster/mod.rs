//! Running as one node of a cluster that shares a PostgreSQL store
//! (`[cluster]`). A node leases the regions it writes (see
//! `store::pg::lease`); every commit is fenced by the epochs it holds.

mod config;
pub mod ticket;

pub use config::{
    ClusterConfig, DEFAULT_LEASE_MS, DEFAULT_POSITION_READS, DEFAULT_POSITION_READ_MS,
    DEFAULT_RENEW_MS, DEFAULT_SEQ_BLOCK, MAX_ADVERTISE_LEN, MAX_LEASE_MS, MAX_NODE_ID_LEN,
    MAX_POSITION_READS, MAX_POSITION_READ_MS, MAX_SEQ_BLOCK, MIN_LEASE_MS, MIN_RENEW_MS,
    MIN_SEQ_BLOCK,
};
