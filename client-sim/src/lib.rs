//! Headless Strata client: a real QUIC client with a replica of the chunks
//! it sees, which re-meshes changed chunks and compares mesh hashes with the
//! server's. The `strata-bots` load tester builds on it.

pub mod bots;
pub mod client;
pub mod pool;
pub mod prediction;
pub mod replica;
pub mod tls;

pub use client::{Acked, Arrival, Client, ClientError, ClientOptions, Verdict};
pub use pool::ChunkPool;
pub use prediction::{Prediction, PredictionStats, MAX_PENDING_PREDICTIONS};
pub use replica::{MeshMismatch, Replica, ReplicaStats, Request};
