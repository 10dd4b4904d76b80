//! [`ChunkStore`] on PostgreSQL: the store a cluster of nodes shares.
//!
//! The layout is in `server/migrations/` (applied at open, see
//! `migrate`). It mirrors the sled store: a world row, chunk records,
//! deltas past them, the edit log by seq, blobs and player positions.
//! Every chunk and delta row carries its region (`[sequencer]
//! region_chunks`, fixed in the `layout` row when the database is first
//! opened), the unit a cluster will lease to one node.
//!
//! Durability: a commit is one transaction (`commit.rs`) whose `COMMIT`
//! returns only after PostgreSQL flushed its WAL: every connection runs
//! with `synchronous_commit = on`, and the store refuses a server that
//! runs with `fsync = off`.
//!
//! Clustered (`open_node`, `[cluster]`), a node leases the regions it
//! writes (`lease.rs`) and every commit checks, inside its transaction,
//! the epoch it holds for each region of the batch (`fence.rs`). Opened
//! with `open`, the store is not fenced: one node alone on its database.
//!
//! Why `tokio-postgres` and not the synchronous `postgres` crate: that
//! crate runs a runtime per client and panics when called from inside a
//! tokio runtime, and the server calls its store from tokio tasks
//! (`app::start`, admin sessions). Here one small runtime of the store's
//! own drives the connections, and calls wait on their futures from any
//! thread (`wait.rs`).

mod commit;
mod config;
mod fence;
mod fold;
mod import;
mod lease;
mod migrate;
mod pages;
mod patience;
mod pool;
mod read;
mod scan_check;
mod seqs;
mod wait;

use std::ops::RangeInclusive;

use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::ChunkPos;

use super::check::CheckReport;
use super::error::StoreError;
use super::rules::{check_blob, check_blob_name, check_new_meta, compare_meta};
use super::types::{
    CheckpointStats, CommitBatch, CommitStats, LogEntry, RawChunk, RegionAccess, StoredChunk,
    StoredPosition, WorldMeta,
};
use super::{ChunkStore, StoreIter};
use crate::sequencer::regions::RegionId;

pub use config::{
    PgConfig, DEFAULT_PG_CONNECT_TIMEOUT_MS, DEFAULT_PG_MAX_CONNECTIONS, DEFAULT_PG_POOL_WAIT_MS,
    DEFAULT_PG_STATEMENT_TIMEOUT_MS, MAX_PG_MAX_CONNECTIONS, MAX_PG_TIMEOUT_MS, SERVER_APPLICATION,
};
pub use import::{PgImport, SERVING_LOCK};
pub use lease::{NodeLeases, RegionLease, MAX_ADOPT_PER_RENEWAL, MAX_CACHED_HOLDERS};
pub use migrate::{MIGRATIONS, MIGRATIONS_TABLE};
use pool::{Conn, Pool};

/// How long one [`ChunkStore::prune_log`] call goes on to further ranges
/// of the log (a cluster's seq blocks): the next call goes on from there.
const PRUNE_CALL_LIMIT: std::time::Duration = std::time::Duration::from_millis(250);

/// Rows one page of a scan fetches (chunk bodies are a few KiB each).
const PAGE_ROWS: i64 = 256;

/// The oldest PostgreSQL served (`server_version_num`): 15, the one
/// tested (13 is the least `commit.rs` needs, for `pg_current_xact_id`
/// and `pg_xact_status`).
pub const MIN_SERVER_VERSION_NUM: u32 = 150_000;

/// The PostgreSQL-backed store. Cheap to share by reference across threads.
#[derive(Debug)]
pub struct PgStore {
    /// Renews `leases` (first, so it stops before the pool goes).
    renewer: Option<lease::Renewer>,
    pool: std::sync::Arc<Pool>,
    /// This node's leases when it is one of a cluster: commits are fenced.
    leases: Option<std::sync::Arc<NodeLeases>>,
    /// Region side in chunks, as the `layout` row records it.
    region_chunks: u32,
    /// The world's generator, once attached: new chunks are then stored
    /// as a "generated" record and deltas (`CommitBatch::generated`).
    generator: std::sync::OnceLock<std::sync::Arc<dyn strata_terrain::world::ChunkGenerator>>,
    /// Where big batches' chunks are encoded.
    encode: crate::store::EncodePool,
    /// The connection holding [`import::SERVING_LOCK`] shared while a
    /// server uses this store ([`ChunkStore::serve`]).
    serving: std::sync::Mutex<Option<Box<Conn>>>,
    /// The commits' own connection ([`Pool::run_own`]), opened at the
    /// first commit.
    commit_conn: std::sync::Mutex<Option<Box<Conn>>>,
    /// The log's range ([`ChunkStore::prune_log`]) the next prune starts at.
    prune_cursor: std::sync::Mutex<usize>,
    /// The world's id (`world.generation`) as [`ChunkStore::init_meta`]
    /// found it; commits refuse a world replaced since.
    world_id: std::sync::OnceLock<String>,
}

/// How long a round trip on the serving lock's connection may take before
/// a retry or an unlock gives up on it.
const LOCK_CHECK_LIMIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Whether this connection's session holds an advisory lock.
async fn holds_a_lock(c: &mut Conn) -> Result<bool, StoreError> {
    let row = c
        .query_opt(
            "SELECT EXISTS (SELECT 1 FROM pg_locks WHERE locktype = 'advisory' \
             AND pid = pg_backend_pid() AND granted)",
            &[],
        )
        .await?;
    Ok(row.is_some_and(|r| r.get::<_, bool>(0)))
}

impl Drop for PgStore {
    fn drop(&mut self) {
        // As `close`: no renewal may follow the unlock.
        if let Some(r) = &self.renewer {
            r.stop();
        }
        self.let_go_of_serving();
    }
}

impl PgStore {
    /// Connects, applies the migrations this build has and the database
    /// lacks, and checks that commits will be durable. A new database
    /// records `region_chunks`; an existing one must have been made with
    /// the same.
    pub fn open(cfg: &PgConfig, region_chunks: u32) -> Result<Self, StoreError> {
        Self::open_on(Pool::open(cfg)?, region_chunks, migrate::Migrator::Server)
    }

    /// [`Self::open`] for an admin tool: it migrates the database only
    /// while no server uses it ([`StoreError::SchemaBehind`] otherwise).
    pub fn open_admin(cfg: &PgConfig, region_chunks: u32) -> Result<Self, StoreError> {
        Self::open_on(
            Pool::open(&cfg.for_admin())?,
            region_chunks,
            migrate::Migrator::Admin,
        )
    }

    /// Takes [`import::SERVING_LOCK`] shared on a connection of its own,
    /// kept while the store is open ([`ChunkStore::serve`]), and with it
    /// [`import::SOLO_LOCK`]: shared by a cluster's nodes, whose commits are
    /// fenced; alone by a server without `[cluster]`, whose commits are not
    /// (beside other servers it would write into their regions and seq
    /// blocks).
    fn take_serving_lock(&self) -> Result<(), StoreError> {
        let solo = self.leases.is_none();
        let (conn, (serving, alone)) =
            self.pool
                .dedicated("marking the store served", async |c: &mut Conn| {
                    let sql = match solo {
                        false => {
                            "SELECT pg_try_advisory_lock_shared($1), \
                             pg_try_advisory_lock_shared($2)"
                        }
                        true => "SELECT pg_try_advisory_lock_shared($1), pg_try_advisory_lock($2)",
                    };
                    let rows = c
                        .query(sql, &[&import::SERVING_LOCK, &import::SOLO_LOCK])
                        .await?;
                    Ok(rows.first().map_or((false, false), |r| {
                        (r.get::<_, bool>(0), r.get::<_, bool>(1))
                    }))
                })?;
        // Dropped, the connection lets go of whichever it took.
        if !serving {
            return Err(import::restore_running());
        }
        if !alone {
            return Err(StoreError::PgSetup {
                reason: match solo {
                    true => format!(
                        "other servers use this database (a cluster's nodes, or a server \
                         without [cluster]; one that died without closing its connection holds \
                         on for about {} s more): a server without [cluster] must be alone on it",
                        pool::KEEPALIVE_S
                    ),
                    false => "a server without [cluster] uses this database: a cluster's nodes \
                              cannot share it (stop that server, then give it [cluster] too)"
                        .into(),
                },
            });
        }
        self.keep_lock_connection(conn);
        Ok(())
    }

    /// Takes [`import::SERVING_LOCK`] alone on a connection of its own,
    /// kept while the store is open ([`ChunkStore::hold_alone`]).
    fn take_serving_lock_alone(&self) -> Result<(), StoreError> {
        let (conn, held) = self
            .pool
            .dedicated("keeping servers off", async |c: &mut Conn| {
                let row = c
                    .query_opt("SELECT pg_try_advisory_lock($1)", &[&import::SERVING_LOCK])
                    .await?;
                Ok(row.is_some_and(|r| r.get::<_, bool>(0)))
            })?;
        if !held {
            return Err(StoreError::PgSetup {
                reason:
                    "a running server (or a restore) holds this database: stop every node first"
                        .into(),
            });
        }
        self.keep_lock_connection(conn);
        Ok(())
    }

    fn keep_lock_connection(&self, conn: Conn) {
        // Held while this connection lives: as long as the store.
        *self.serving.lock().unwrap_or_else(|p| p.into_inner()) = Some(Box::new(conn));
    }

    /// Unlocks what the serving lock's connection holds, then closes it.
    /// Only closed, the connection's backend lets go when it has exited,
    /// after this returns: an admin tool run at once could still find the
    /// store served.
    fn let_go_of_serving(&self) {
        let conn = self
            .serving
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .take();
        let Some(mut conn) = conn else {
            return;
        };
        if conn.is_closed() {
            return;
        }
        let what = "releasing the serving lock";
        let unlocked = self.pool.on_dedicated_within(
            &mut conn,
            what,
            LOCK_CHECK_LIMIT,
            async |c: &mut Conn| c.batch("SELECT pg_advisory_unlock_all()").await,
        );
        if let Err(e) = unlocked {
            tracing::warn!(error = %e, "the serving lock goes with its connection instead");
        }
    }

    /// Before a commit is tried again: a round trip on the serving lock's
    /// connection, which looks open until used when it was lost to a
    /// failover or a partition. Lost, or its session no longer holding
    /// the lock, it is dropped, and whether it was: the lock must be taken
    /// again (on a new primary, say) before anything is committed there.
    fn recheck_serving(&self) -> bool {
        let mut serving = self.serving.lock().unwrap_or_else(|p| p.into_inner());
        let Some(conn) = serving.as_mut() else {
            return false;
        };
        let what = "checking the serving lock";
        let held = self
            .pool
            .on_dedicated_within(conn, what, LOCK_CHECK_LIMIT, holds_a_lock);
        let lost = !matches!(held, Ok(true));
        if lost {
            *serving = None;
        }
        lost
    }

    /// Whether the connection holding the serving lock ended.
    fn lock_connection_lost(&self) -> bool {
        self.serving
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_ref()
            .is_some_and(|c| c.is_closed())
    }

    /// Before a commit: a served store whose lock connection ended (a
    /// PostgreSQL restart, a terminated backend) takes the lock again, or
    /// fails the commit (a restore got in meanwhile).
    fn keep_serving(&self) -> Result<(), StoreError> {
        let lost = self.lock_connection_lost();
        if lost {
            tracing::warn!("the connection holding the serving lock ended; taking it again");
            self.take_serving_lock()?;
        }
        Ok(())
    }

    /// [`Self::open`] on a pool already open.
    fn open_on(pool: Pool, region_chunks: u32, by: migrate::Migrator) -> Result<Self, StoreError> {
        let version: String = pool.run("reading the server's version", async |c: &mut Conn| {
            Ok(c.query("SHOW server_version_num", &[]).await?[0].get(0))
        })?;
        if version.parse::<u32>().unwrap_or(0) < MIN_SERVER_VERSION_NUM {
            return Err(StoreError::PgSetup {
                reason: format!(
                    "the server is PostgreSQL {version} (server_version_num): 15 or later is needed"
                ),
            });
        }
        migrate::apply(&pool, by)?;
        let fsync: String = pool.run("reading fsync", async |c: &mut Conn| {
            Ok(c.query("SHOW fsync", &[]).await?[0].get(0))
        })?;
        if fsync != "on" {
            return Err(StoreError::PgSetup {
                reason: format!(
                    "the server runs with fsync = {fsync}: a commit would not survive a power cut"
                ),
            });
        }
        let side = i32::try_from(region_chunks.max(1)).map_err(|_| StoreError::PgSetup {
            reason: format!("region_chunks {region_chunks} does not fit the layout"),
        })?;
        let stored: i32 = pool.run_tx("recording the layout", "BEGIN", async |c: &mut Conn| {
            c.execute(
                "INSERT INTO layout (id, region_chunks) VALUES (1, $1) ON CONFLICT (id) DO NOTHING",
                &[&side],
            )
            .await?;
            Ok(
                c.query("SELECT region_chunks FROM layout WHERE id = 1", &[])
                    .await?[0]
                    .get(0),
            )
        })?;
        if stored != side {
            return Err(StoreError::MetaMismatch {
                field: "region_chunks",
                stored: stored.to_string(),
                given: side.to_string(),
            });
        }
        Ok(Self {
            renewer: None,
            pool: std::sync::Arc::new(pool),
            leases: None,
            region_chunks: region_chunks.max(1),
            generator: std::sync::OnceLock::new(),
            encode: Default::default(),
            serving: std::sync::Mutex::new(None),
            commit_conn: std::sync::Mutex::new(None),
            prune_cursor: std::sync::Mutex::new(0),
            world_id: std::sync::OnceLock::new(),
        })
    }

    /// The attached generator, which "generated" records need.
    pub(super) fn generator(&self) -> Option<&dyn strata_terrain::world::ChunkGenerator> {
        self.generator.get().map(|g| g.as_ref())
    }

    /// The region a chunk row belongs to.
    fn region(&self, pos: ChunkPos) -> RegionId {
        RegionId::of(pos, self.region_chunks)
    }

    /// Number of named blobs.
    pub fn blob_count(&self) -> Result<u64, StoreError> {
        let n: i64 = self.pool.run("counting blobs", async |c: &mut Conn| {
            Ok(c.query("SELECT count(*) FROM blobs", &[]).await?[0].get(0))
        })?;
        from_sql(n, "blob count", "blobs")
    }
}

/// A `players` row read as `name, x, y, z, known_ms`.
fn position_row(r: &tokio_postgres::Row) -> Result<(String, StoredPosition), StoreError> {
    let c = |i: usize| Fixed(r.get::<_, i32>(i));
    let feet = FixedVec3::new(c(1), c(2), c(3));
    let known_ms = from_sql(r.get(4), "known_ms", "players")?;
    Ok((r.get::<_, String>(0), StoredPosition { feet, known_ms }))
}

/// A seq, version or count for a bigint column.
fn to_sql(v: u64, what: &str) -> Result<i64, StoreError> {
    i64::try_from(v).map_err(|_| StoreError::batch(format!("{what} {v} is past 2^63")))
}

/// A bigint column read back as the unsigned value it holds.
fn from_sql(v: i64, what: &str, key: impl Into<String>) -> Result<u64, StoreError> {
    u64::try_from(v).map_err(|_| StoreError::corrupt(format!("negative {what} {v}"), key))
}

fn meta_from_row(row: &tokio_postgres::Row) -> Result<WorldMeta, StoreError> {
    let format: i32 = row.get(0);
    let generator: i64 = row.get(2);
    let corrupt = |what: &str| StoreError::corrupt(what.to_string(), "world");
    Ok(WorldMeta {
        format_version: u32::try_from(format).map_err(|_| corrupt("format_version"))?,
        // The seed's 64 bits, stored two's complement.
        seed: row.get::<_, i64>(1) as u64,
        generator_version: u32::try_from(generator).map_err(|_| corrupt("generator_version"))?,
        generator_params: row.get(3),
        last_seq: from_sql(row.get(4), "last_seq", "world")?,
    })
}

/// The store's last seq, as SQL over the world row: the row's, or the
/// log's last where a cluster's fenced commits (which leave the row
/// alone) went beyond it. `seq` is the log's key: its max is one probe.
macro_rules! last_seq_sql {
    () => {
        "GREATEST(last_seq, (SELECT COALESCE(max(seq), 0) FROM edit_log))"
    };
}
pub(super) use last_seq_sql;

const SELECT_META: &str = concat!(
    "SELECT format_version, seed, generator_version, generator_params, ",
    last_seq_sql!(),
    " FROM world WHERE id = 1"
);

impl PgStore {
    /// Who writes each of `regions`; what is looked up is cached when
    /// `cache` ([`ChunkStore::region_holders_read`] does not).
    fn holders(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
        cache: bool,
    ) -> Result<Vec<(RegionId, crate::store::RegionHolder)>, StoreError> {
        match &self.leases {
            Some(leases) => lease::holders(&self.pool, leases, regions, cache),
            None => Ok(regions
                .iter()
                .map(|r| (*r, crate::store::RegionHolder::Here))
                .collect()),
        }
    }
}

impl ChunkStore for PgStore {
    fn load_meta(&self) -> Result<Option<WorldMeta>, StoreError> {
        let row = self.pool.run("reading the world", async |c: &mut Conn| {
            c.query_opt(SELECT_META, &[]).await
        })?;
        let Some(row) = row else {
            return Ok(None);
        };
        let meta = meta_from_row(&row)?;
        if meta.format_version != super::STORE_FORMAT_VERSION {
            return Err(StoreError::UnsupportedFormat {
                found: meta.format_version,
                supported: super::STORE_FORMAT_VERSION,
            });
        }
        Ok(Some(meta))
    }

    fn init_meta(&self, meta: &WorldMeta) -> Result<WorldMeta, StoreError> {
        check_new_meta(meta)?;
        let format = meta.format_version as i32;
        let seed = meta.seed as i64;
        let generator = i64::from(meta.generator_version);
        // Inserted only if absent, in one statement: two nodes starting at
        // once agree on one world row. Not over rows without a world (a
        // restore by an older build, cut short), which would then pass for
        // a new world.
        self.pool.run("writing the world", async |c: &mut Conn| {
            c.execute(
                "INSERT INTO world (id, format_version, seed, generator_version, \
                     generator_params, last_seq) SELECT 1, $1::int4, $2::int8, $3::int8, $4::text, 0 \
                     WHERE NOT EXISTS (SELECT 1 FROM chunks) \
                     AND NOT EXISTS (SELECT 1 FROM chunk_deltas) \
                     AND NOT EXISTS (SELECT 1 FROM edit_log) \
                     ON CONFLICT (id) DO NOTHING",
                &[&format, &seed, &generator, &meta.generator_params],
            )
            .await
        })?;
        let stored = self.load_meta()?.ok_or_else(|| StoreError::InvalidMeta {
            reason: "the store has no world row but holds chunks, deltas or log records \
                     (an interrupted restore by an older build?); restore it again with --force"
                .into(),
        })?;
        compare_meta(&stored, meta)?;
        let id = self
            .pool
            .run("reading the world's id", async |c: &mut Conn| {
                c.query_opt("SELECT generation FROM world WHERE id = 1", &[])
                    .await
            })?;
        if let Some(id) = id {
            let _ = self.world_id.set(id.get(0));
        }
        Ok(stored)
    }

    fn world_id(&self) -> Option<String> {
        self.world_id.get().cloned()
    }

    fn last_seq(&self) -> Result<u64, StoreError> {
        let row = self.pool.run("reading last_seq", async |c: &mut Conn| {
            c.query_opt(
                concat!("SELECT ", last_seq_sql!(), " FROM world WHERE id = 1"),
                &[],
            )
            .await
        })?;
        row.map_or(Ok(0), |r| from_sql(r.get(0), "last_seq", "world"))
    }

    fn load_chunk(&self, pos: ChunkPos) -> Result<Option<StoredChunk>, StoreError> {
        Ok(self
            .latest(pos)?
            .map(|(version, chunk)| StoredChunk { chunk, version }))
    }

    fn load_chunks(&self, positions: &[ChunkPos]) -> Result<Vec<Option<StoredChunk>>, StoreError> {
        Ok(self
            .latest_many(positions)?
            .into_iter()
            .map(|s| s.map(|(version, chunk)| StoredChunk { chunk, version }))
            .collect())
    }

    fn commit_batch(&self, batch: &CommitBatch) -> Result<CommitStats, StoreError> {
        let window = match self.leases {
            None => self.pool.commit_retry(),
            Some(_) => std::time::Duration::ZERO,
        };
        let mut patience = patience::Patience::new(window);
        for tries in 0.. {
            let relock = tries > 0 && self.recheck_serving();
            let serving = match relock {
                true => self.take_serving_lock(),
                false => self.keep_serving(),
            };
            let tried = serving
                .map_err(|e| match e {
                    // Before the batch's transaction: nothing written.
                    e if e.is_pg_outage() => StoreError::Uncommitted {
                        reason: format!("taking the serving lock again: {e}"),
                    },
                    e => e,
                })
                .and_then(|()| self.commit(batch, &mut patience));
            match tried {
                Err(e @ StoreError::Uncommitted { .. })
                    if patience.again("a commit wrote nothing", &e) => {}
                done => return done,
            }
        }
        unreachable!("the tries run until one returns")
    }

    fn log_entry(&self, seq: u64) -> Result<Option<LogEntry>, StoreError> {
        let Ok(key) = i64::try_from(seq) else {
            return Ok(None);
        };
        let row = self.pool.run("reading a log entry", async |c: &mut Conn| {
            c.query_opt("SELECT entry FROM edit_log WHERE seq = $1", &[&key])
                .await
        })?;
        row.map(|r| super::record::decode_log_entry(seq, r.get(0)))
            .transpose()
    }

    fn edit_log(&self, seqs: RangeInclusive<u64>) -> StoreIter<'_, LogEntry> {
        self.log_pages(seqs)
    }

    fn log_base(&self) -> Result<u64, StoreError> {
        let row = self.pool.run("reading log_base", async |c: &mut Conn| {
            c.query_opt("SELECT log_base FROM world WHERE id = 1", &[])
                .await
        })?;
        row.map_or(Ok(0), |r| from_sql(r.get(0), "log_base", "world"))
    }

    /// Each range of the log from its own start: the seqs before the first
    /// seq block (numbered by a store alone, from `world.log_base`), then
    /// each block (a cluster node's, from its `pruned_to`). A cluster's
    /// nodes number from blocks far apart: a run from the log's start
    /// alone would stop at the first node's newest entry and never reach
    /// another's.
    fn prune_log(&self, before_ms: u64, max: usize) -> Result<u64, StoreError> {
        let ranges = self
            .pool
            .run("reading the log's ranges", async |c: &mut Conn| {
                let base: i64 = c
                    .query_opt("SELECT log_base FROM world WHERE id = 1", &[])
                    .await?
                    .map_or(0, |r| r.get(0));
                let blocks = c
                    .query(
                        "SELECT first_seq, pruned_to FROM seq_blocks ORDER BY first_seq",
                        &[],
                    )
                    .await?;
                // (the block, or none for the seqs before any; pruned up to;
                // the next range's first seq).
                let mut ranges: Vec<(Option<i64>, i64, i64)> = Vec::new();
                let mut block = None;
                let mut after = base;
                for r in &blocks {
                    let (first, pruned): (i64, i64) = (r.get(0), r.get(1));
                    ranges.push((block, after, first));
                    (block, after) = (Some(first), pruned.max(first - 1));
                }
                ranges.push((block, after, i64::MAX));
                Ok(ranges)
            })?;
        // From where the last call stopped: with many blocks (a node's
        // every start reserves one), each gets its turn.
        let mut cursor = self.prune_cursor.lock().unwrap_or_else(|p| p.into_inner());
        let started = std::time::Instant::now();
        let mut removed = 0u64;
        for i in 0..ranges.len() {
            let at = (*cursor + i) % ranges.len();
            let (block, after, end) = ranges[at];
            let left = (max as u64).saturating_sub(removed);
            if left == 0 || started.elapsed() >= PRUNE_CALL_LIMIT {
                *cursor = at;
                return Ok(removed);
            }
            let limit = i64::try_from(left).unwrap_or(i64::MAX);
            // Read outside a transaction: most ranges have nothing to go.
            let rows = self
                .pool
                .run("reading the edit log's oldest", async |c: &mut Conn| {
                    c.query(
                        "SELECT seq, entry FROM edit_log WHERE seq > $1 AND seq < $2 \
                     ORDER BY seq LIMIT $3",
                        &[&after, &end, &limit],
                    )
                    .await
                })?;
            let mut cut = None;
            for r in &rows {
                let seq: i64 = r.get(0);
                let entry =
                    super::record::decode_log_entry(from_sql(seq, "seq", "edit_log")?, r.get(1))?;
                if entry.time_ms >= before_ms {
                    break;
                }
                cut = Some(seq);
            }
            let Some(cut) = cut else {
                continue;
            };
            removed +=
                self.pool
                    .run_tx("pruning the edit log", "BEGIN", async |c: &mut Conn| {
                        let n = c
                            .execute(
                                "DELETE FROM edit_log WHERE seq > $1 AND seq <= $2",
                                &[&after, &cut],
                            )
                            .await?;
                        if let Some(first) = block {
                            c.execute(
                                "UPDATE seq_blocks SET pruned_to = GREATEST(pruned_to, $2) \
                             WHERE first_seq = $1",
                                &[&first, &cut],
                            )
                            .await?;
                        }
                        // `last_seq` too: the log's newest entry may be among
                        // those removed, and the store's last seq reads it there.
                        let base = if block.is_none() { cut } else { 0 };
                        c.execute(
                            "UPDATE world SET log_base = GREATEST(log_base, $1), \
                         last_seq = GREATEST(last_seq, $2) WHERE id = 1",
                            &[&base, &cut],
                        )
                        .await?;
                        Ok(n)
                    })?;
        }
        *cursor = 0;
        // The pass's last call (nothing left to prune): old empty seq
        // blocks are merged, a failure only logged (the next pass tries).
        if removed == 0 {
            drop(cursor);
            if let Err(e) = seqs::compact(&self.pool) {
                crate::log_every::store_error("seqs", "compacting seq blocks failed", &e);
            }
        }
        Ok(removed)
    }

    fn log_segments(
        &self,
        also: crate::store::SegmentsAlso,
    ) -> Result<Vec<crate::store::LogSegment>, StoreError> {
        let whole = || {
            Ok(vec![crate::store::LogSegment {
                first: 1,
                last: i64::MAX as u64,
                head: self.last_seq()?,
            }])
        };
        // A server alone on the store numbers on from the log's last seq,
        // whatever blocks a cluster left.
        if self.leases.is_none() {
            return whole();
        }
        // Each node's newest block (the nodes found by a skip over the
        // (node, first_seq) index, then one probe of it each; not the
        // compacted blocks' empty name, `seqs::compact`), the others
        // asked for (`$others`: a query of first seqs), and the highest seq
        // logged in each (pruned ones included); no scan of every block.
        macro_rules! segments {
            ($others:literal) => {
                concat!(
                    "WITH RECURSIVE nodes AS ( \
                         (SELECT node FROM seq_blocks WHERE node > '' ORDER BY node LIMIT 1) \
                         UNION ALL \
                         SELECT (SELECT s.node FROM seq_blocks s WHERE s.node > n.node \
                                 ORDER BY s.node LIMIT 1) \
                         FROM nodes n WHERE n.node IS NOT NULL), \
                     picked AS ( \
                         SELECT (SELECT max(s.first_seq) FROM seq_blocks s WHERE s.node = n.node) \
                             AS first_seq \
                         FROM nodes n WHERE n.node IS NOT NULL \
                         UNION ",
                    $others,
                    ") \
                     SELECT b.first_seq, b.last_seq, GREATEST(b.first_seq - 1, b.pruned_to, \
                         (SELECT max(e.seq) FROM edit_log e \
                          WHERE e.seq >= b.first_seq AND e.seq <= b.last_seq)) \
                     FROM seq_blocks b \
                     WHERE b.first_seq = ANY(ARRAY(SELECT first_seq FROM picked)) \
                     ORDER BY b.first_seq"
                )
            };
        }
        let (query, bound) = match also {
            // The blocks superseded lately: each one reserved lately
            // follows its node's previous block.
            crate::store::SegmentsAlso::Recent => (
                segments!(
                    "SELECT (SELECT max(p.first_seq) FROM seq_blocks p \
                             WHERE p.node = r.node AND p.first_seq < r.first_seq) \
                     FROM seq_blocks r \
                     WHERE r.reserved_at > now() - $1::int8 * interval '1 millisecond'"
                ),
                crate::store::DEAD_SEGMENT_KEPT.as_millis() as i64,
            ),
            crate::store::SegmentsAlso::After(since) => (
                segments!("SELECT first_seq FROM seq_blocks WHERE first_seq > $1 AND node <> ''"),
                i64::try_from(since).unwrap_or(i64::MAX),
            ),
        };
        let rows = self
            .pool
            .run("reading the log's segments", async |c: &mut Conn| {
                c.query(query, &[&bound]).await
            })?;
        if rows.is_empty() {
            return whole();
        }
        rows.iter()
            .map(|r| {
                Ok(crate::store::LogSegment {
                    first: from_sql(r.get(0), "first_seq", "seq_blocks")?,
                    last: from_sql(r.get(1), "last_seq", "seq_blocks")?,
                    head: from_sql(r.get(2), "seq", "edit_log")?,
                })
            })
            .collect()
    }

    fn log_pruned_at_any(&self, seqs: &[u64]) -> Result<bool, StoreError> {
        let seqs: Vec<i64> = seqs
            .iter()
            .map(|&s| i64::try_from(s).unwrap_or(i64::MAX))
            .collect();
        let row = self.pool.run(
            "reading how far the log was pruned",
            async |c: &mut Conn| {
                c.query_opt(
                    "SELECT (SELECT log_base FROM world WHERE id = 1) >= ANY($1) \
                     OR EXISTS (SELECT 1 FROM seq_blocks b, unnest($1::int8[]) AS s(seq) \
                                WHERE b.first_seq <= s.seq AND b.pruned_to >= s.seq)",
                    &[&seqs],
                )
                .await
            },
        )?;
        Ok(row
            .and_then(|r| r.get::<_, Option<bool>>(0))
            .unwrap_or(false))
    }

    fn log_pruned_at(&self, seq: u64) -> Result<bool, StoreError> {
        let seq = i64::try_from(seq).unwrap_or(i64::MAX);
        let row = self.pool.run("reading how far the log was pruned", async |c: &mut Conn| {
            c.query_opt(
                "SELECT (SELECT log_base FROM world WHERE id = 1) >= $1 \
                     OR EXISTS (SELECT 1 FROM seq_blocks WHERE first_seq <= $1 AND pruned_to >= $1)",
                &[&seq],
            )
            .await
        })?;
        Ok(row
            .and_then(|r| r.get::<_, Option<bool>>(0))
            .unwrap_or(false))
    }

    fn raw_chunk(&self, pos: ChunkPos) -> Result<Option<RawChunk>, StoreError> {
        self.raw_latest(pos)
    }

    fn modified_chunks(&self) -> StoreIter<'_, (ChunkPos, u64)> {
        self.version_pages()
    }

    fn raw_chunks(&self) -> StoreIter<'_, RawChunk> {
        self.raw_pages()
    }

    fn chunk_count(&self) -> Result<u64, StoreError> {
        let n: i64 = self.pool.run("counting chunks", async |c: &mut Conn| {
            Ok(c.query("SELECT count(*) FROM chunks", &[]).await?[0].get(0))
        })?;
        from_sql(n, "chunk count", "chunks")
    }

    fn delta_count(&self) -> Result<u64, StoreError> {
        let n: i64 = self.pool.run("counting deltas", async |c: &mut Conn| {
            Ok(c.query("SELECT count(*) FROM chunk_deltas", &[]).await?[0].get(0))
        })?;
        from_sql(n, "delta count", "chunk_deltas")
    }

    fn size_on_disk(&self) -> Result<u64, StoreError> {
        let n: i64 = self
            .pool
            .run("reading the database size", async |c: &mut Conn| {
                Ok(c.query("SELECT pg_database_size(current_database())", &[])
                    .await?[0]
                    .get(0))
            })?;
        from_sql(n, "database size", "database")
    }

    fn get_blob(&self, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        check_blob_name(name)?;
        let row = self.pool.run("reading a blob", async |c: &mut Conn| {
            c.query_opt("SELECT body FROM blobs WHERE name = $1", &[&name])
                .await
        })?;
        Ok(row.map(|r| r.get(0)))
    }

    fn put_blob(&self, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        check_blob(name, bytes)?;
        self.pool.run("writing a blob", async |c: &mut Conn| {
            c.execute(
                "INSERT INTO blobs (name, body) VALUES ($1, $2) \
                 ON CONFLICT (name) DO UPDATE SET body = EXCLUDED.body",
                &[&name, &bytes],
            )
            .await
        })?;
        Ok(())
    }

    fn swap_blob(
        &self,
        name: &str,
        expected: Option<&[u8]>,
        bytes: &[u8],
    ) -> Result<bool, StoreError> {
        check_blob(name, bytes)?;
        let n =
            self.pool.run("swapping a blob", async |c: &mut Conn| {
                match expected {
            None => {
                c.execute(
                    "INSERT INTO blobs (name, body) VALUES ($1, $2) ON CONFLICT (name) DO NOTHING",
                    &[&name, &bytes],
                )
                .await
            }
            Some(old) => {
                c.execute(
                    "UPDATE blobs SET body = $3 WHERE name = $1 AND body = $2",
                    &[&name, &old, &bytes],
                )
                .await
            }
        }
            })?;
        Ok(n == 1)
    }

    fn delete_blob(&self, name: &str) -> Result<bool, StoreError> {
        check_blob_name(name)?;
        let n = self.pool.run("deleting a blob", async |c: &mut Conn| {
            c.execute("DELETE FROM blobs WHERE name = $1", &[&name])
                .await
        })?;
        Ok(n > 0)
    }

    fn save_positions(&self, positions: &[(String, StoredPosition)]) -> Result<(), StoreError> {
        // One row per player (an upsert may not touch a row twice): the last
        // wins, and never over a newer one another node saved, unless that
        // one is dated ahead of the database's clock (a node whose clock
        // ran ahead would pin it).
        const SKEW_MS: i64 = strata_protocol::limits::TICKET_SKEW_MS as i64;
        let latest: std::collections::BTreeMap<&str, StoredPosition> = positions
            .iter()
            .map(|(name, p)| (name.as_str(), *p))
            .collect();
        if latest.is_empty() {
            return Ok(());
        }
        let names: Vec<&str> = latest.keys().copied().collect();
        let axis = |f: fn(&FixedVec3) -> Fixed| latest.values().map(|p| f(&p.feet).0).collect();
        let (xs, ys, zs): (Vec<i32>, Vec<i32>, Vec<i32>) =
            (axis(|p| p.x), axis(|p| p.y), axis(|p| p.z));
        // bigint holds every time before the year 292 million.
        let times: Vec<i64> = latest
            .values()
            .map(|p| i64::try_from(p.known_ms).unwrap_or(i64::MAX))
            .collect();
        self.pool.run("saving positions", async |c: &mut Conn| {
            c.execute(
                "INSERT INTO players (name, x, y, z, known_ms) \
                 SELECT * FROM unnest($1::text[], $2::int4[], $3::int4[], $4::int4[], $5::int8[]) \
                 ON CONFLICT (name) DO UPDATE SET x = EXCLUDED.x, y = EXCLUDED.y, z = EXCLUDED.z, \
                 known_ms = EXCLUDED.known_ms WHERE players.known_ms <= EXCLUDED.known_ms \
                 OR players.known_ms > (extract(epoch FROM clock_timestamp()) * 1000)::bigint \
                     + $6",
                &[&names, &xs, &ys, &zs, &times, &SKEW_MS],
            )
            .await
        })?;
        Ok(())
    }

    fn player_position(&self, player: &str) -> Result<Option<StoredPosition>, StoreError> {
        let row = self.pool.run("reading a position", async |c: &mut Conn| {
            c.query_opt(
                "SELECT x, y, z, known_ms FROM players WHERE name = $1",
                &[&player],
            )
            .await
        })?;
        let Some(r) = row else { return Ok(None) };
        let c = |i: usize| Fixed(r.get::<_, i32>(i));
        Ok(Some(StoredPosition {
            feet: FixedVec3::new(c(0), c(1), c(2)),
            known_ms: from_sql(r.get(3), "known_ms", "players")?,
        }))
    }

    fn player_positions(&self) -> StoreIter<'_, (String, StoredPosition)> {
        let rows = self.pool.run("reading positions", async |c: &mut Conn| {
            c.query(
                "SELECT name, x, y, z, known_ms FROM players ORDER BY name",
                &[],
            )
            .await
        });
        match rows {
            Ok(rows) => Box::new(rows.into_iter().map(|r| position_row(&r))),
            Err(e) => Box::new(std::iter::once(Err(e))),
        }
    }

    fn recent_player_positions(
        &self,
        max: usize,
    ) -> Result<Vec<(String, StoredPosition)>, StoreError> {
        let limit = i64::try_from(max).unwrap_or(i64::MAX);
        let rows = self
            .pool
            .run("reading recent positions", async |c: &mut Conn| {
                c.query(
                    "SELECT name, x, y, z, known_ms FROM players \
                 ORDER BY known_ms DESC, name LIMIT $1",
                    &[&limit],
                )
                .await
            })?;
        rows.iter().map(position_row).collect()
    }

    fn chunks_with_deltas(
        &self,
        after: Option<ChunkPos>,
        max_chunks: usize,
    ) -> Result<Vec<ChunkPos>, StoreError> {
        PgStore::chunks_with_deltas(self, after, max_chunks)
    }

    fn fold_chunks(&self, chunks: &[ChunkPos]) -> Result<CheckpointStats, StoreError> {
        PgStore::fold_chunks(self, chunks)
    }

    fn check(&self) -> Result<CheckReport, StoreError> {
        self.check_with_progress(&|| {})
    }

    fn attach_generator(
        &self,
        generator: std::sync::Arc<dyn strata_terrain::world::ChunkGenerator>,
    ) {
        // The first one stays: the world has one generator.
        let _ = self.generator.set(generator);
    }

    fn encode_on(&self, pool: Option<std::sync::Arc<rayon::ThreadPool>>) {
        self.encode.set(pool);
    }

    fn close(&self) -> Result<(), StoreError> {
        // No renewal pass may adopt a region after the release below.
        if let Some(r) = &self.renewer {
            r.stop();
        }
        let released = match &self.leases {
            Some(leases) => lease::release(&self.pool, leases).map(|n| {
                tracing::info!(node = %leases.node_id(), regions = n, "region leases released");
            }),
            None => Ok(()),
        };
        // Last: a restore may go ahead once this server is gone.
        self.let_go_of_serving();
        released
    }

    fn clustered(&self) -> bool {
        self.leases.is_some()
    }

    fn regions_held(&self) -> usize {
        self.leases.as_ref().map_or(0, |l| l.held_count())
    }

    fn release_regions(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<(), StoreError> {
        match &self.leases {
            Some(leases) => lease::release_some(&self.pool, leases, regions).map(|_| ()),
            None => Ok(()),
        }
    }

    fn max_held_regions(&self) -> usize {
        self.leases.as_ref().map_or(usize::MAX, |l| l.max_held())
    }

    fn reserve_seqs(&self, last_seq: u64) -> Result<u64, StoreError> {
        let Some(leases) = &self.leases else {
            return Ok(last_seq);
        };
        let floor = match seqs::reserve(&self.pool, leases.node_id(), leases.block_size(), None) {
            Ok(floor) => floor,
            Err(e) => {
                // No seq above `last_seq` from this block: the lease
                // thread reserves the next one.
                leases.end_block_at(last_seq);
                return Err(e);
            }
        };
        leases.raise_floor(floor);
        tracing::info!(node = %leases.node_id(), first_seq = floor + 1, "seq block reserved");
        Ok(floor)
    }

    fn note_next_seq(&self, next: u64) {
        if let Some(l) = &self.leases {
            l.note_next_seq(next);
        }
    }

    fn seq_bounds(&self) -> (u64, u64) {
        self.leases
            .as_ref()
            .map_or((0, crate::store::MAX_SEQ), |l| l.seq_bounds())
    }

    fn acquire_regions(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<RegionAccess, StoreError> {
        match &self.leases {
            Some(leases) => lease::acquire(&self.pool, leases, regions),
            None => Ok(RegionAccess::Granted),
        }
    }

    fn want_regions(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<(), StoreError> {
        match &self.leases {
            Some(leases) => lease::want(&self.pool, leases, regions),
            None => Ok(()),
        }
    }

    fn superseded(&self) -> Option<String> {
        self.leases.as_ref().and_then(|l| l.superseded())
    }

    fn node_id(&self) -> Option<String> {
        self.leases.as_ref().map(|l| l.node_id().to_string())
    }

    fn serve(&self) -> Result<(), StoreError> {
        self.take_serving_lock()?;
        self.pool.run("checking the schema", async |c: &mut Conn| {
            migrate::check_current(c).await
        })
    }

    fn hold_alone(&self) -> Result<(), StoreError> {
        self.take_serving_lock_alone()
    }

    /// A round trip on the lock's connection: one that ended without a
    /// word (a crashed host, a failover, a partition) looks open until it
    /// is used.
    fn still_alone(&self) -> Result<(), StoreError> {
        let lost = || {
            StoreError::PgSetup {
            reason: "the connection keeping servers off this database ended: a server may have written meanwhile".into(),
        }
        };
        let mut serving = self.serving.lock().unwrap_or_else(|p| p.into_inner());
        let Some(conn) = serving.as_mut() else {
            return Ok(());
        };
        let held = self
            .pool
            .on_dedicated(conn, "checking the lock", holds_a_lock);
        match held {
            Ok(true) => Ok(()),
            Ok(false) | Err(_) => Err(lost()),
        }
    }

    fn register_node(&self) -> Result<(), StoreError> {
        match &self.leases {
            Some(leases) => lease::register(&self.pool, leases),
            None => Ok(()),
        }
    }

    fn region_holders(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, crate::store::RegionHolder)>, StoreError> {
        self.holders(regions, true)
    }

    fn region_holders_read(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, crate::store::RegionHolder)>, StoreError> {
        self.holders(regions, false)
    }

    fn free_region_marks(
        &self,
        regions: &std::collections::BTreeSet<RegionId>,
    ) -> Result<Vec<(RegionId, crate::store::RegionMark)>, StoreError> {
        match &self.leases {
            Some(_) => lease::free_marks(&self.pool, regions),
            None => Ok(Vec::new()),
        }
    }

    fn take_fresh_regions(&self) -> Vec<(RegionId, Option<u64>)> {
        self.leases
            .as_ref()
            .map_or_else(Vec::new, |l| l.take_fresh())
    }

    fn region_versions(&self, region: RegionId) -> Result<Vec<(ChunkPos, u64)>, StoreError> {
        self.stored_versions(region)
    }

    fn report_to(&self, health: std::sync::Arc<crate::health::Health>) {
        if let Some(leases) = &self.leases {
            leases.report_to(health);
        }
    }

    fn bound_at(&self, addr: &str) {
        if let Some(leases) = &self.leases {
            leases.set_addr_if_unset(addr);
        }
    }
}
