//! Strata's client library. It knows only the protocol and the terrain
//! core, never the server.
//!
//! - [`Session`]: for a game loop. Connect, report positions, send typed
//!   edits, `poll` events, read chunks and mesh them; the connection runs
//!   on the session's own thread.
//! - [`Client`]: the async client underneath (tokio), with its
//!   [`Replica`]: snapshots and deltas applied with version and hash
//!   checks, changed chunks re-meshed and compared with the server's mesh
//!   hashes, and optional [`prediction`].
//! - [`ClusterClient`]: one player on a cluster of nodes: a connection to
//!   each node writing a region in view, each edit sent to its writer.

pub mod bounds;
mod changes;
pub mod client;
pub mod cluster;
pub mod coords;
pub mod edits;
pub mod link_delay;
pub mod mesh;
pub mod mesh_checks;
pub mod notice;
pub mod pool;
pub mod prediction;
pub mod replay;
pub mod replica;
pub mod session;
pub use strata_protocol::client_tls as tls;

pub use bounds::{ChunkLimits, Violation};
pub use client::{Acked, Arrival, Client, ClientError, ClientOptions, SentEdit, Verdict};
pub use cluster::{
    ClusterClient, ClusterError, ClusterView, JoinRate, RegionOwners, MAX_CLUSTER_NODES,
};
pub use mesh::ChunkMesh;
pub use notice::Notice;
pub use pool::ChunkPool;
pub use prediction::{Prediction, PredictionStats, MAX_PENDING_PREDICTIONS};
pub use replica::{MeshMismatch, Replica, ReplicaStats, Request};
pub use session::{ChunkData, Event, Session, SessionError, SessionOptions};
pub use {glam, strata_protocol as protocol, strata_terrain as terrain};
