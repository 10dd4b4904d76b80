//! The `strata-bots` load tester, built on the `strata-client` library
//! (re-exported here under its old paths).

pub mod bots;

pub use strata_client::{client, cluster, pool, prediction, replica, tls};
pub use strata_client::{
    Acked, Arrival, ChunkPool, Client, ClientError, ClientOptions, ClusterClient, ClusterError,
    JoinRate, MeshMismatch, Notice, Prediction, PredictionStats, Replica, ReplicaStats, Request,
    Verdict, MAX_PENDING_PREDICTIONS,
};
