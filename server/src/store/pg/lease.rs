//! Region leases: which regions this node may write, and with which epoch.
//!
//! A row of `regions` (migration 0002) names a region's owner, its epoch
//! and when its lease runs out, on the database's clock. A node claims a
//! region that is free (never claimed, released, or its lease expired) or
//! that its own node id holds (a restart under the same name); every claim
//! bumps the epoch, and so does a restore, which frees every region
//! (`import.rs`). It renews what it holds every `renew_ms` while owner
//! and epoch are still its own. A region whose epoch moved on is lost: a
//! commit or an adoption never claims it back, since this process's copy
//! may be stale; only the engine does, asking for it again ([`acquire`]): then
//! it is claimed like any other and reported fresh, the engine reloads it,
//! and a batch the engine built before that carries the old epoch and is
//! refused. Commits check the epochs (`fence.rs`).
//!
//! The engine asks before it queues an edit ([`PgStore::acquire`]): a
//! region held elsewhere refuses the edit with the holder's name and
//! address, cached until its lease could have run out, so a client aiming
//! edits at another node's regions costs no query each. Every renewal also
//! adopts regions whose owner let the lease run out (a crashed node), at
//! most [`MAX_ADOPT_PER_RENEWAL`] at a time. Every region claimed is
//! reported once as fresh: its stored chunks may have moved on while
//! another node held it, and the engine reloads them before using them.
//! Each renewal releases the regions no edit asked for in `[cluster]
//! release_idle_ms`, and a node holds at most `max_held_regions`: past
//! half of it, those no edit asked for in a whole lease ([`release_idle`]).
//!
//! Handoffs: an edit this node must apply (its own region is held here,
//! and this node has room) that writes into a region another node holds
//! asks that node for it ([`want`]: the row's `wanted_by`, at most once a renewal period per
//! region). The holder lets the region go at its next renewal once its own
//! edits have left it alone for `[cluster] handoff_idle_ms`
//! ([`hand_over`]), and the edit sent again claims it. A claim clears the
//! ask; an ask older than two renewal periods is ignored.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use tracing::{info, warn};

use super::pool::{Conn, Pool};
use super::{from_sql, seqs, PgStore};
use crate::cluster::ClusterConfig;
use crate::sequencer::regions::RegionId;
use crate::store::{RegionAccess, RegionHolder, StoreError};

/// Most expired regions one renewal adopts.
pub const MAX_ADOPT_PER_RENEWAL: i64 = 256;
/// Most holders of other nodes' regions remembered for refusals; the cache
/// is emptied when full.
pub const MAX_CACHED_HOLDERS: usize = 4096;

/// This node's leases: its name, its lease length, and what it holds.
#[derive(Debug)]
pub struct NodeLeases {
    node_id: String,
    lease_ms: f64,
    renew: Duration,
    adopt: bool,
    max_held: usize,
    /// `[cluster] release_idle_ms`: `None` for 0 (never by time alone).
    release_idle: Option<Duration>,
    /// `[cluster] handoff_idle_ms`: `None` for 0 (never hands over).
    handoff_idle: Option<Duration>,
    /// Where clients reach this node (`[cluster] advertise`, or the bound
    /// address), written into the rows it claims.
    addr: Mutex<String>,
    /// This process's current seq block.
    seqs: Mutex<SeqBlock>,
    /// Seqs in each block it reserves (`[cluster] seq_block`).
    block: u64,
    /// The engine's next seq, as it last told ([`NodeLeases::note_next_seq`]):
    /// the renewal thread reserves the next block when its block runs low.
    next_seq: AtomicU64,
    /// This process's incarnation (random, written into `nodes` at open).
    incarnation: i64,
    /// The incarnation a renewal found there instead, once one did.
    superseded: Mutex<Option<i64>>,
    /// Whether `register` ran: until then renewals check nothing (the
    /// row is still the previous process's).
    registered: std::sync::atomic::AtomicBool,
    book: Mutex<Book>,
    /// Told of the renewal thread's failures (`ChunkStore::report_to`).
    health: std::sync::OnceLock<Arc<crate::health::Health>>,
}

/// The seq block a node numbers in.
#[derive(Debug, Default, Clone, Copy)]
struct SeqBlock {
    /// The seq below it.
    floor: u64,
    /// Its last seq the engine may hand out: the block's end, or below
    /// it once it was ended early ([`NodeLeases::end_block_at`]).
    last: u64,
    /// Whether the engine has reserved a block (`reserve_seqs`): until then
    /// claims reserve none, the engine's first block is above them all.
    numbering: bool,
}

#[derive(Debug, Default)]
struct Book {
    /// Regions held, by the epoch this node claimed them with.
    held: BTreeMap<RegionId, u64>,
    /// Regions lost, by the epoch this node held them with.
    lost: BTreeMap<RegionId, u64>,
    /// Regions claimed, lost or let go and not yet reported by
    /// [`NodeLeases::take_fresh`].
    fresh: BTreeSet<RegionId>,
    /// When the engine last asked for each held region ([`acquire`]).
    used: BTreeMap<RegionId, Instant>,
    /// Other nodes' regions: holder, address, and until when to believe it.
    elsewhere: BTreeMap<RegionId, (String, String, Instant)>,
    /// Regions seen free ([`holders`]), and until when to believe it.
    free: BTreeMap<RegionId, Instant>,
    /// Other nodes' regions this node asked for ([`want`]), and when.
    asked: BTreeMap<RegionId, Instant>,
    /// Regions a claim found locked by another node's commit, and until
    /// when that is the answer ([`CONTENDED_FOR`]).
    contended: BTreeMap<RegionId, Instant>,
    /// Held regions: until when their lease surely runs (from before the
    /// claim or the last renewal that kept it, plus `lease_ms`). Past it,
    /// with renewals failing (the database out of reach), another node
    /// may hold the region: [`holders`] no longer says `Here`.
    sure_until: BTreeMap<RegionId, Instant>,
}

impl Book {
    /// Keeps at most `most` lost regions. One forgotten may be adopted or
    /// claimed by a commit again: the engine's batches name the epoch they
    /// were built under, so that is refused, not written.
    fn forget_lost_past(&mut self, most: usize) {
        while self.lost.len() > most {
            self.lost.pop_first();
        }
    }
}

impl NodeLeases {
    fn new(cfg: &ClusterConfig) -> Self {
        Self {
            node_id: cfg.node_id.clone(),
            lease_ms: cfg.lease_ms as f64,
            renew: Duration::from_millis(cfg.renew_ms),
            adopt: cfg.adopt,
            max_held: cfg.max_held_regions.max(1),
            release_idle: (cfg.release_idle_ms > 0)
                .then(|| Duration::from_millis(cfg.release_idle_ms.max(cfg.lease_ms))),
            handoff_idle: (cfg.handoff_idle_ms > 0)
                .then(|| Duration::from_millis(cfg.handoff_idle_ms)),
            addr: Mutex::new(cfg.advertise.clone()),
            seqs: Mutex::new(SeqBlock::default()),
            block: cfg.seq_block.max(1),
            next_seq: AtomicU64::new(0),
            incarnation: new_incarnation(),
            superseded: Mutex::new(None),
            registered: std::sync::atomic::AtomicBool::new(false),
            book: Mutex::new(Book::default()),
            health: std::sync::OnceLock::new(),
        }
    }

    /// Tells `health` how the renewal thread's passes go from now on (the
    /// first call counts).
    pub(super) fn report_to(&self, health: Arc<crate::health::Health>) {
        health.expect_every(crate::health::StoreWork::Leases, self.renew);
        let _ = self.health.set(health);
    }

    /// How a renewal pass went: its first failure, if any.
    fn report(&self, pass: &Result<(), StoreError>) {
        if let Some(h) = self.health.get() {
            h.report(crate::health::StoreWork::Leases, pass);
        }
    }

    /// `[cluster] lease_ms` as a duration.
    fn lease(&self) -> Duration {
        Duration::from_secs_f64(self.lease_ms / 1000.0)
    }

    /// Why this process must stop, once another took its node id.
    pub fn superseded(&self) -> Option<String> {
        self.not_superseded().err().map(|e| e.to_string())
    }

    /// Refuses when another process took this node's id.
    pub(super) fn not_superseded(&self) -> Result<(), StoreError> {
        match *self.superseded.lock().unwrap_or_else(|p| p.into_inner()) {
            Some(current) => Err(StoreError::Superseded {
                node_id: self.node_id.clone(),
                mine: self.incarnation,
                current,
            }),
            None => Ok(()),
        }
    }

    fn seq_block(&self) -> SeqBlock {
        *self.seqs.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The seq below this process's current block and the last it may
    /// hand out (one read: a claim may move it to a new block meanwhile).
    /// Before the engine's first block: none is reserved, no end.
    pub fn seq_bounds(&self) -> (u64, u64) {
        let b = self.seq_block();
        match b.numbering {
            true => (b.floor, b.last),
            false => (b.floor, crate::store::MAX_SEQ),
        }
    }

    /// Seqs in each block this process reserves.
    pub(super) fn block_size(&self) -> u64 {
        self.block
    }

    /// How long the lease thread waits for the world row when it reserves
    /// a seq block: half a renewal period, at most a second (a node paused
    /// mid-reservation holds it; renewals come first).
    fn lock_wait(&self) -> Option<Duration> {
        Some((self.renew / 2).min(Duration::from_secs(1)))
    }

    /// The engine numbers its next edit `next` (between ticks).
    pub fn note_next_seq(&self, next: u64) {
        self.next_seq.store(next, Ordering::Release);
    }

    /// Moves to the block above `floor`, unless a newer one was reserved
    /// meanwhile.
    pub(super) fn raise_floor(&self, floor: u64) {
        let mut b = self.seqs.lock().unwrap_or_else(|p| p.into_inner());
        if !b.numbering || floor > b.floor {
            b.floor = floor;
            b.last = floor.saturating_add(self.block);
        }
        b.numbering = true;
    }

    /// Hands out no seq of the current block past `last_used` (a fenced
    /// batch's seqs were abandoned there and no new block could be
    /// reserved: the log may not skip seqs inside a block). Edits wait
    /// until the lease thread reserves the next ([`refill_seqs`]).
    pub(super) fn end_block_at(&self, last_used: u64) {
        let mut b = self.seqs.lock().unwrap_or_else(|p| p.into_inner());
        if b.numbering && last_used > b.floor {
            b.last = b.last.min(last_used);
        }
    }

    /// Regions claimed, lost or let go since the last call, with the
    /// epoch held now (`None`: no longer held).
    pub fn take_fresh(&self) -> Vec<(RegionId, Option<u64>)> {
        let mut book = self.book();
        let fresh = std::mem::take(&mut book.fresh);
        fresh
            .into_iter()
            .map(|r| (r, book.held.get(&r).copied()))
            .collect()
    }

    fn addr(&self) -> String {
        self.addr.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Sets the address written into claimed rows, unless configured.
    pub(super) fn set_addr_if_unset(&self, addr: &str) {
        let mut a = self.addr.lock().unwrap_or_else(|p| p.into_inner());
        if a.is_empty() {
            *a = addr.to_string();
        }
    }

    fn book(&self) -> std::sync::MutexGuard<'_, Book> {
        self.book.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// `[cluster] lease_ms`.
    pub(super) fn lease_ms(&self) -> f64 {
        self.lease_ms
    }

    pub fn node_id(&self) -> &str {
        &self.node_id
    }

    /// `[cluster] max_held_regions`.
    pub fn max_held(&self) -> usize {
        self.max_held
    }

    /// How many regions are held.
    pub fn held_count(&self) -> usize {
        self.book().held.len()
    }

    /// Regions held, with their epochs.
    pub fn held(&self) -> BTreeMap<RegionId, u64> {
        self.book().held.clone()
    }

    /// Regions lost since this process claimed them, with the epochs held.
    pub fn lost(&self) -> BTreeMap<RegionId, u64> {
        self.book().lost.clone()
    }

    /// [`Self::lose`] when `epoch` is the one held: a batch built under an
    /// older epoch says nothing of the lease held now.
    pub(super) fn lose_at(&self, region: RegionId, epoch: Option<u64>) {
        if epoch.is_some() && self.book().held.get(&region) == epoch.as_ref() {
            self.lose(region);
        }
    }

    /// Moves `region` from held to lost (a commit or renewal found its
    /// epoch changed).
    pub(super) fn lose(&self, region: RegionId) {
        let mut book = self.book();
        // What was believed of it before this node held it is stale.
        book.free.remove(&region);
        book.elsewhere.remove(&region);
        book.used.remove(&region);
        if let Some(epoch) = book.held.remove(&region) {
            book.fresh.insert(region);
            warn!(
                node = %self.node_id,
                region_x = region.x,
                region_z = region.z,
                epoch,
                "region lease lost; this node no longer writes it"
            );
            book.lost.insert(region, epoch);
            book.forget_lost_past(self.max_held);
        }
    }
}

/// How long the engine thread's lease statements wait for a row lock.
const LOCK_WAIT: &str = "SET lock_timeout = '100ms'";
/// How long a region found [`RegionAccess::Contended`] is answered so
/// without another try.
const CONTENDED_FOR: Duration = Duration::from_millis(500);

/// Runs `f`, one statement (autocommit: no lock outlives it), waiting at
/// most [`LOCK_WAIT`] for a row lock: a region row another node's commit
/// holds (to its end; a node paused mid-commit, until PostgreSQL ends its
/// session) answers `None` at once instead of holding up the engine
/// thread for seconds. The connection is kept.
fn without_lock_waits<T>(
    pool: &Pool,
    what: &'static str,
    f: impl AsyncFnOnce(&mut Conn) -> Result<T, StoreError>,
) -> Result<Option<T>, StoreError> {
    pool.run(what, async |c: &mut Conn| {
        c.batch(LOCK_WAIT).await?;
        let out = match f(c).await {
            Ok(v) => Some(v),
            Err(StoreError::Postgres(e))
                if e.code() == Some(&tokio_postgres::error::SqlState::LOCK_NOT_AVAILABLE) =>
            {
                None
            }
            Err(e) => return Err(e),
        };
        c.batch("RESET lock_timeout").await?;
        Ok(out)
    })
}

/// Column arrays of regions for `unnest`.
fn columns<'a>(regions: impl Iterator<Item = &'a RegionId>) -> (Vec<i32>, Vec<i32>) {
    regions.map(|r| (r.x, r.z)).unzip()
}

/// One row of the `regions` table, as every node sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegionLease {
    pub region: RegionId,
    /// `None` once released.
    pub owner: Option<String>,
    pub epoch: u64,
    /// Milliseconds until the lease runs out on the database's clock
    /// (negative: expired that long ago).
    pub expires_in_ms: i64,
    /// Milliseconds since the lease was last claimed or renewed.
    pub renewed_ms_ago: i64,
    /// Accepted edits that changed the region, since it was first claimed.
    pub edits: u64,
}

/// Column arrays of held regions and their epochs.
type HeldColumns = (Vec<i32>, Vec<i32>, Vec<i64>);

fn held_columns(held: &BTreeMap<RegionId, u64>) -> Result<HeldColumns, StoreError> {
    let (xs, zs) = columns(held.keys());
    let epochs = held
        .values()
        .map(|&e| super::to_sql(e, "epoch"))
        .collect::<Result<_, _>>()?;
    Ok((xs, zs, epochs))
}

/// Whether a claim may take back a region this process lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Lost {
    /// Never (the commit path: its batch was built on the lost copy).
    Keep,
    /// Yes (the engine, which reloads what it is reported fresh before it
    /// builds on it).
    Retake,
}

/// Claims those of `wanted` that are free, expired or this node's by
/// name, in one statement (rows in key order). Returns what it claimed.
pub(super) fn claim(
    pool: &Pool,
    leases: &NodeLeases,
    wanted: &BTreeSet<RegionId>,
    lost: Lost,
) -> Result<BTreeMap<RegionId, u64>, StoreError> {
    claim_waiting(pool, leases, wanted, (lost, true)).map(|claimed| claimed.unwrap_or_default())
}

/// [`claim`]; without `wait`, `None` when a row lock was not had within
/// [`LOCK_WAIT`] (nothing claimed).
fn claim_waiting(
    pool: &Pool,
    leases: &NodeLeases,
    wanted: &BTreeSet<RegionId>,
    (lost, wait): (Lost, bool),
) -> Result<Option<BTreeMap<RegionId, u64>>, StoreError> {
    leases.not_superseded()?;
    let started = Instant::now();
    let todo: Vec<RegionId> = {
        let book = leases.book();
        wanted
            .iter()
            .filter(|r| {
                !book.held.contains_key(r) && (lost == Lost::Retake || !book.lost.contains_key(r))
            })
            .copied()
            .collect()
    };
    if todo.is_empty() {
        return Ok(Some(BTreeMap::new()));
    }
    let (xs, zs) = columns(todo.iter());
    let addr = leases.addr();
    let statement = async |c: &mut Conn| {
        c.query(
            "INSERT INTO regions AS r (region_x, region_z, owner, epoch, lease_expires, owner_addr) \
             SELECT x, z, $3, 1, now() + $4::float8 * interval '1 millisecond', $5 \
             FROM unnest($1::int4[], $2::int4[]) AS u(x, z) ORDER BY x, z \
             ON CONFLICT (region_x, region_z) DO UPDATE \
             SET owner = EXCLUDED.owner, epoch = r.epoch + 1, owner_addr = EXCLUDED.owner_addr, \
                 lease_expires = EXCLUDED.lease_expires, renewed_at = now(), \
                 wanted_by = NULL, wanted_at = NULL \
             WHERE r.owner IS NULL OR r.owner = EXCLUDED.owner OR r.lease_expires < now() \
             RETURNING region_x, region_z, epoch, last_seq",
            &[&xs, &zs, &leases.node_id, &leases.lease_ms, &addr],
        )
        .await
    };
    let rows = match wait {
        true => pool.run("claiming regions", statement)?,
        false => match without_lock_waits(pool, "claiming regions", statement)? {
            Some(rows) => rows,
            None => return Ok(None),
        },
    };
    took(pool, leases, rows, ("region claimed", None), started).map(Some)
}

/// Books regions a claim or adoption returned (x, z, epoch, last_seq):
/// first a new seq block if one of them was written above this node's
/// block (taking back a region it wrote itself costs none), then held and
/// fresh. When that block cannot be reserved, lets them go again and
/// books none.
/// `started`: before the statement that took them (their leases surely
/// run from then).
/// `lock_wait`: how long its reservation may wait for the world row (the
/// lease thread's: [`NodeLeases::lock_wait`]; the engine's: as long as any
/// statement).
fn took(
    pool: &Pool,
    leases: &NodeLeases,
    rows: Vec<tokio_postgres::Row>,
    (what, lock_wait): (&'static str, Option<Duration>),
    started: Instant,
) -> Result<BTreeMap<RegionId, u64>, StoreError> {
    let mut got = BTreeMap::new();
    let mut newest = 0;
    for r in rows {
        let region = RegionId {
            x: r.get(0),
            z: r.get(1),
        };
        got.insert(region, from_sql(r.get(2), "epoch", show(region))?);
        newest = newest.max(from_sql(r.get(3), "last_seq", show(region))?);
    }
    // Above this node's own block: a node with a newer block wrote there.
    // Within it only this node can have (each block is one node's).
    let own = leases.seq_block();
    if own.numbering && newest > own.floor.saturating_add(leases.block) {
        let next = match seqs::reserve(pool, &leases.node_id, leases.block, lock_wait) {
            Ok(next) => next,
            Err(e) => {
                // Unbooked, they would refuse every other node until
                // their leases ran out.
                match let_go(pool, leases, &got) {
                    Err(e) => {
                        warn!(error = %e, regions = got.len(), "letting go of regions claimed without a seq block failed; their leases run out");
                    }
                    Ok((_, locked)) if !locked.is_empty() => {
                        warn!(regions = locked.len(), "regions claimed without a seq block were locked by another session; their leases run out");
                    }
                    Ok(_) => {}
                }
                return Err(e);
            }
        };
        info!(node = %leases.node_id, first_seq = next + 1, "seq block reserved");
        leases.raise_floor(next);
    }
    let mut book = leases.book();
    let now = Instant::now();
    for (&region, &epoch) in &got {
        info!(node = %leases.node_id, region_x = region.x, region_z = region.z, epoch, "{what}");
        book.used.insert(region, now);
        book.held.insert(region, epoch);
        book.sure_until.insert(region, started + leases.lease());
        book.lost.remove(&region);
        book.fresh.insert(region);
        book.elsewhere.remove(&region);
        book.free.remove(&region);
    }
    Ok(got)
}

/// Reserves the next seq block once the engine, numbering in the current
/// one, has [`seqs::REFILL_PART`] of it or less left: well before its end
/// (past it the engine's edits wait), off the engine's thread, tried again
/// at every renewal while it fails. The rest of the block is left unused.
/// A block ended early ([`NodeLeases::end_block_at`]) is replaced at once.
/// It waits for the world row at most [`NodeLeases::lock_wait`].
fn refill_seqs(pool: &Pool, leases: &NodeLeases) -> Result<(), StoreError> {
    // The engine's seq first: the block read after it is at least as new
    // (a claim that moved it on since leaves `next` below its floor).
    let next = leases.next_seq.load(Ordering::Acquire);
    let own = leases.seq_block();
    if !own.numbering {
        return Ok(());
    }
    // Not numbering in this block yet (a claim just moved it on): it is
    // whole.
    if next <= own.floor {
        return Ok(());
    }
    // Ended early: replaced whatever the engine last told.
    let ended_early = own.last < own.floor.saturating_add(leases.block);
    let left = (own.last + 1).saturating_sub(next);
    if left > leases.block / seqs::REFILL_PART && !ended_early {
        return Ok(());
    }
    let next_floor = seqs::reserve(pool, &leases.node_id, leases.block, leases.lock_wait())?;
    info!(node = %leases.node_id, first_seq = next_floor + 1, left, "seq block reserved");
    leases.raise_floor(next_floor);
    Ok(())
}

/// Claims the regions whose owner let its lease run out (not ones this
/// node lost: its copy of those may be stale), at most
/// [`MAX_ADOPT_PER_RENEWAL`]. Nodes adopting at once skip each other's
/// rows. Returns what it adopted.
pub(super) fn adopt(pool: &Pool, leases: &NodeLeases) -> Result<Vec<RegionId>, StoreError> {
    leases.not_superseded()?;
    let started = Instant::now();
    let (lx, lz, room) = {
        let book = leases.book();
        let (lx, lz) = columns(book.lost.keys());
        (lx, lz, leases.max_held.saturating_sub(book.held.len()))
    };
    let limit = MAX_ADOPT_PER_RENEWAL.min(room as i64);
    if limit == 0 {
        return Ok(Vec::new());
    }
    let addr = leases.addr();
    let rows = pool.run("adopting regions", async |c: &mut Conn| {
        c.query(
            "UPDATE regions AS r SET owner = $1, owner_addr = $2, epoch = r.epoch + 1, \
                 lease_expires = now() + $3::float8 * interval '1 millisecond', renewed_at = now(), \
                 wanted_by = NULL, wanted_at = NULL \
             FROM (SELECT region_x, region_z FROM regions \
                   WHERE owner IS NOT NULL AND owner <> $1 AND lease_expires < now() \
                     AND (region_x, region_z) NOT IN \
                         (SELECT * FROM unnest($4::int4[], $5::int4[])) \
                   ORDER BY region_x, region_z LIMIT $6 FOR UPDATE SKIP LOCKED) AS o \
             WHERE r.region_x = o.region_x AND r.region_z = o.region_z \
             RETURNING r.region_x, r.region_z, r.epoch, r.last_seq",
            &[&leases.node_id, &addr, &leases.lease_ms, &lx, &lz, &limit],
        )
        .await
    })?;
    Ok(took(
        pool,
        leases,
        rows,
        (
            "region adopted from a node whose lease ran out",
            leases.lock_wait(),
        ),
        started,
    )?
    .into_keys()
    .collect())
}

/// Whether this node may write every one of `regions`: claims those free,
/// expired or its own by name (lost ones too: the engine reloads them
/// before use); names the holder of the first it cannot.
pub(super) fn acquire(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeSet<RegionId>,
) -> Result<RegionAccess, StoreError> {
    leases.not_superseded()?;
    let now = Instant::now();
    let todo: BTreeSet<RegionId> = {
        let mut book = leases.book();
        let mut todo = BTreeSet::new();
        for r in regions {
            if book.held.contains_key(r) {
                book.used.insert(*r, now);
                continue;
            }
            if let Some((owner, addr, until)) = book.elsewhere.get(r) {
                if *until > now {
                    return Ok(elsewhere(*r, owner, addr));
                }
            }
            todo.insert(*r);
        }
        let held = book.held.len();
        if held + todo.len() > leases.max_held {
            drop(book);
            return at_capacity(pool, leases, &todo, held);
        }
        todo
    };
    if todo.is_empty() {
        return Ok(RegionAccess::Granted);
    }
    // A row another node's commit holds (a node paused mid-commit holds it
    // until its session is ended) is not waited for on the engine thread,
    // nor tried again for a moment.
    {
        let mut book = leases.book();
        if todo
            .iter()
            .any(|r| book.contended.get(r).is_some_and(|until| *until > now))
        {
            return Ok(RegionAccess::Contended);
        }
        book.contended.retain(|_, until| *until > now);
    }
    if claim_waiting(pool, leases, &todo, (Lost::Retake, false))?.is_none() {
        let mut book = leases.book();
        if book.contended.len() + todo.len() > MAX_CACHED_HOLDERS {
            book.contended.clear();
        }
        for r in &todo {
            book.contended.insert(*r, now + CONTENDED_FOR);
        }
        return Ok(RegionAccess::Contended);
    }
    let Some(&refused) = todo.iter().find(|r| !leases.book().held.contains_key(r)) else {
        return Ok(RegionAccess::Granted);
    };
    let row = pool.run("reading a region's holder", async |c: &mut Conn| {
        c.query_opt(
            "SELECT owner, owner_addr, \
                 GREATEST((extract(epoch FROM lease_expires - now()) * 1000)::int8, 0) \
             FROM regions WHERE region_x = $1 AND region_z = $2",
            &[&refused.x, &refused.z],
        )
        .await
    })?;
    let (owner, addr, left_ms) = match row {
        Some(r) => (
            r.get::<_, Option<String>>(0).unwrap_or_default(),
            r.get::<_, Option<String>>(1).unwrap_or_default(),
            r.get::<_, i64>(2),
        ),
        None => (String::new(), String::new(), 0),
    };
    // Believed until the lease could have run out, and never for longer
    // than a renewal period (a lost region stays refused: it is re-read).
    let until = now + leases.renew.min(Duration::from_millis(left_ms as u64));
    let mut book = leases.book();
    if book.elsewhere.len() >= MAX_CACHED_HOLDERS {
        book.elsewhere.clear();
    }
    book.elsewhere
        .insert(refused, (owner.clone(), addr.clone(), until));
    Ok(elsewhere(refused, &owner, &addr))
}

/// Who writes each of `regions`, claiming nothing: held ones from the
/// book, others from the cache or one query, then cached for at most a
/// renewal period (a live holder no longer than its lease).
pub(super) fn holders(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeSet<RegionId>,
    cache: bool,
) -> Result<Vec<(RegionId, RegionHolder)>, StoreError> {
    let now = Instant::now();
    let mut out = Vec::with_capacity(regions.len());
    let mut todo = Vec::new();
    {
        let book = leases.book();
        for r in regions {
            if book.held.contains_key(r) {
                // Renewals failing past the lease: another node may hold it.
                let sure = book.sure_until.get(r).is_some_and(|until| *until > now);
                out.push((
                    *r,
                    if sure {
                        RegionHolder::Here
                    } else {
                        RegionHolder::Free
                    },
                ));
            } else if let Some((owner, addr, _)) = book
                .elsewhere
                .get(r)
                .filter(|(o, _, until)| *until > now && !o.is_empty())
            {
                let (owner, addr) = (owner.clone(), addr.clone());
                out.push((*r, RegionHolder::Node { owner, addr }));
            } else if book.free.get(r).is_some_and(|until| *until > now) {
                out.push((*r, RegionHolder::Free));
            } else {
                todo.push(*r);
            }
        }
    }
    if !todo.is_empty() {
        let (xs, zs) = columns(todo.iter());
        let rows = pool.run("reading regions' holders", async |c: &mut Conn| {
            c.query(
                "SELECT r.region_x, r.region_z, r.owner, r.owner_addr, \
                     GREATEST((extract(epoch FROM r.lease_expires - now()) * 1000)::int8, 0) \
                 FROM regions r \
                 JOIN unnest($1::int4[], $2::int4[]) AS q(x, z) \
                   ON r.region_x = q.x AND r.region_z = q.z",
                &[&xs, &zs],
            )
            .await
        })?;
        let mut live = BTreeMap::new();
        for row in rows {
            let r = RegionId {
                x: row.get(0),
                z: row.get(1),
            };
            let owner = row.get::<_, Option<String>>(2).unwrap_or_default();
            let addr = row.get::<_, Option<String>>(3).unwrap_or_default();
            let left_ms: i64 = row.get(4);
            // A row under this node's name that it does not hold is a
            // previous run's: free to this node.
            if left_ms > 0 && !owner.is_empty() && owner != leases.node_id {
                live.insert(r, (owner, addr, left_ms as u64));
            }
        }
        if !cache {
            for r in todo {
                out.push(match live.remove(&r) {
                    Some((owner, addr, _)) => (r, RegionHolder::Node { owner, addr }),
                    None => (r, RegionHolder::Free),
                });
            }
            out.sort_by_key(|(r, _)| *r);
            return Ok(out);
        }
        let mut book = leases.book();
        if book.elsewhere.len() >= MAX_CACHED_HOLDERS {
            book.elsewhere.clear();
        }
        if book.free.len() >= MAX_CACHED_HOLDERS {
            book.free.clear();
        }
        for r in todo {
            match live.remove(&r) {
                Some((owner, addr, left_ms)) => {
                    let until = now + leases.renew.min(Duration::from_millis(left_ms));
                    book.elsewhere
                        .insert(r, (owner.clone(), addr.clone(), until));
                    out.push((r, RegionHolder::Node { owner, addr }));
                }
                None => {
                    book.free.insert(r, now + leases.renew);
                    out.push((r, RegionHolder::Free));
                }
            }
        }
    }
    out.sort_by_key(|(r, _)| *r);
    Ok(out)
}

/// [`crate::store::ChunkStore::free_region_marks`]: a region with no row
/// was never claimed (0, 0).
pub(super) fn free_marks(
    pool: &Pool,
    regions: &BTreeSet<RegionId>,
) -> Result<Vec<(RegionId, crate::store::RegionMark)>, StoreError> {
    if regions.is_empty() {
        return Ok(Vec::new());
    }
    let (xs, zs) = columns(regions.iter());
    let rows = pool.run("reading free regions' epochs", async |c: &mut Conn| {
        c.query(
            "SELECT q.x, q.z, COALESCE(r.epoch, 0), COALESCE(r.last_seq, 0) \
             FROM unnest($1::int4[], $2::int4[]) AS q(x, z) \
             LEFT JOIN regions r ON r.region_x = q.x AND r.region_z = q.z \
             WHERE r.region_x IS NULL OR r.owner IS NULL OR r.lease_expires <= now() \
             ORDER BY q.x, q.z",
            &[&xs, &zs],
        )
        .await
    })?;
    rows.iter()
        .map(|row| {
            let region = RegionId {
                x: row.get(0),
                z: row.get(1),
            };
            let epoch = from_sql(row.get(2), "epoch", show(region))?;
            Ok((
                region,
                (epoch, from_sql(row.get(3), "last_seq", show(region))?),
            ))
        })
        .collect()
}

/// A node that may claim no more: names the first of `todo` another node
/// holds (so the edit goes there), else says it is full.
fn at_capacity(
    pool: &Pool,
    leases: &NodeLeases,
    todo: &BTreeSet<RegionId>,
    held: usize,
) -> Result<RegionAccess, StoreError> {
    for (r, h) in holders(pool, leases, todo, true)? {
        if let RegionHolder::Node { owner, addr } = h {
            return Ok(elsewhere(r, &owner, &addr));
        }
    }
    Ok(RegionAccess::AtCapacity {
        held,
        max: leases.max_held,
    })
}

fn elsewhere(region: RegionId, owner: &str, addr: &str) -> RegionAccess {
    RegionAccess::Elsewhere {
        region,
        owner: owner.to_string(),
        addr: addr.to_string(),
    }
}

/// A random incarnation: two processes never share one.
fn new_incarnation() -> i64 {
    use ring::rand::SecureRandom;
    let mut b = [0u8; 8];
    if ring::rand::SystemRandom::new().fill(&mut b).is_err() {
        // No system randomness: the time and the process id still differ
        // between two processes started under one name.
        let t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        b = (t.as_nanos() as u64 ^ (u64::from(std::process::id()) << 40)).to_le_bytes();
    }
    i64::from_le_bytes(b)
}

/// Writes this process's incarnation as its node id's: from now on a
/// previous process still running under the name finds itself superseded
/// at its next renewal.
pub(super) fn register(pool: &Pool, leases: &NodeLeases) -> Result<(), StoreError> {
    pool.run("registering the node", async |c: &mut Conn| {
        c.execute(
            "INSERT INTO nodes (node_id, incarnation) VALUES ($1, $2) \
             ON CONFLICT (node_id) DO UPDATE SET incarnation = EXCLUDED.incarnation, \
                 started_at = now(), seen_at = now()",
            &[&leases.node_id, &leases.incarnation],
        )
        .await
    })?;
    leases.registered.store(true, Ordering::Release);
    info!(node = %leases.node_id, incarnation = leases.incarnation, "node registered");
    Ok(())
}

/// Whether the node id is still this process's: marks it when another
/// process registered since, and refuses from then on.
pub(super) fn check_incarnation(pool: &Pool, leases: &NodeLeases) -> Result<(), StoreError> {
    leases.not_superseded()?;
    if !leases.registered.load(Ordering::Acquire) {
        return Ok(());
    }
    let row = pool.run("checking the node's incarnation", async |c: &mut Conn| {
        c.query_opt(
            "UPDATE nodes SET seen_at = now() WHERE node_id = $1 \
             RETURNING incarnation",
            &[&leases.node_id],
        )
        .await
    })?;
    let current = match row {
        Some(r) => r.get::<_, i64>(0),
        // No row (a database restored from a dump, say): written again,
        // unless another process got there first.
        None => {
            let row = pool.run("registering the node again", async |c: &mut Conn| {
                c.query_opt(
                    "INSERT INTO nodes (node_id, incarnation) VALUES ($1, $2) \
                     ON CONFLICT (node_id) DO UPDATE SET node_id = EXCLUDED.node_id \
                     RETURNING incarnation",
                    &[&leases.node_id, &leases.incarnation],
                )
                .await
            })?;
            match row {
                Some(r) => r.get::<_, i64>(0),
                None => return Ok(()),
            }
        }
    };
    if current == leases.incarnation {
        return Ok(());
    }
    *leases.superseded.lock().unwrap_or_else(|p| p.into_inner()) = Some(current);
    let e = leases.not_superseded();
    if let Err(e) = &e {
        tracing::error!(error = %e, "this node's id was taken over");
    }
    e
}

/// Extends every lease still this node's at the epoch it holds; those
/// whose owner or epoch changed are lost. Returns the regions lost now.
/// A row another transaction has locked (this node's commit, whose fence
/// extends the lease itself) is skipped, not waited for: a slow commit
/// must not hold up the renewal of every other region until their leases
/// run out. It is lost only if it is no longer this node's as committed.
pub(super) fn renew(pool: &Pool, leases: &NodeLeases) -> Result<Vec<RegionId>, StoreError> {
    let started = Instant::now();
    let held = leases.held();
    if held.is_empty() {
        return Ok(Vec::new());
    }
    let (xs, zs, epochs) = held_columns(&held)?;
    let addr = leases.addr();
    let region_of = |r: &tokio_postgres::Row| RegionId {
        x: r.get(0),
        z: r.get(1),
    };
    let rows = pool.run("renewing leases", async |c: &mut Conn| {
        c.query(
            "WITH mine AS (SELECT r.region_x, r.region_z FROM regions r \
                 JOIN unnest($1::int4[], $2::int4[], $3::int8[]) AS u(x, z, e) \
                   ON r.region_x = u.x AND r.region_z = u.z AND r.epoch = u.e \
                 WHERE r.owner = $4 \
                 ORDER BY r.region_x, r.region_z FOR UPDATE OF r SKIP LOCKED) \
             UPDATE regions AS r \
                 SET lease_expires = clock_timestamp() + $5::float8 * interval '1 millisecond', \
                 renewed_at = clock_timestamp(), owner_addr = $6 \
             FROM mine WHERE r.region_x = mine.region_x AND r.region_z = mine.region_z \
             RETURNING r.region_x, r.region_z",
            &[&xs, &zs, &epochs, &leases.node_id, &leases.lease_ms, &addr],
        )
        .await
    })?;
    let renewed = started + leases.lease();
    // Each region kept, with until when its lease surely runs.
    let mut still: BTreeMap<RegionId, Instant> =
        rows.iter().map(|r| (region_of(r), renewed)).collect();
    if still.len() < held.len() {
        // Those skipped (locked): this node's still, as last committed, and
        // not run out (a commit that held one too long and then failed did
        // not extend it)? Sure only for the lease they have left: the
        // commit holding them may yet fail.
        let asked = Instant::now();
        let rows = pool.run("reading leases being committed", async |c: &mut Conn| {
            c.query(
                "SELECT r.region_x, r.region_z, \
                     (extract(epoch FROM r.lease_expires - clock_timestamp()) * 1000)::int8 \
                 FROM regions r \
                 JOIN unnest($1::int4[], $2::int4[], $3::int8[]) AS u(x, z, e) \
                   ON r.region_x = u.x AND r.region_z = u.z AND r.epoch = u.e \
                 WHERE r.owner = $4 AND r.lease_expires > clock_timestamp()",
                &[&xs, &zs, &epochs, &leases.node_id],
            )
            .await
        })?;
        for r in &rows {
            let left = Duration::from_millis(r.get::<_, i64>(2).max(0) as u64);
            still.insert(region_of(r), asked + left);
        }
    }
    let lost: Vec<RegionId> = held
        .keys()
        .filter(|r| !still.contains_key(r))
        .copied()
        .collect();
    {
        let mut book = leases.book();
        for (r, sure) in &still {
            book.sure_until.insert(*r, *sure);
        }
    }
    // At the epoch this pass renewed: a region let go and claimed again
    // meanwhile (a newer epoch) is held still.
    for &r in &lost {
        leases.lose_at(r, held.get(&r).copied());
    }
    let mut book = leases.book();
    let Book {
        held, sure_until, ..
    } = &mut *book;
    sure_until.retain(|r, _| held.contains_key(r));
    Ok(lost)
}

/// Gives up those of `regions` this node holds (a claim made for an edit
/// that was then refused); each is reported fresh. Returns how many.
pub(super) fn release_some(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeSet<RegionId>,
) -> Result<u64, StoreError> {
    let mut used_at = BTreeMap::new();
    let gone: BTreeMap<RegionId, u64> = {
        let mut book = leases.book();
        let mut gone = BTreeMap::new();
        for r in regions {
            if let Some(epoch) = book.held.remove(r) {
                if let Some(at) = book.used.remove(r) {
                    used_at.insert(*r, at);
                }
                book.fresh.insert(*r);
                gone.insert(*r, epoch);
            }
        }
        gone
    };
    Ok(let_go_or_keep(pool, leases, &gone, &used_at)?.len() as u64)
}

/// Gives up every lease still this node's (owner set to NULL, epoch
/// kept): another node may claim them at once. Returns how many.
pub(super) fn release(pool: &Pool, leases: &NodeLeases) -> Result<u64, StoreError> {
    let held = {
        let mut book = leases.book();
        book.used.clear();
        std::mem::take(&mut book.held)
    };
    let (released, locked) = let_go(pool, leases, &held)?;
    if !locked.is_empty() {
        warn!(node = %leases.node_id, regions = locked.len(),
            "region rows another session holds were not let go; their leases run out");
    }
    let n = released.len() as u64;
    let mut book = leases.book();
    book.lost.extend(held);
    book.forget_lost_past(leases.max_held);
    Ok(n)
}

/// Sets the owner of `regions` to NULL where this node still holds them
/// at those epochs; returns those it let go (not one claimed again since)
/// and those whose rows another session holds locked (a node paused in
/// its commit): skipped, never waited for, still this node's.
fn let_go(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeMap<RegionId, u64>,
) -> Result<(BTreeSet<RegionId>, BTreeSet<RegionId>), StoreError> {
    let (mut released, mut locked) = (BTreeSet::new(), BTreeSet::new());
    if regions.is_empty() {
        return Ok((released, locked));
    }
    let (xs, zs, epochs) = held_columns(regions)?;
    // The last part reads the statement's snapshot: rows still this
    // node's that `mine` did not lock were skipped.
    let rows = pool.run("releasing leases", async |c: &mut Conn| {
        c.query(
            "WITH asked AS (SELECT r.region_x, r.region_z FROM regions r \
                 JOIN unnest($1::int4[], $2::int4[], $3::int8[]) AS u(x, z, e) \
                   ON r.region_x = u.x AND r.region_z = u.z AND r.epoch = u.e \
                 WHERE r.owner = $4), \
             mine AS (SELECT r.region_x, r.region_z FROM regions r \
                 JOIN asked a ON r.region_x = a.region_x AND r.region_z = a.region_z \
                 WHERE r.owner = $4 \
                 ORDER BY r.region_x, r.region_z FOR UPDATE OF r SKIP LOCKED), \
             gone AS (UPDATE regions AS r SET owner = NULL \
                 FROM mine WHERE r.region_x = mine.region_x AND r.region_z = mine.region_z \
                 RETURNING r.region_x, r.region_z) \
             SELECT region_x, region_z, true FROM gone \
             UNION ALL \
             SELECT a.region_x, a.region_z, false FROM asked a WHERE NOT EXISTS \
                 (SELECT 1 FROM mine m WHERE m.region_x = a.region_x AND m.region_z = a.region_z)",
            &[&xs, &zs, &epochs, &leases.node_id],
        )
        .await
    })?;
    for r in rows {
        let region = RegionId {
            x: r.get(0),
            z: r.get(1),
        };
        if r.get::<_, bool>(2) {
            released.insert(region);
        } else {
            locked.insert(region);
        }
    }
    Ok((released, locked))
}

/// [`let_go`] of regions already taken out of the book (`used_at`: when
/// each was last used). Those it could not let go (their rows locked by
/// another session, or the database out of reach) go back into it at
/// their epoch, unless claimed again meanwhile, and are reported fresh
/// again: renewals keep them and a later pass lets them go, where their
/// rows would otherwise stay leased to this node, unrenewed and refusing
/// every other node, until they ran out.
fn let_go_or_keep(
    pool: &Pool,
    leases: &NodeLeases,
    gone: &BTreeMap<RegionId, u64>,
    used_at: &BTreeMap<RegionId, Instant>,
) -> Result<BTreeSet<RegionId>, StoreError> {
    let keep = |which: &mut dyn Iterator<Item = &RegionId>| {
        let mut book = leases.book();
        for r in which {
            let Some(&epoch) = gone.get(r) else {
                continue;
            };
            if book.held.contains_key(r) {
                continue;
            }
            book.held.insert(*r, epoch);
            book.fresh.insert(*r);
            if let Some(at) = used_at.get(r) {
                book.used.insert(*r, *at);
            }
        }
    };
    match let_go(pool, leases, gone) {
        Ok((released, locked)) => {
            if !locked.is_empty() {
                warn!(node = %leases.node_id, regions = locked.len(),
                    "region rows another session holds were kept; a later pass lets them go");
                keep(&mut locked.iter());
            }
            Ok(released)
        }
        Err(e) => {
            keep(&mut gone.keys());
            Err(e)
        }
    }
}

/// Releases the held regions the engine has not asked for in
/// `release_idle_ms`, and past half of `max_held_regions` those idle for
/// a whole lease, least recently used first, down to half. They leave the
/// book first, so an edit meanwhile claims them anew (a new epoch, which
/// the release then no longer matches). Returns those released.
pub(super) fn release_idle(pool: &Pool, leases: &NodeLeases) -> Result<Vec<RegionId>, StoreError> {
    let keep = leases.max_held / 2;
    let idle_for = Duration::from_secs_f64(leases.lease_ms / 1000.0);
    let mut used_at = BTreeMap::new();
    let gone: BTreeMap<RegionId, u64> = {
        let mut book = leases.book();
        if book.held.len() <= keep && leases.release_idle.is_none() {
            return Ok(Vec::new());
        }
        let now = Instant::now();
        let mut idle: Vec<(Instant, RegionId)> = book
            .used
            .iter()
            .filter(|(_, &at)| now.saturating_duration_since(at) >= idle_for)
            .map(|(&r, &at)| (at, r))
            .collect();
        idle.sort();
        // Oldest first: those idle past `release_idle` are a prefix.
        let stale = leases.release_idle.map_or(0, |d| {
            idle.partition_point(|(at, _)| now.saturating_duration_since(*at) >= d)
        });
        let over = book.held.len().saturating_sub(keep).max(stale);
        let mut gone = BTreeMap::new();
        for (at, r) in idle.into_iter().take(over) {
            book.used.remove(&r);
            if let Some(epoch) = book.held.remove(&r) {
                book.fresh.insert(r);
                gone.insert(r, epoch);
                used_at.insert(r, at);
            }
        }
        let idle = gone.len().min(stale);
        let counter = |why: &'static str, n: usize| {
            metrics::counter!(crate::metrics::REGIONS_RELEASED, "why" => why).increment(n as u64)
        };
        counter("idle", idle);
        counter("cap", gone.len() - idle);
        gone
    };
    let_go_or_keep(pool, leases, &gone, &used_at)?;
    for r in gone.keys() {
        info!(node = %leases.node_id, region_x = r.x, region_z = r.z, "idle region released");
    }
    Ok(gone.into_keys().collect())
}

/// Asks the holders of `regions` (other nodes') to hand them over: an edit
/// this node must apply reaches into them. Each region is asked for at
/// most once a renewal period; the ask counts two renewal periods.
pub(super) fn want(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeSet<RegionId>,
) -> Result<(), StoreError> {
    leases.not_superseded()?;
    let now = Instant::now();
    let todo: Vec<RegionId> = {
        let mut book = leases.book();
        let todo: Vec<RegionId> = regions
            .iter()
            .filter(|r| {
                !book.held.contains_key(r)
                    && book
                        .asked
                        .get(r)
                        .is_none_or(|at| now.saturating_duration_since(*at) >= leases.renew)
            })
            .copied()
            .collect();
        if book.asked.len() + todo.len() > MAX_CACHED_HOLDERS {
            book.asked.clear();
        }
        for r in &todo {
            book.asked.insert(*r, now);
        }
        todo
    };
    if todo.is_empty() {
        return Ok(());
    }
    let (xs, zs) = columns(todo.iter());
    let asked = without_lock_waits(pool, "asking for regions", async |c: &mut Conn| {
        c.execute(
            "UPDATE regions AS r SET wanted_by = $3, wanted_at = now() \
             FROM unnest($1::int4[], $2::int4[]) AS u(x, z) \
             WHERE r.region_x = u.x AND r.region_z = u.z \
               AND r.owner IS NOT NULL AND r.owner <> $3",
            &[&xs, &zs, &leases.node_id],
        )
        .await
    });
    // Their holder is committing (or paused mid-commit): asked again at a
    // later edit.
    if asked?.is_none() {
        let mut book = leases.book();
        for r in &todo {
            book.asked.remove(r);
        }
        return Ok(());
    }
    for r in &todo {
        info!(node = %leases.node_id, region_x = r.x, region_z = r.z, "region asked for");
    }
    Ok(())
}

/// Lets go of the held regions another node asked for within two renewal
/// periods that this node's edits have left alone for `handoff_idle_ms`
/// (they leave the book first, as in [`release_idle`]). Returns those
/// handed over.
pub(super) fn hand_over(pool: &Pool, leases: &NodeLeases) -> Result<Vec<RegionId>, StoreError> {
    let Some(quiet) = leases.handoff_idle else {
        return Ok(Vec::new());
    };
    if leases.book().held.is_empty() {
        return Ok(Vec::new());
    }
    // An ask counts two renewal periods: the asking node asks again once
    // a period while its player still tries, so one whose player left
    // moves no region.
    let fresh_ms = leases.renew.as_secs_f64() * 2_000.0;
    let rows = pool.run("reading regions asked for", async |c: &mut Conn| {
        c.query(
            "SELECT region_x, region_z, wanted_by FROM regions \
             WHERE owner = $1 AND wanted_by IS NOT NULL AND wanted_by <> $1 \
               AND wanted_at > now() - $2::float8 * interval '1 millisecond'",
            &[&leases.node_id, &fresh_ms],
        )
        .await
    })?;
    let now = Instant::now();
    let mut to = BTreeMap::new();
    let mut used_at = BTreeMap::new();
    let gone: BTreeMap<RegionId, u64> = {
        let mut book = leases.book();
        let mut gone = BTreeMap::new();
        for row in rows {
            let r = RegionId {
                x: row.get(0),
                z: row.get(1),
            };
            let busy = book
                .used
                .get(&r)
                .is_some_and(|at| now.saturating_duration_since(*at) < quiet);
            if busy {
                continue;
            }
            if let Some(epoch) = book.held.remove(&r) {
                if let Some(at) = book.used.remove(&r) {
                    used_at.insert(r, at);
                }
                book.fresh.insert(r);
                gone.insert(r, epoch);
                to.insert(r, row.get::<_, String>(2));
            }
        }
        gone
    };
    if gone.is_empty() {
        return Ok(Vec::new());
    }
    // One an edit here claimed again meanwhile stays.
    let released = let_go_or_keep(pool, leases, &gone, &used_at)?;
    metrics::counter!(crate::metrics::REGIONS_RELEASED, "why" => "handoff")
        .increment(released.len() as u64);
    for r in &released {
        let asker = to.get(r).map_or("", String::as_str);
        info!(node = %leases.node_id, region_x = r.x, region_z = r.z, to = %asker, "region handed over");
    }
    Ok(released.into_iter().collect())
}

/// A region as error messages and logs name it.
pub(super) fn show(r: RegionId) -> String {
    format!("region ({}, {})", r.x, r.z)
}

#[derive(Debug, Default)]
struct Stop {
    flag: Mutex<bool>,
    wake: Condvar,
}

/// The thread that renews this node's leases every `renew_ms`, on a
/// connection of its own; stopped and joined on drop.
#[derive(Debug)]
pub(super) struct Renewer {
    stop: Arc<Stop>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl Renewer {
    fn spawn(pool: Arc<Pool>, leases: Arc<NodeLeases>, every: Duration) -> std::io::Result<Self> {
        let stop = Arc::new(Stop::default());
        let flag = stop.clone();
        let thread = std::thread::Builder::new()
            .name("strata-leases".into())
            .spawn(move || {
                let mut stopped = flag.flag.lock().unwrap_or_else(|p| p.into_inner());
                while !*stopped {
                    stopped = flag
                        .wake
                        .wait_timeout(stopped, every)
                        .unwrap_or_else(|p| p.into_inner())
                        .0;
                    if *stopped {
                        break;
                    }
                    drop(stopped);
                    let mut pass = Ok(());
                    if let Err(e) = check_incarnation(&pool, &leases) {
                        if leases.superseded().is_some() {
                            // The engine stops at its next tick.
                            break;
                        }
                        warn!(error = %e, "checking the node's incarnation failed; retrying");
                        pass = pass.and(Err(e));
                    }
                    if let Err(e) = renew(&pool, &leases) {
                        warn!(error = %e, "renewing region leases failed; retrying");
                        pass = pass.and(Err(e));
                    }
                    if let Err(e) = hand_over(&pool, &leases) {
                        warn!(error = %e, "handing regions over failed");
                        pass = pass.and(Err(e));
                    }
                    if let Err(e) = release_idle(&pool, &leases) {
                        warn!(error = %e, "releasing idle regions failed");
                        pass = pass.and(Err(e));
                    }
                    // A process still starting adopts nothing: its start
                    // may fail, and it has no address to name yet.
                    if leases.adopt && leases.registered.load(Ordering::Acquire) {
                        if let Err(e) = adopt(&pool, &leases) {
                            warn!(error = %e, "adopting expired regions failed; retrying");
                            pass = pass.and(Err(e));
                        }
                    }
                    leases.report(&pass);
                    // Not a lease failure: the node's block has a quarter
                    // left, or its edits wait (counted and logged apart).
                    if let Err(e) = refill_seqs(&pool, &leases) {
                        let what =
                            "reserving the next seq block failed; trying again at the next renewal";
                        crate::log_every::store_error("seqs", what, &e);
                    }
                    stopped = flag.flag.lock().unwrap_or_else(|p| p.into_inner());
                }
            })?;
        Ok(Self {
            stop,
            thread: Mutex::new(Some(thread)),
        })
    }

    /// Stops the thread and waits for it: a pass under way (which may adopt
    /// regions) ends first. Later calls do nothing.
    pub(super) fn stop(&self) {
        *self.stop.flag.lock().unwrap_or_else(|p| p.into_inner()) = true;
        self.stop.wake.notify_all();
        let thread = self.thread.lock().unwrap_or_else(|p| p.into_inner()).take();
        if let Some(t) = thread {
            let _ = t.join();
        }
    }
}

impl Drop for Renewer {
    fn drop(&mut self) {
        self.stop();
    }
}

impl PgStore {
    /// [`PgStore::open`] for one node of a cluster: commits are fenced by
    /// the leases this node holds, claimed as it first writes a region (or
    /// by [`PgStore::claim_regions`]) and renewed every `renew_ms`.
    pub fn open_node(
        cfg: &super::PgConfig,
        region_chunks: u32,
        cluster: &ClusterConfig,
    ) -> Result<Self, StoreError> {
        cluster
            .check()
            .map_err(|(field, reason)| StoreError::PgSetup {
                reason: format!("{field} {reason}"),
            })?;
        // A transaction left open by a paused node is rolled back by the
        // server within the lease, so it never holds a takeover up.
        let idle = Duration::from_millis(cluster.lease_ms.min(cfg.statement_timeout_ms));
        let mut store = Self::open_on(
            Pool::open_idle(cfg, idle)?,
            region_chunks,
            super::migrate::Migrator::Server,
        )?;
        let leases = Arc::new(NodeLeases::new(cluster));
        // A connection of its own: renewals never wait behind commits or
        // scans for a pooled one. Its transactions (a seq block's
        // reservation) are ended within the lease too when it is paused.
        let renewals = Pool::open_idle(
            &super::PgConfig {
                max_connections: 1,
                ..cfg.clone()
            },
            idle,
        )?;
        store.renewer = Some(Renewer::spawn(
            Arc::new(renewals),
            leases.clone(),
            Duration::from_millis(cluster.renew_ms),
        )?);
        store.leases = Some(leases);
        Ok(store)
    }

    /// This node's leases; `None` when the store is not fenced (no `[cluster]`).
    pub fn leases(&self) -> Option<&NodeLeases> {
        self.leases.as_deref()
    }

    /// Claims those of `regions` that are free or expired; returns every
    /// one of them this node now holds, with its epoch.
    pub fn claim_regions(
        &self,
        regions: &[RegionId],
    ) -> Result<BTreeMap<RegionId, u64>, StoreError> {
        let leases = self.cluster_leases()?;
        let wanted: BTreeSet<RegionId> = regions.iter().copied().collect();
        claim(&self.pool, leases, &wanted, Lost::Keep)?;
        let held = leases.held();
        Ok(held
            .into_iter()
            .filter(|(r, _)| wanted.contains(r))
            .collect())
    }

    /// Adopts now what the renewal thread adopts every `renew_ms`: regions
    /// whose owner let the lease run out.
    pub fn adopt_regions(&self) -> Result<Vec<RegionId>, StoreError> {
        adopt(&self.pool, self.cluster_leases()?)
    }

    /// Renews now (the renewal thread does it every `renew_ms`); returns
    /// the regions found lost.
    pub fn renew_leases(&self) -> Result<Vec<RegionId>, StoreError> {
        let leases = self.cluster_leases()?;
        check_incarnation(&self.pool, leases)?;
        renew(&self.pool, leases)
    }

    /// Releases every lease held (at shutdown, after the last commit).
    pub fn release_leases(&self) -> Result<u64, StoreError> {
        release(&self.pool, self.cluster_leases()?)
    }

    /// Releases now what the renewal thread releases every `renew_ms`:
    /// past half of `max_held_regions`, the regions idle for a lease.
    pub fn release_idle_regions(&self) -> Result<Vec<RegionId>, StoreError> {
        release_idle(&self.pool, self.cluster_leases()?)
    }

    /// Hands over now what the renewal thread hands over every
    /// `renew_ms`: regions other nodes asked for, left alone here for
    /// `handoff_idle_ms`.
    pub fn hand_over_regions(&self) -> Result<Vec<RegionId>, StoreError> {
        hand_over(&self.pool, self.cluster_leases()?)
    }

    /// Every region ever claimed, in key order.
    pub fn region_leases(&self) -> Result<Vec<RegionLease>, StoreError> {
        let rows = self
            .pool
            .run("reading region leases", async |c: &mut Conn| {
                c.query(
                    "SELECT region_x, region_z, owner, epoch, \
                 (extract(epoch FROM lease_expires - now()) * 1000)::int8, \
                 (extract(epoch FROM now() - renewed_at) * 1000)::int8, edits \
                 FROM regions ORDER BY region_x, region_z",
                    &[],
                )
                .await
            })?;
        rows.iter()
            .map(|r| {
                let region = RegionId {
                    x: r.get(0),
                    z: r.get(1),
                };
                Ok(RegionLease {
                    region,
                    owner: r.get(2),
                    epoch: from_sql(r.get(3), "epoch", show(region))?,
                    expires_in_ms: r.get(4),
                    renewed_ms_ago: r.get(5),
                    edits: from_sql(r.get(6), "edits", show(region))?,
                })
            })
            .collect()
    }

    fn cluster_leases(&self) -> Result<&NodeLeases, StoreError> {
        self.leases.as_deref().ok_or_else(|| StoreError::PgSetup {
            reason: "this store was opened without [cluster]: it holds no leases".into(),
        })
    }
}
