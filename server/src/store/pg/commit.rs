//! One tick's commit: one PostgreSQL transaction, durable when `COMMIT`
//! returns (`synchronous_commit = on`).
//!
//! A single node's transaction locks the world row first, so its commits
//! run one at a time. Then it locks the rows of the chunks the batch
//! changes (in key order), so a checkpoint cannot fold them meanwhile. A
//! cluster node's takes no world row: after the chunks' rows it locks its
//! regions' (`fence.rs`), so nodes commit side by side, and one paused
//! inside its commit holds up only the regions it writes. It refuses, changing nothing,
//! what the sled store refuses: seqs that do not follow `last_seq`, chunk
//! versions at or below the stored ones, and deltas that do not continue
//! the stored chain. A cluster node's commit is also fenced (`fence.rs`):
//! it writes only regions it holds at the epoch the store has, with seqs
//! above each region's last; its seqs come from its own block (`seqs.rs`),
//! so they need not follow `last_seq`, and they leave the world row's
//! `last_seq` alone: the store's last seq is the higher of it and the
//! log's last (`last_seq_sql!`).

use super::patience::Patience;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Instant;

use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::ChunkPos;

use super::fence::{self, Fence};
use super::pool::Conn;
use super::{to_sql, PgStore};
use crate::sequencer::regions::RegionId;
use crate::store::batch;
use crate::store::keys::show_pos;
use crate::store::record::{encode_delta, encode_log_record, GENERATED_BODY};
use crate::store::types::{CommitBatch, CommitStats};
use crate::store::StoreError;
use tokio_postgres::error::SqlState;

/// A batch encoded as column arrays, ready for `unnest`.
#[derive(Debug, Default)]
struct Columns {
    first_seq: i64,
    last_seq: i64,
    seqs: Vec<i64>,
    entries: Vec<Vec<u8>>,
    /// Whole chunks: position, region, version, chunk codec bytes.
    chunks: Rows,
    /// Deltas: position, region, to_version, bincode delta.
    deltas: Rows,
    /// The lowest version the batch gives each chunk, and for a chunk
    /// changed by deltas the version its chain must start from.
    lowest: BTreeMap<ChunkPos, u64>,
    starts: BTreeMap<ChunkPos, u64>,
    bytes: u64,
}

/// Chunk or delta rows as column arrays for `unnest`.
#[derive(Debug, Default)]
pub(super) struct Rows {
    pub(super) x: Vec<i32>,
    pub(super) y: Vec<i32>,
    pub(super) z: Vec<i32>,
    pub(super) rx: Vec<i32>,
    pub(super) rz: Vec<i32>,
    pub(super) version: Vec<i64>,
    pub(super) body: Vec<Vec<u8>>,
}

impl Columns {
    /// Every region the batch writes a chunk or delta of.
    fn regions(&self) -> BTreeSet<RegionId> {
        [&self.chunks, &self.deltas]
            .iter()
            .flat_map(|r| r.rx.iter().zip(&r.rz))
            .map(|(&x, &z)| RegionId { x, z })
            .collect()
    }
}

impl Rows {
    pub(super) fn push(&mut self, store: &PgStore, pos: ChunkPos, version: i64, body: Vec<u8>) {
        let r = store.region(pos);
        self.x.push(pos.x);
        self.y.push(pos.y);
        self.z.push(pos.z);
        self.rx.push(r.x);
        self.rz.push(r.z);
        self.version.push(version);
        self.body.push(body);
    }
}

/// An error before `COMMIT` was sent: a session the server ended (idle in
/// the transaction too long, or the connection gone), or a transaction it
/// aborted (a deadlock or serialization failure it broke by ending this
/// one, a statement cancelled), wrote nothing.
fn before_commit(e: StoreError) -> StoreError {
    let aborted = [
        SqlState::IDLE_IN_TRANSACTION_SESSION_TIMEOUT,
        SqlState::T_R_DEADLOCK_DETECTED,
        SqlState::T_R_SERIALIZATION_FAILURE,
        SqlState::QUERY_CANCELED,
        SqlState::LOCK_NOT_AVAILABLE,
    ];
    match &e {
        StoreError::Postgres(pg)
            if pg.is_closed() || pg.code().is_some_and(|c| aborted.contains(c)) =>
        {
            StoreError::Uncommitted {
                reason: e.to_string(),
            }
        }
        _ => e,
    }
}

impl PgStore {
    /// One try at committing `b`; `patience` says how long an unanswered
    /// `COMMIT`'s outcome is asked about again.
    pub(super) fn commit(
        &self,
        b: &CommitBatch,
        patience: &mut Patience,
    ) -> Result<CommitStats, StoreError> {
        let lowest = batch::validate(b)?;
        let Some(first) = b.entries.first() else {
            return Ok(CommitStats::default());
        };
        let started = Instant::now();
        let mut cols = Columns {
            first_seq: to_sql(first.seq, "seq")?,
            last_seq: to_sql(b.last_seq, "seq")?,
            lowest,
            ..Columns::default()
        };
        for e in &b.entries {
            cols.seqs.push(to_sql(e.seq, "seq")?);
            cols.entries.push(encode_log_record(e)?);
        }
        // With a generator, a new chunk is a "generated" record and the
        // delta of its first changes; its whole state waits for a fold.
        let from_generated: BTreeMap<ChunkPos, &ChunkDelta> = match self.generator() {
            Some(_) => b.generated.iter().map(|d| (d.pos, d)).collect(),
            None => BTreeMap::new(),
        };
        for d in from_generated.values() {
            cols.chunks.push(self, d.pos, 0, GENERATED_BODY.to_vec());
            cols.starts.insert(d.pos, 0);
            cols.deltas.push(
                self,
                d.pos,
                to_sql(d.to_version, "chunk version")?,
                encode_delta(d)?,
            );
        }
        let whole: Vec<_> = b
            .chunks
            .iter()
            .filter(|c| !from_generated.contains_key(&c.0))
            .collect();
        // zstd dominates a big batch's cost; chunks compress independently.
        let bodies: Vec<Vec<u8>> = self.encode.map(&whole, |c| encode_chunk(&c.2));
        for ((pos, version, _), body) in whole.into_iter().zip(bodies) {
            cols.chunks
                .push(self, *pos, to_sql(*version, "chunk version")?, body);
        }
        for d in &b.deltas {
            cols.starts.entry(d.pos).or_insert(d.from_version);
            cols.deltas.push(
                self,
                d.pos,
                to_sql(d.to_version, "chunk version")?,
                encode_delta(d)?,
            );
        }
        cols.bytes = [&cols.entries, &cols.chunks.body, &cols.deltas.body]
            .iter()
            .flat_map(|v| v.iter())
            .map(|v| v.len() as u64)
            .sum();
        let fence = match &self.leases {
            Some(leases) => {
                // Those it writes, and those its edits read (the engine's
                // epochs name them too).
                let mut regions = cols.regions();
                regions.extend(b.epochs.iter().flat_map(|e| e.keys().copied()));
                let mut f = fence::prepare(&self.pool, leases, &regions, b.epochs.as_ref())?;
                f.set_seqs(cols.first_seq, cols.last_seq);
                f.count_edits(b.entries.iter().map(|e| {
                    e.changes
                        .iter()
                        .map(|(pos, _)| self.region(*pos))
                        .collect::<BTreeSet<_>>()
                }));
                Some(f)
            }
            None => None,
        };
        let encode = started.elapsed();
        let commit_sent = std::sync::atomic::AtomicBool::new(false);
        let named = std::sync::OnceLock::new();
        let committed = self.pool.run_own(
            &self.commit_conn,
            "committing a batch",
            async |c: &mut Conn| {
                let _ = named.set(begin(c).await.map_err(before_commit)?);
                let applying = Instant::now();
                match write(c, &cols, fence.as_ref(), self.world_id.get()).await {
                    Ok(()) => {
                        let apply = applying.elapsed();
                        let committing = Instant::now();
                        // From here a lost connection leaves the outcome unknown.
                        commit_sent.store(true, std::sync::atomic::Ordering::Release);
                        c.batch("COMMIT").await?;
                        Ok((apply, committing.elapsed()))
                    }
                    Err(e) => {
                        if !e.is_postgres() {
                            c.batch("ROLLBACK").await?;
                        }
                        Err(before_commit(e))
                    }
                }
            },
        );
        // COMMIT was sent and went unanswered: the connection ended (a
        // node paused past its lease just then: the server ends a session
        // idle in its transaction, COMMIT unread) or the wait timed out.
        // PostgreSQL says how the transaction ended, once it has.
        let mut unanswered = |e: StoreError| match named.get() {
            Some(&x) => self
                .settle(x, cols.first_seq, e, patience)
                .map(|()| (std::time::Duration::ZERO, std::time::Duration::ZERO)),
            None => Err(e),
        };
        let sent = commit_sent.load(std::sync::atomic::Ordering::Acquire);
        let committed = match committed {
            // Timed out before COMMIT was sent (waiting on another node's
            // row locks, say): the connection was closed, so nothing was
            // written.
            Err(e @ StoreError::PgTimeout { .. }) if !sent => Err(StoreError::Uncommitted {
                reason: e.to_string(),
            }),
            Err(e @ StoreError::PgTimeout { .. }) => unanswered(e),
            // The connection closed, or an error came back (the session
            // ended by the server before it read COMMIT, say): PostgreSQL's
            // record says which.
            Err(e @ StoreError::Postgres(_)) if sent => unanswered(e),
            // PostgreSQL unreachable before COMMIT (its connection refused
            // or ended, the server shutting down or starting up) wrote
            // nothing either. (A cluster node abandons a batch that wrote
            // nothing: only a server alone is told so, to try again.)
            Err(e) if self.leases.is_none() && e.is_pg_outage() => Err(StoreError::Uncommitted {
                reason: e.to_string(),
            }),
            other => other,
        };
        if let (
            Err(StoreError::Fenced {
                region, held_epoch, ..
            }),
            Some(leases),
        ) = (&committed, &self.leases)
        {
            leases.lose_at(*region, *held_epoch);
        }
        let (apply, commit) = committed?;
        Ok(CommitStats {
            bytes_written: cols.bytes,
            encode,
            apply,
            flush: std::time::Duration::ZERO,
            // COMMIT returns after the WAL flush: that is the fsync.
            fsync: commit,
        })
    }
}

/// A commit's transaction as PostgreSQL names it: enough for another
/// session to learn how it ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Xact {
    /// `pg_current_xact_id()`: epoch and xid, never reused.
    xid: u64,
    /// The session's backend process.
    pid: i32,
}

/// Opens the commit's transaction and names it, in the one round trip
/// `BEGIN` took alone.
async fn begin(c: &mut Conn) -> Result<Xact, StoreError> {
    let row = c
        .simple_row("BEGIN; SELECT pg_current_xact_id()::text, pg_backend_pid()::text")
        .await?
        .unwrap_or_default();
    let field = |i: usize| row.get(i).cloned().flatten().unwrap_or_default();
    match (field(0).parse(), field(1).parse()) {
        (Ok(xid), Ok(pid)) => Ok(Xact { xid, pid }),
        _ => {
            c.batch("ROLLBACK").await?;
            Err(StoreError::corrupt("transaction id", format!("{row:?}")))
        }
    }
}

/// Between looks at a transaction whose session is being ended.
const OUTCOME_POLL: std::time::Duration = std::time::Duration::from_millis(20);

/// How PostgreSQL records transaction `xid`: `committed`, `aborted`,
/// `in progress`, or `None` (too old, or never handed out).
async fn xact_status(c: &mut Conn, xid: &str) -> Result<Option<String>, StoreError> {
    let row = c
        .query_opt("SELECT pg_xact_status($1::text::xid8)", &[&xid])
        .await?;
    Ok(row.and_then(|r| r.get::<_, Option<String>>(0)))
}

impl PgStore {
    /// How `x`, whose COMMIT went unanswered (`e`), ended: `Ok` when it
    /// committed the batch whose first seq is `first_seq`,
    /// [`StoreError::Uncommitted`] when it did not; asked again while
    /// PostgreSQL cannot say (unreachable), within `patience`, then `e`.
    fn settle(
        &self,
        x: Xact,
        first_seq: i64,
        e: StoreError,
        patience: &mut Patience,
    ) -> Result<(), StoreError> {
        loop {
            match self.outcome(x, first_seq) {
                Ok(Some(true)) => return Ok(()),
                Ok(Some(false)) => {
                    return Err(StoreError::Uncommitted {
                        reason: format!("{e}; PostgreSQL rolled the transaction back"),
                    })
                }
                Err(replaced @ StoreError::WorldReplaced { .. }) => return Err(replaced),
                Ok(None) | Err(_) if patience.again("a commit's outcome is unknown", &e) => {}
                Ok(None) | Err(_) => return Err(e),
            }
        }
    }

    /// Whether `x`, whose COMMIT went unanswered, committed the batch
    /// whose first seq is `first_seq`: `None` when PostgreSQL cannot say
    /// (unreachable, or the transaction still in progress after the
    /// statement timeout). Its session may still be alive (the connection
    /// only looked dead from here, its COMMIT unread or under way): that
    /// session is ended first, which rolls back a transaction whose COMMIT
    /// never arrived and lets one under way finish, so the answer cannot
    /// change afterwards (the log row a look used to read could still
    /// appear after it was found missing). On a connection of its own:
    /// the pool's may all be lent out.
    fn outcome(&self, x: Xact, first_seq: i64) -> Result<Option<bool>, StoreError> {
        let deadline = Instant::now() + self.pool.statement_timeout();
        let xid = x.xid.to_string();
        // pg_stat_activity shows the 32-bit xid, without the epoch.
        let short = (x.xid & 0xffff_ffff).to_string();
        let what = "reading a commit's outcome";
        let (mut conn, mut status) = self
            .pool
            .dedicated(what, async |c: &mut Conn| xact_status(c, &xid).await)?;
        // Ends the session if it still runs the transaction; whether it did.
        let end_session = |conn: &mut Conn| {
            self.pool
                .on_dedicated(conn, "ending a commit's session", async |c: &mut Conn| {
                    let row = c
                        .query_opt(
                            "SELECT pg_terminate_backend(pid) FROM pg_stat_activity \
                             WHERE pid = $1 AND backend_xid::text = $2",
                            &[&x.pid, &short],
                        )
                        .await?;
                    Ok(row.is_some())
                })
        };
        loop {
            match status.as_deref() {
                // Committed, but its rows may not show yet while its session
                // still runs it (a synchronous standby's word awaited): that
                // session is ended and gone first. Then, since a server that
                // lost the transaction (a crash before its WAL reached the
                // disk) may have handed its id out again, the batch's own
                // log row tells.
                Some("committed") => {
                    if end_session(&mut conn)? {
                        if Instant::now() >= deadline {
                            return Ok(None);
                        }
                        std::thread::sleep(OUTCOME_POLL);
                        continue;
                    }
                    // In the world this server started on: a restore while
                    // PostgreSQL was unreachable may have logged that seq.
                    let (logged, world) =
                        self.pool
                            .on_dedicated(&mut conn, what, async |c: &mut Conn| {
                                let row = c
                                    .query_opt(
                                        "SELECT EXISTS (SELECT 1 FROM edit_log WHERE seq = $1), \
                                         (SELECT generation FROM world WHERE id = 1)",
                                        &[&first_seq],
                                    )
                                    .await?;
                                Ok(row.map_or((false, None), |r| {
                                    (r.get::<_, bool>(0), r.get::<_, Option<String>>(1))
                                }))
                            })?;
                    if let Some(found) = world {
                        same_world(self.world_id.get(), found)?;
                    }
                    return Ok(Some(logged));
                }
                Some("aborted") => return Ok(Some(false)),
                Some("in progress") if Instant::now() < deadline => {
                    end_session(&mut conn)?;
                    std::thread::sleep(OUTCOME_POLL);
                    status = self
                        .pool
                        .on_dedicated(&mut conn, what, async |c: &mut Conn| {
                            xact_status(c, &xid).await
                        })?;
                }
                _ => return Ok(None),
            }
        }
    }
}

/// The transaction's statements, between `BEGIN` and `COMMIT`.
/// `world`: the world's id the server started on, which the store must
/// still hold (`None`: a tool's or a test's store, which never read it).
async fn write(
    c: &mut Conn,
    cols: &Columns,
    fence: Option<&Fence>,
    world: Option<&String>,
) -> Result<(), StoreError> {
    if fence.is_none() {
        let Some(row) = c
            .query_opt(
                "SELECT last_seq, (SELECT COALESCE(max(seq), 0) FROM edit_log), \
                     EXISTS (SELECT 1 FROM seq_blocks), generation \
                 FROM world WHERE id = 1 FOR UPDATE",
                &[],
            )
            .await?
        else {
            return Err(StoreError::NoMeta);
        };
        same_world(world, row.get(3))?;
        let (row_last, logged, clustered): (i64, i64, bool) = (row.get(0), row.get(1), row.get(2));
        // A cluster's fenced commits leave the row behind the log; a
        // store never clustered has nothing logged beyond it.
        if logged > row_last && !clustered {
            return Err(StoreError::corrupt(
                "log record beyond last_seq",
                format!("seq {logged}"),
            ));
        }
        let last = row_last.max(logged);
        if last.checked_add(1) != Some(cols.first_seq) {
            return Err(StoreError::batch(format!(
                "first seq {} does not follow the stored last_seq {last}",
                cols.first_seq
            )));
        }
    }
    let heads = lock_heads(c, cols).await?;
    if let Some(fence) = fence {
        // Nodes number from blocks of their own (`seqs.rs`): the log has
        // gaps, and per region the fence checks the order. No world row:
        // a node paused in its commit stalls only its own regions. Their
        // rows are locked after the chunks', so a commit waiting on a
        // fold holds up no renewal or claim meanwhile.
        fence::check(c, fence, world).await?;
    }
    for (pos, &lowest) in &cols.lowest {
        let head = heads.get(pos).copied();
        match cols.starts.get(pos) {
            // Stored from generated: nothing may be stored yet.
            Some(&0) if head.is_none() => {}
            Some(&from) if head != Some(from) => {
                return Err(StoreError::batch(format!(
                    "{} is not stored at version {from}, the batch's delta starts there",
                    show_pos(*pos)
                )))
            }
            None => {
                if let Some(head) = head.filter(|&h| h >= lowest) {
                    return Err(StoreError::batch(format!(
                        "{} is stored at version {head}, the batch moves it to {lowest}",
                        show_pos(*pos)
                    )));
                }
            }
            Some(_) => {}
        }
    }
    let beyond = match fence {
        // Another node's newer block may be above: seqs must be free.
        Some(_) => {
            c.query_opt(
                "SELECT seq FROM edit_log WHERE seq = ANY($1) LIMIT 1",
                &[&cols.seqs],
            )
            .await?
        }
        None => {
            c.query_opt(
                "SELECT seq FROM edit_log WHERE seq >= $1 LIMIT 1",
                &[&cols.first_seq],
            )
            .await?
        }
    };
    if let Some(row) = beyond {
        let seq: i64 = row.get(0);
        return Err(match fence {
            Some(_) => StoreError::batch(format!("seq {seq} is logged already")),
            None => StoreError::corrupt("log record beyond last_seq", format!("seq {seq}")),
        });
    }
    let ch = &cols.chunks;
    if !ch.x.is_empty() {
        c.execute(
            "INSERT INTO chunks (x, y, z, region_x, region_z, version, body) \
             SELECT * FROM unnest($1::int4[], $2::int4[], $3::int4[], $4::int4[], \
                                  $5::int4[], $6::int8[], $7::bytea[]) \
             ON CONFLICT (x, y, z) DO UPDATE SET version = EXCLUDED.version, body = EXCLUDED.body",
            &[&ch.x, &ch.y, &ch.z, &ch.rx, &ch.rz, &ch.version, &ch.body],
        )
        .await?;
        // Deltas a whole state replaces are no longer part of any chain.
        c.execute(
            "DELETE FROM chunk_deltas d \
             USING unnest($1::int4[], $2::int4[], $3::int4[], $4::int8[]) AS u(x, y, z, v) \
             WHERE d.x = u.x AND d.y = u.y AND d.z = u.z AND d.to_version <= u.v",
            &[&ch.x, &ch.y, &ch.z, &ch.version],
        )
        .await?;
    }
    let d = &cols.deltas;
    if !d.x.is_empty() {
        c.execute(
            "INSERT INTO chunk_deltas (x, y, z, region_x, region_z, to_version, body) \
             SELECT * FROM unnest($1::int4[], $2::int4[], $3::int4[], $4::int4[], \
                                  $5::int4[], $6::int8[], $7::bytea[])",
            &[&d.x, &d.y, &d.z, &d.rx, &d.rz, &d.version, &d.body],
        )
        .await?;
    }
    c.execute(
        "INSERT INTO edit_log (seq, entry) SELECT * FROM unnest($1::int8[], $2::bytea[])",
        &[&cols.seqs, &cols.entries],
    )
    .await?;
    if fence.is_none() {
        c.execute(
            "UPDATE world SET last_seq = $1 WHERE id = 1",
            &[&cols.last_seq],
        )
        .await?;
    }
    Ok(())
}

/// Refuses a commit into another world than the one the server started on
/// (`expected`): one a restore wrote while the server's lock connection
/// was lost. Its seqs may well follow on: the restored world can end at
/// the very seq the server is at.
pub(super) fn same_world(expected: Option<&String>, found: String) -> Result<(), StoreError> {
    match expected {
        Some(e) if *e != found => Err(StoreError::WorldReplaced {
            expected: e.clone(),
            found,
        }),
        _ => Ok(()),
    }
}

/// Locks the stored records of the batch's chunks (in key order, so two
/// lockers never wait on each other crosswise) and reads each one's
/// newest version: its record's, or its last delta's.
async fn lock_heads(c: &mut Conn, cols: &Columns) -> Result<BTreeMap<ChunkPos, u64>, StoreError> {
    let (mut x, mut y, mut z) = (Vec::new(), Vec::new(), Vec::new());
    for p in cols.lowest.keys() {
        x.push(p.x);
        y.push(p.y);
        z.push(p.z);
    }
    let mut heads = BTreeMap::new();
    for r in c
        .query(
            "SELECT c.x, c.y, c.z, c.version FROM chunks c \
             JOIN unnest($1::int4[], $2::int4[], $3::int4[]) AS u(x, y, z) \
               ON c.x = u.x AND c.y = u.y AND c.z = u.z \
             ORDER BY c.x, c.y, c.z FOR UPDATE OF c",
            &[&x, &y, &z],
        )
        .await?
    {
        heads.insert(
            ChunkPos::new(r.get(0), r.get(1), r.get(2)),
            r.get::<_, i64>(3),
        );
    }
    // Read after the locks: a fold that held one has committed by now.
    for r in c
        .query(
            "SELECT d.x, d.y, d.z, max(d.to_version) FROM chunk_deltas d \
             JOIN unnest($1::int4[], $2::int4[], $3::int4[]) AS u(x, y, z) \
               ON d.x = u.x AND d.y = u.y AND d.z = u.z \
             GROUP BY d.x, d.y, d.z",
            &[&x, &y, &z],
        )
        .await?
    {
        let pos = ChunkPos::new(r.get(0), r.get(1), r.get(2));
        let v: i64 = r.get(3);
        let head = heads.entry(pos).or_insert(v);
        *head = (*head).max(v);
    }
    heads
        .into_iter()
        .map(|(p, v)| Ok((p, super::from_sql(v, "chunk version", show_pos(p))?)))
        .collect()
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::store::pg::pool::Pool;
    use crate::store::pg::PgConfig;
    use crate::store::ChunkStore;

    /// A commit whose COMMIT went unanswered is resolved by PostgreSQL's
    /// record of its transaction: committed, rolled back, or, while its
    /// session still holds it open (the connection only looked dead from
    /// here), rolled back by ending that session, which can then no
    /// longer commit it.
    #[test]
    fn a_commits_outcome_is_read_from_its_transaction() {
        let Some(db) = strata_tests::postgres::database("pg_commit_outcome") else {
            return;
        };
        let cfg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        // The store waits 3 s at most; the open transaction's session is
        // never ended by the server on its own meanwhile.
        let store = PgStore::open(
            &PgConfig {
                statement_timeout_ms: 3_000,
                ..cfg.clone()
            },
            8,
        )
        .unwrap();
        let other = Pool::open_idle(&cfg, Duration::from_secs(600)).unwrap();
        let log = |seq: i64, end: &'static str| {
            other
                .run("logging one entry", async move |c: &mut Conn| {
                    let x = begin(c).await?;
                    c.batch(&format!(
                        "INSERT INTO edit_log (seq, entry) VALUES ({seq}, '\\x00'); {end}"
                    ))
                    .await?;
                    Ok(x)
                })
                .unwrap()
        };
        assert_eq!(store.outcome(log(5, "COMMIT"), 5).unwrap(), Some(true));
        // Committed, but not the batch starting at seq 4: a transaction
        // the server lost, whose id it handed out again.
        assert_eq!(store.outcome(log(6, "COMMIT"), 4).unwrap(), Some(false));
        assert_eq!(store.outcome(log(8, "ROLLBACK"), 8).unwrap(), Some(false));
        let (mut open, x) = other
            .dedicated("an open transaction", async |c: &mut Conn| {
                let x = begin(c).await?;
                c.batch("INSERT INTO edit_log (seq, entry) VALUES (7, '\\x00')")
                    .await?;
                Ok(x)
            })
            .unwrap();
        assert_eq!(store.outcome(x, 7).unwrap(), Some(false));
        let late = other.on_dedicated(&mut open, "committing late", async |c: &mut Conn| {
            c.batch("COMMIT").await
        });
        assert!(late.is_err(), "{late:?}");
        let logged = other
            .run("reading the log", async |c: &mut Conn| {
                let rows = c
                    .query("SELECT seq FROM edit_log ORDER BY seq", &[])
                    .await?;
                Ok(rows.iter().map(|r| r.get::<_, i64>(0)).collect::<Vec<_>>())
            })
            .unwrap();
        assert_eq!(logged, [5, 6]);
    }

    /// An unanswered COMMIT's outcome is asked again while PostgreSQL
    /// cannot say, within the store's patience, and no longer.
    #[test]
    fn an_unanswered_commit_is_settled_once_postgres_is_back() {
        let Some(db) = strata_tests::postgres::database("pg_commit_settled") else {
            return;
        };
        let cfg = PgConfig {
            url: db.url(),
            connect_timeout_ms: 1_000,
            ..PgConfig::default()
        };
        let store = PgStore::open(&cfg, 8).unwrap();
        store
            .init_meta(&crate::store::WorldMeta::new(1, 1, ""))
            .unwrap();
        let other = Pool::open(&cfg).unwrap();
        let x = other
            .run("logging one entry", async |c: &mut Conn| {
                let x = begin(c).await?;
                c.batch("INSERT INTO edit_log (seq, entry) VALUES (3, '\\x00'); COMMIT")
                    .await?;
                Ok(x)
            })
            .unwrap();
        let admin = Pool::open(&PgConfig {
            url: db.cluster().url("postgres"),
            ..PgConfig::default()
        })
        .unwrap();
        let name = db.name().to_string();
        let allow = |yes: bool| {
            let sql = format!(
                "ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS {yes}; \
                 SELECT pg_terminate_backend(pid) FROM pg_stat_activity \
                 WHERE datname = '{name}' AND pid <> pg_backend_pid()"
            );
            admin
                .run("opening or closing the database", async |c: &mut Conn| {
                    c.batch(&sql).await
                })
                .unwrap();
        };
        let unanswered = || StoreError::PgTimeout {
            what: "committing a batch",
            limit_ms: 1,
        };
        allow(false);
        let gave_up = store.settle(x, 3, unanswered(), &mut Patience::new(Duration::ZERO));
        assert!(
            matches!(gave_up, Err(StoreError::PgTimeout { .. })),
            "{gave_up:?}"
        );
        let settled = std::thread::scope(|s| {
            s.spawn(|| {
                std::thread::sleep(Duration::from_millis(800));
                allow(true);
            });
            let mut patience = Patience::new(Duration::from_secs(20));
            store.settle(x, 3, unanswered(), &mut patience)
        });
        assert!(settled.is_ok(), "{settled:?}");
        assert!(matches!(
            store.settle(x, 4, unanswered(), &mut Patience::new(Duration::ZERO)),
            Err(StoreError::Uncommitted { .. })
        ));
        // Committed, but into a world a restore put in place meanwhile:
        // never acknowledged, never asked again.
        other
            .run("replacing the world", async |c: &mut Conn| {
                c.batch("UPDATE world SET generation = 'restored' WHERE id = 1")
                    .await
            })
            .unwrap();
        let mut patience = Patience::new(Duration::from_secs(20));
        let replaced = store.settle(x, 3, unanswered(), &mut patience);
        assert!(
            matches!(replaced, Err(StoreError::WorldReplaced { .. })),
            "{replaced:?}"
        );
    }

    /// Before a commit is tried again, a serving lock connection whose
    /// session no longer holds the lock (lost to a failover, it looked
    /// open) is dropped, and the lock taken again on a new one.
    #[test]
    fn a_retry_takes_the_serving_lock_again_when_its_session_lost_it() {
        let Some(db) = strata_tests::postgres::database("pg_retry_relocks") else {
            return;
        };
        let cfg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let store = PgStore::open(&cfg, 8).unwrap();
        store
            .init_meta(&crate::store::WorldMeta::new(1, 1, ""))
            .unwrap();
        store.serve().unwrap();
        let other = Pool::open(&cfg).unwrap();
        let holder = || {
            other
                .run("who holds the serving lock", async |c: &mut Conn| {
                    let rows = c
                        .query(
                            "SELECT pid FROM pg_locks WHERE locktype = 'advisory' \
                             AND classid = ($1::bigint >> 32)::oid \
                             AND objid = ($1::bigint & 4294967295)::oid AND granted \
                             AND database = (SELECT oid FROM pg_database \
                                             WHERE datname = current_database())",
                            &[&super::super::import::SERVING_LOCK],
                        )
                        .await?;
                    Ok(rows.iter().map(|r| r.get::<_, i32>(0)).collect::<Vec<_>>())
                })
                .unwrap()
        };
        let first = holder();
        assert_eq!(first.len(), 1, "{first:?}");
        assert!(
            !store.recheck_serving(),
            "a session still holding it is kept"
        );
        assert_eq!(holder(), first);
        // The session lets go of its locks (as a new primary knows none).
        other
            .run("ending the lock", async |c: &mut Conn| {
                c.execute("SELECT pg_terminate_backend($1, 5000)", &[&first[0]])
                    .await
                    .map(|_| ())
            })
            .unwrap();
        assert!(store.recheck_serving(), "lost");
        store.take_serving_lock().unwrap();
        let now = holder();
        assert_eq!(now.len(), 1, "{now:?}");
        assert_ne!(now, first, "taken again on another session");
    }

    #[test]
    fn a_session_ended_idle_in_its_transaction_wrote_nothing() {
        let Some(db) = strata_tests::postgres::database("pg_idle_in_transaction") else {
            return;
        };
        let cfg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let pool = Pool::open_idle(&cfg, Duration::from_millis(100)).unwrap();
        // A client stalled inside its transaction (a paused node): the
        // server ends the session, and the next statement says so.
        let r = pool.run("an idle transaction", async |c: &mut Conn| {
            c.batch("BEGIN").await?;
            std::thread::sleep(Duration::from_millis(600));
            c.batch("SELECT 1").await.map_err(before_commit)
        });
        assert!(matches!(r, Err(StoreError::Uncommitted { .. })), "{r:?}");
        // That connection was dropped: the next call gets a fresh one.
        pool.run("a fresh session", async |c: &mut Conn| {
            c.batch("SELECT 1").await
        })
        .unwrap();
    }

    /// Two transactions locking two rows in opposite orders: PostgreSQL
    /// breaks the deadlock by aborting one, which wrote nothing.
    #[test]
    fn a_transaction_aborted_to_break_a_deadlock_wrote_nothing() {
        let Some(db) = strata_tests::postgres::database("pg_deadlock") else {
            return;
        };
        let cfg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let setup = Pool::open_idle(&cfg, Duration::from_secs(60)).unwrap();
        setup
            .run("a table", async |c: &mut Conn| {
                c.batch("CREATE TABLE t (id int PRIMARY KEY, n int); INSERT INTO t VALUES (1, 0), (2, 0)")
                    .await
            })
            .unwrap();
        let both_hold_one = std::sync::Barrier::new(2);
        let results: Vec<Result<(), StoreError>> = std::thread::scope(|scope| {
            let runs: Vec<_> = [(1, 2), (2, 1)]
                .into_iter()
                .map(|(first, second)| {
                    let (cfg, barrier) = (&cfg, &both_hold_one);
                    scope.spawn(move || {
                        let pool = Pool::open_idle(cfg, Duration::from_secs(60)).unwrap();
                        pool.run("locking two rows", async |c: &mut Conn| {
                            c.batch("BEGIN").await?;
                            let lock = |id: i32| format!("UPDATE t SET n = n + 1 WHERE id = {id}");
                            c.batch(&lock(first)).await?;
                            barrier.wait();
                            match c.batch(&lock(second)).await {
                                Ok(()) => c.batch("COMMIT").await,
                                Err(e) => Err(before_commit(e)),
                            }
                        })
                    })
                })
                .collect();
            runs.into_iter().map(|r| r.join().unwrap()).collect()
        });
        let aborted: Vec<_> = results.iter().filter_map(|r| r.as_ref().err()).collect();
        assert_eq!(aborted.len(), 1, "{results:?}");
        assert!(
            matches!(aborted[0], StoreError::Uncommitted { reason } if reason.contains("deadlock")),
            "{aborted:?}"
        );
    }
}
