//! `[cluster]`: this node's name and its lease timing.

use serde::{Deserialize, Serialize};

/// How long a claim or renewal keeps a region this node's. A node paused or
/// cut off longer than this loses its regions to the first node that claims
/// them; takeover after a crash waits at most this long.
pub const DEFAULT_LEASE_MS: u64 = 10_000;
/// How often the node renews its leases: a fifth of the default lease, so a
/// few renewals may fail before a lease runs out.
pub const DEFAULT_RENEW_MS: u64 = 2_000;
/// Shortest allowed lease (a tick's commit must fit well inside it).
pub const MIN_LEASE_MS: u64 = 200;
/// Longest allowed lease.
pub const MAX_LEASE_MS: u64 = 600_000;
/// Shortest allowed renewal period.
pub const MIN_RENEW_MS: u64 = 20;
/// Longest node name.
pub const MAX_NODE_ID_LEN: usize = 64;
/// Longest `advertise` address.
pub const MAX_ADVERTISE_LEN: usize = 255;
/// Regions one node holds at most by default (players claim them by
/// editing; regions idle for a lease are let go past half of it).
pub const DEFAULT_MAX_HELD_REGIONS: usize = 16_384;
/// Largest allowed `max_held_regions`.
pub const MAX_HELD_REGIONS_CAP: usize = 1 << 20;
/// How long a region may go unedited before its node lets it go, however
/// few it holds: the next edit there claims it for whichever node it is
/// sent to, so regions follow the players across the nodes.
pub const DEFAULT_RELEASE_IDLE_MS: u64 = 600_000;
/// Longest allowed `release_idle_ms` (a week).
pub const MAX_RELEASE_IDLE_MS: u64 = 7 * 24 * 3_600_000;
/// How long this node's players must leave a region unedited before the
/// node hands it to another node that asked for it (an edit there reached
/// across the border into it): a border edit waits that long at most
/// while the other side is quiet, and a region busy on both sides does not
/// change hands back and forth faster.
pub const DEFAULT_HANDOFF_IDLE_MS: u64 = 3_000;
/// Shortest allowed `handoff_idle_ms` but 0: a region whose players edit
/// it every second or so is not handed back and forth.
pub const MIN_HANDOFF_IDLE_MS: u64 = 1_000;
/// Longest allowed `handoff_idle_ms`.
pub const MAX_HANDOFF_IDLE_MS: u64 = 3_600_000;
/// Players' stored positions read at once by logins (each read holds one
/// of the store's `[store.postgres] max_connections`, 8 by default): well
/// under the pool, so a login storm leaves commits, chunk loads and
/// claims their connections.
pub const DEFAULT_POSITION_READS: usize = 2;
/// Seqs a node reserves at once (`store/pg/seqs.rs`): one `UPDATE` of
/// the world row and a `seq_blocks` row per block. A node takes a new one
/// when a quarter of its block is left (the quarter goes unused), and
/// whenever it takes a region last written from a newer block: blocks are
/// spent on handoffs too, so they are small, and 2^39 of them fit below
/// 2^63. At 10,000 edits a second a block lasts about 21 minutes.
pub const DEFAULT_SEQ_BLOCK: u64 = 1 << 24;
/// Smallest allowed `seq_block` (for tests: a small block costs a row and
/// a wait for the lease thread every few edits). A tick hands out at most
/// what its block has left, the rest of its edits waiting for the next
/// block; it never numbers past one.
pub const MIN_SEQ_BLOCK: u64 = 64;
/// Largest allowed `seq_block`.
pub const MAX_SEQ_BLOCK: u64 = 1 << 40;
/// Largest allowed `position_reads` (the pool's own cap; at most
/// `[store.postgres] max_connections - 1` are used, see
/// [`ClusterConfig::position_reads_with`]).
pub const MAX_POSITION_READS: usize = 256;
/// How long a login waits for a position read (its turn among
/// `position_reads`, then the read) before it is refused, retryable
/// (`TooManyConnections`). Well inside a client's wait for `Welcome` (10 s
/// in strata-client).
pub const DEFAULT_POSITION_READ_MS: u64 = 3_000;
/// Longest allowed `position_read_ms`.
pub const MAX_POSITION_READ_MS: u64 = 60_000;

/// The `[cluster]` section. Without it a node on PostgreSQL takes no leases
/// and its commits are not fenced: it must be the only one on its database.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ClusterConfig {
    /// This node's name in the `regions` table: unique in the cluster. A
    /// node restarted under the same name takes its regions back at once
    /// (fencing its previous process).
    pub node_id: String,
    /// See [`DEFAULT_LEASE_MS`].
    pub lease_ms: u64,
    /// See [`DEFAULT_RENEW_MS`]; at most half of `lease_ms`.
    pub renew_ms: u64,
    /// The address clients reach this node at (`host:port`), named to a
    /// client whose edit lands in a region this node does not hold. Empty:
    /// the address the node is bound to.
    pub advertise: String,
    /// Whether every renewal also takes over regions whose owner let its
    /// lease run out (a crashed node's), so they are not left unowned
    /// until a client edits them.
    pub adopt: bool,
    /// Regions held at once: an edit that would claim more is refused
    /// (`NodeFull`), and nothing more is adopted. Past half of it, each
    /// renewal releases the regions no edit asked for in a whole lease,
    /// least recently used first, down to half.
    pub max_held_regions: usize,
    /// See [`DEFAULT_RELEASE_IDLE_MS`]; 0 keeps every region until
    /// `max_held_regions` presses, else at least `lease_ms`.
    pub release_idle_ms: u64,
    /// See [`DEFAULT_HANDOFF_IDLE_MS`]; 0 (or [`MIN_HANDOFF_IDLE_MS`]
    /// ..=[`MAX_HANDOFF_IDLE_MS`]). 0 never hands a region over (an
    /// edit reaching into another node's region is then refused for as
    /// long as that node holds it).
    pub handoff_idle_ms: u64,
    /// Logins reading their player's stored position at once (see
    /// [`DEFAULT_POSITION_READS`]); the others wait their turn. At least
    /// 1, and below `[store.postgres] max_connections`.
    pub position_reads: usize,
    /// See [`DEFAULT_POSITION_READ_MS`]: a login whose read has not
    /// begun and ended in this long is refused (as is one whose read
    /// failed), never let in unplaced.
    pub position_read_ms: u64,
    /// See [`DEFAULT_SEQ_BLOCK`]: [`MIN_SEQ_BLOCK`]..=[`MAX_SEQ_BLOCK`].
    pub seq_block: u64,
}

impl Default for ClusterConfig {
    fn default() -> Self {
        Self {
            node_id: String::new(),
            lease_ms: DEFAULT_LEASE_MS,
            renew_ms: DEFAULT_RENEW_MS,
            advertise: String::new(),
            adopt: true,
            max_held_regions: DEFAULT_MAX_HELD_REGIONS,
            release_idle_ms: DEFAULT_RELEASE_IDLE_MS,
            handoff_idle_ms: DEFAULT_HANDOFF_IDLE_MS,
            position_reads: DEFAULT_POSITION_READS,
            position_read_ms: DEFAULT_POSITION_READ_MS,
            seq_block: DEFAULT_SEQ_BLOCK,
        }
    }
}

impl ClusterConfig {
    /// The first bad field and why.
    pub fn check(&self) -> Result<(), (&'static str, String)> {
        let id = &self.node_id;
        if id.is_empty() || id.len() > MAX_NODE_ID_LEN {
            return Err((
                "cluster.node_id",
                format!("must be 1..={MAX_NODE_ID_LEN} characters"),
            ));
        }
        if !id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err((
                "cluster.node_id",
                format!("{id:?} may hold only ASCII letters, digits, '-', '_' and '.'"),
            ));
        }
        if !(MIN_LEASE_MS..=MAX_LEASE_MS).contains(&self.lease_ms) {
            return Err((
                "cluster.lease_ms",
                format!(
                    "{} is outside {MIN_LEASE_MS}..={MAX_LEASE_MS}",
                    self.lease_ms
                ),
            ));
        }
        if self.advertise.len() > MAX_ADVERTISE_LEN
            || self.advertise.chars().any(|c| c.is_control() || c == ' ')
        {
            return Err((
                "cluster.advertise",
                format!("must be at most {MAX_ADVERTISE_LEN} characters, without spaces"),
            ));
        }
        within(
            "cluster.max_held_regions",
            self.max_held_regions,
            1,
            MAX_HELD_REGIONS_CAP,
        )?;
        let idle = self.release_idle_ms;
        if idle != 0 && !(self.lease_ms..=MAX_RELEASE_IDLE_MS).contains(&idle) {
            return Err((
                "cluster.release_idle_ms",
                format!(
                    "{idle} is neither 0 nor within {}..={MAX_RELEASE_IDLE_MS} (cluster.lease_ms up to a week)",
                    self.lease_ms
                ),
            ));
        }
        if self.handoff_idle_ms != 0 {
            within(
                "cluster.handoff_idle_ms",
                self.handoff_idle_ms,
                MIN_HANDOFF_IDLE_MS,
                MAX_HANDOFF_IDLE_MS,
            )?;
        }
        within(
            "cluster.position_reads",
            self.position_reads,
            1,
            MAX_POSITION_READS,
        )?;
        within(
            "cluster.position_read_ms",
            self.position_read_ms,
            1,
            MAX_POSITION_READ_MS,
        )?;
        within(
            "cluster.seq_block",
            self.seq_block,
            MIN_SEQ_BLOCK,
            MAX_SEQ_BLOCK,
        )?;
        let most = self.lease_ms / 2;
        if !(MIN_RENEW_MS..=most).contains(&self.renew_ms) {
            return Err((
                "cluster.renew_ms",
                format!(
                    "{} is outside {MIN_RENEW_MS}..={most} (half of cluster.lease_ms)",
                    self.renew_ms
                ),
            ));
        }
        Ok(())
    }
}

impl ClusterConfig {
    /// The position reads a node runs at once with a pool of `pool`
    /// connections: `position_reads`, leaving the commits, chunk loads and
    /// claims at least one connection (a pool of one shares it).
    pub fn position_reads_with(&self, pool: usize) -> usize {
        self.position_reads.min(pool.saturating_sub(1)).max(1)
    }
}

/// `Err((field, why))` unless `lo <= v <= hi`.
fn within<T: PartialOrd + std::fmt::Display>(
    field: &'static str,
    v: T,
    lo: T,
    hi: T,
) -> Result<(), (&'static str, String)> {
    if lo <= v && v <= hi {
        return Ok(());
    }
    Err((field, format!("{v} is outside {lo}..={hi}")))
}
