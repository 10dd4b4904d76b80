//! The store's one error type: every failure says which record and why.

use strata_terrain::chunk_codec::CodecError;
use thiserror::Error;

use crate::sequencer::regions::RegionId;

/// Why a store operation failed. A failed write changes nothing.
#[derive(Debug, Error)]
pub enum StoreError {
    #[error("sled: {0}")]
    Sled(#[from] sled::Error),
    /// PostgreSQL refused a statement or the connection failed.
    #[error("postgres: {}", pg_reason(.0))]
    Postgres(#[from] tokio_postgres::Error),
    /// A commit's connection was lost before its `COMMIT` was sent (the
    /// server ended a session left idle in its transaction, as when the
    /// node was paused): nothing of the batch was written.
    #[error("postgres: the commit's session ended before COMMIT; nothing was written ({reason})")]
    Uncommitted { reason: String },
    /// A PostgreSQL call ran past its limit (`[store.postgres]`).
    #[error("postgres: {what} took longer than {limit_ms} ms")]
    PgTimeout { what: &'static str, limit_ms: u64 },
    /// The PostgreSQL store cannot be used as configured or found.
    #[error("postgres: {reason}")]
    PgSetup { reason: String },
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
    /// Another process holds the sled world (`world_lock`).
    #[error(
        "{} is in use by another process (a running server, an admin tool or a restore): stop it first",
        .world.display()
    )]
    WorldInUse { world: std::path::PathBuf },
    /// A restore's swap was cut short and finishing it failed.
    #[error(
        "a restore was cut short: {} is missing and finishing the swap failed ({source}); move {} or the restored world beside it into its place",
        .world.display(), .replaced.display()
    )]
    RestoreCutShort {
        world: std::path::PathBuf,
        replaced: std::path::PathBuf,
        source: std::io::Error,
    },
    /// A read showed a commit that was not made durable in time (its
    /// fsync is slow, or failed).
    #[error("the store showed edits up to seq {seq} that were not durable within {waited_ms} ms")]
    NotDurable { seq: u64, waited_ms: u64 },
    /// A record on disk does not have the layout this version writes.
    #[error("corrupt {what} at key {key}")]
    Corrupt { what: String, key: String },
    /// A stored chunk's snapshot bytes do not decode.
    #[error("chunk {key} does not decode: {source}")]
    Codec {
        key: String,
        #[source]
        source: CodecError,
    },
    /// The chunk is stored as changes to its generated state, and no
    /// generator is attached to rebuild that state
    /// ([`crate::store::ChunkStore::attach_generator`]).
    #[error("chunk ({}, {}, {}) is stored as changes to generated terrain; reading it needs the world's generator", .pos.x, .pos.y, .pos.z)]
    NeedsGenerator { pos: strata_terrain::ChunkPos },
    /// The world on disk was made with different generation inputs.
    #[error("world metadata mismatch: stored {field} is {stored}, given {given}")]
    MetaMismatch {
        field: &'static str,
        stored: String,
        given: String,
    },
    /// The store was written by an unknown format version.
    #[error("store format version {found} is not supported (this build reads {supported})")]
    UnsupportedFormat { found: u32, supported: u32 },
    /// An admin tool of a newer build met a database that running servers
    /// of an older one use: it would have to migrate it under them.
    #[error(
        "the database's schema is at version {found} and this strata-admin needs {needed}, but a \
         running server uses it: migrations run only when servers start or while none runs; \
         use the strata-admin of the servers' build, or upgrade the servers first"
    )]
    SchemaBehind { found: u32, needed: u32 },
    /// A write needs the world metadata, which `init_meta` has not written.
    #[error("the store has no world metadata; call init_meta first")]
    NoMeta,
    /// Caller-supplied metadata is not acceptable.
    #[error("invalid world metadata: {reason}")]
    InvalidMeta { reason: String },
    /// A commit batch is inconsistent with itself or with the store.
    #[error("invalid commit batch: {reason}")]
    InvalidBatch { reason: String },
    /// This node does not hold `region` at the epoch the store has (a
    /// cluster node's commit; see `store::pg::fence`): the batch was
    /// refused and changed nothing.
    #[error(
        "region ({}, {}) is fenced: this node holds epoch {}, the store has epoch {} owned by {}",
        .region.x, .region.z, show_epoch(.held_epoch), show_epoch(.current_epoch),
        .owner.as_deref().unwrap_or("no node")
    )]
    Fenced {
        region: RegionId,
        held_epoch: Option<u64>,
        current_epoch: Option<u64>,
        owner: Option<String>,
    },
    /// A fenced batch numbered from a seq block no longer this node's (a
    /// node paused long past its block being superseded and compacted
    /// away, `seqs.rs` `compact`): the batch was refused and changed
    /// nothing.
    #[error(
        "seqs {first}..={last} are not in a seq block of this node (superseded and compacted); nothing was written"
    )]
    SeqsRetired { first: u64, last: u64 },
    /// The store holds another world than the one this server started on
    /// (a restore replaced it while the server's lock connection was
    /// lost): the batch was refused and changed nothing.
    #[error(
        "the database's world was replaced while this server served it (world {expected} is now \
         {found}, a restore): restart the server to serve the restored world"
    )]
    WorldReplaced { expected: String, found: String },
    /// Another process started under this node's `node_id` (a newer
    /// incarnation in the `nodes` table): this one claims nothing more and
    /// must stop.
    #[error(
        "another process started as node {node_id} (incarnation {current}, this one's is {mine}); \
         node ids must be unique, so this process stops"
    )]
    Superseded {
        node_id: String,
        mine: i64,
        current: i64,
    },
    /// A blob name or body breaks a limit.
    #[error("invalid blob: {reason}")]
    InvalidBlob { reason: String },
    /// A record could not be serialized (too large for its limit, usually).
    #[error("cannot encode {what}: {reason}")]
    Encode { what: &'static str, reason: String },
}

fn show_epoch(e: &Option<u64>) -> String {
    e.map_or_else(|| "none".into(), |e| e.to_string())
}

/// The server's message and SQLSTATE when it sent one, else the client's.
fn pg_reason(e: &tokio_postgres::Error) -> String {
    match e.as_db_error() {
        Some(db) => format!("{} ({})", db.message(), db.code().code()),
        None => e.to_string(),
    }
}

impl StoreError {
    /// An error in one chunk's records (they do not decode, replay or
    /// rebuild): a checkpoint leaves that chunk unfolded and goes on.
    pub fn is_chunk_local(&self) -> bool {
        matches!(
            self,
            StoreError::Corrupt { .. }
                | StoreError::Codec { .. }
                | StoreError::NeedsGenerator { .. }
        )
    }

    /// The store itself failed (a database or disk gone, a timeout), as
    /// readiness counts it (`health.rs`): not one chunk's records, not a
    /// lease lost or a newer process under this node's id, not a batch or
    /// value of ours the store refused. (A world replaced under the server
    /// counts: it must restart before it serves again.)
    pub fn is_store_fault(&self) -> bool {
        !(self.is_chunk_local()
            || matches!(
                self,
                StoreError::Fenced { .. }
                    | StoreError::SeqsRetired { .. }
                    | StoreError::Superseded { .. }
                    | StoreError::InvalidBatch { .. }
                    | StoreError::InvalidBlob { .. }
                    | StoreError::Encode { .. }
            ))
    }

    /// A record that does not read (it does not decode, or has not the
    /// layout this version writes): the store answered, the data is bad.
    pub fn is_bad_record(&self) -> bool {
        matches!(self, StoreError::Codec { .. } | StoreError::Corrupt { .. })
    }

    /// PostgreSQL unreachable rather than refusing: the connection failed,
    /// closed or timed out, or the server is shutting down, starting up,
    /// out of connections or (after a failover) read-only. What a server
    /// alone on its database waits out ([`crate::store::pg`]'s patience).
    pub fn is_pg_outage(&self) -> bool {
        use tokio_postgres::error::SqlState;
        let unreachable = [
            SqlState::ADMIN_SHUTDOWN,
            SqlState::CRASH_SHUTDOWN,
            SqlState::CANNOT_CONNECT_NOW,
            SqlState::TOO_MANY_CONNECTIONS,
            SqlState::READ_ONLY_SQL_TRANSACTION,
        ];
        match self {
            StoreError::PgTimeout { .. } => true,
            StoreError::Postgres(e) => {
                let io = std::error::Error::source(e).is_some_and(|s| s.is::<std::io::Error>());
                e.is_closed()
                    || io
                    || e.code()
                        .is_some_and(|c| unreachable.contains(c) || c.code().starts_with("08"))
            }
            _ => false,
        }
    }

    /// An error from PostgreSQL itself (the connection may be unusable).
    pub fn is_postgres(&self) -> bool {
        matches!(
            self,
            StoreError::Postgres(_) | StoreError::Uncommitted { .. }
        )
    }

    pub(crate) fn corrupt(what: impl Into<String>, key: impl Into<String>) -> Self {
        StoreError::Corrupt {
            what: what.into(),
            key: key.into(),
        }
    }

    pub(crate) fn batch(reason: impl Into<String>) -> Self {
        StoreError::InvalidBatch {
            reason: reason.into(),
        }
    }
}
