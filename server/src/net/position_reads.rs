//! On a cluster node, the reads of players' stored positions that logins
//! make before their `Join` (`[cluster] position_reads` at once, each
//! login waiting at most `[cluster] position_read_ms` for its turn and its
//! read).
//!
//! Each read holds one of the store's pooled connections, which the
//! node's commits, chunk loads and claims need too: however many players
//! log in at once (a login storm after a restart, one attacker with many
//! accounts), at most `position_reads` connections read positions. A read
//! keeps its permit until the store call itself returns, even after its
//! login gave up on it, so reads stuck behind a lock never add up past
//! the bound.
//!
//! A login whose read did not come in time, or failed, is refused
//! (retryable, `TooManyConnections`), never let in as a player with no
//! stored position: the stored position bounds how old a replayed
//! `Arrive` ticket may be and places the resume, so a player able to make
//! the read fail would otherwise rewind himself with an old ticket.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::Semaphore;

use crate::store::{ChunkStore, StoredPosition};

/// Why a login's position read gave no answer (the message is the
/// client's reason).
#[derive(Debug, thiserror::Error)]
pub enum ReadRefused {
    /// Every permit stayed taken for the whole wait.
    #[error("the server is busy with other logins; try again shortly")]
    Busy,
    /// The read began but did not end within the wait.
    #[error("the server could not read where this player was in time; try again shortly")]
    Slow,
    /// The store answered with an error (logged, not sent).
    #[error("the server could not read where this player was; try again shortly")]
    Failed(String),
}

impl ReadRefused {
    /// Its `reason` in `strata_connections_refused_total`.
    pub fn reason(&self) -> &'static str {
        match self {
            ReadRefused::Busy => "position_reads",
            ReadRefused::Slow => "position_read_slow",
            ReadRefused::Failed(_) => "position_read_failed",
        }
    }
}

/// The node's bound on stored-position reads (held by the session context).
#[derive(Debug)]
pub struct PositionReads {
    permits: Arc<Semaphore>,
    wait: Duration,
}

impl Default for PositionReads {
    /// The `[cluster]` defaults.
    fn default() -> Self {
        Self::new(
            crate::cluster::DEFAULT_POSITION_READS,
            Duration::from_millis(crate::cluster::DEFAULT_POSITION_READ_MS),
        )
    }
}

impl PositionReads {
    /// At most `reads` at once (at least one); a login waits at most `wait`
    /// for its turn and its read together.
    pub fn new(reads: usize, wait: Duration) -> Self {
        Self {
            permits: Arc::new(Semaphore::new(reads.clamp(1, Semaphore::MAX_PERMITS))),
            wait,
        }
    }

    /// How long a login waits for its turn and its read.
    pub fn wait(&self) -> Duration {
        self.wait
    }

    /// Where `store` last has `player`, read on a blocking thread under a
    /// permit, within [`Self::wait`].
    pub async fn read(
        &self,
        store: &Arc<dyn ChunkStore>,
        player: &str,
        health: &Arc<crate::health::Health>,
    ) -> Result<Option<StoredPosition>, ReadRefused> {
        let deadline = tokio::time::Instant::now() + self.wait;
        let permit =
            match tokio::time::timeout_at(deadline, self.permits.clone().acquire_owned()).await {
                Ok(Ok(permit)) => permit,
                // Never closed; a closed bound reads as a full one.
                Ok(Err(_)) | Err(_) => return Err(ReadRefused::Busy),
            };
        let (store, name, health) = (store.clone(), player.to_string(), health.clone());
        let read = tokio::task::spawn_blocking(move || {
            // Held until the store call returns, whoever still waits.
            let _permit = permit;
            let read = store.player_position(&name);
            // Reported however long it took: a login gone by then still
            // tells of the store.
            health.report(crate::health::StoreWork::PositionReads, &read);
            read
        });
        match tokio::time::timeout_at(deadline, read).await {
            Ok(Ok(Ok(stored))) => Ok(stored),
            Ok(Ok(Err(e))) => Err(ReadRefused::Failed(e.to_string())),
            Ok(Err(joined)) => Err(ReadRefused::Failed(joined.to_string())),
            Err(_) => Err(ReadRefused::Slow),
        }
    }
}
