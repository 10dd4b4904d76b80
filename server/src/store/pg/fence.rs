//! Fencing: a commit writes a region only while the `regions` row still
//! names this node as owner at the epoch it holds.
//!
//! Before the transaction the node claims the regions of the batch it does
//! not hold yet (`lease.rs`; never one it lost), and refuses a batch the
//! engine built under another epoch than the one held now (it was built on
//! the copy from before the region was taken back); inside it, after the
//! rows of the batch's chunks, it locks the batch's region rows `FOR UPDATE` (a claim by another node
//! waits for the commit, or the commit sees the claim) and compares. Any
//! mismatch refuses the whole batch with [`StoreError::Fenced`] and the
//! transaction is rolled back. So does a batch whose first seq is not
//! above a region's `last_seq`: each region's edits keep one rising order
//! across owners (`seqs.rs`). A batch that passes moves each region's
//! `last_seq` to its own and adds its edits to the regions' `edits` counts
//! in the same transaction (`cluster status`). The lease's expiry is not checked here: an
//! epoch only moves when another claim succeeded or a restore freed the
//! region, and that is what makes a write unsafe.

use std::collections::{BTreeMap, BTreeSet};

use super::lease::{claim, Lost, NodeLeases};
use super::pool::{Conn, Pool};
use super::{from_sql, to_sql};
use crate::sequencer::regions::RegionId;
use crate::store::StoreError;

/// The regions a commit writes and the epoch held for each.
#[derive(Debug)]
pub(super) struct Fence {
    node_id: String,
    /// `[cluster] lease_ms`: a commit extends the leases it locks.
    lease_ms: f64,
    held: BTreeMap<RegionId, u64>,
    /// Accepted edits of the batch that changed each region.
    edits: BTreeMap<RegionId, i64>,
    /// The batch's first and last seq.
    seqs: (i64, i64),
}

impl Fence {
    pub(super) fn set_seqs(&mut self, first: i64, last: i64) {
        self.seqs = (first, last);
    }

    /// Counts, per region, the edits whose changes touch it (an edit
    /// across a border counts in each of its regions).
    pub(super) fn count_edits(&mut self, edits: impl Iterator<Item = BTreeSet<RegionId>>) {
        for regions in edits {
            for r in regions {
                *self.edits.entry(r).or_default() += 1;
            }
        }
    }
}

/// Refuses at once a region this node lost or another node holds, and one
/// whose epoch the batch was built under (`built`, when the engine gave
/// them) is not the one held. Without `built` (tools, tests) it first
/// claims what the batch needs and this node does not hold; with it, a
/// claim could only take the region under a new epoch the batch was not
/// built under, so none is made.
pub(super) fn prepare(
    pool: &Pool,
    leases: &NodeLeases,
    regions: &BTreeSet<RegionId>,
    built: Option<&BTreeMap<RegionId, u64>>,
) -> Result<Fence, StoreError> {
    // Another process runs under this node's id: this one writes nothing.
    leases.not_superseded()?;
    if built.is_none() {
        claim(pool, leases, regions, Lost::Keep)?;
    }
    let held = leases.held();
    let lost = leases.lost();
    let mut fence = Fence {
        node_id: leases.node_id().to_string(),
        lease_ms: leases.lease_ms(),
        held: BTreeMap::new(),
        edits: BTreeMap::new(),
        seqs: (0, 0),
    };
    for &r in regions {
        let under = match built {
            Some(b) => b.get(&r).copied(),
            None => held.get(&r).copied(),
        };
        match (held.get(&r), under) {
            (Some(&epoch), Some(b)) if b == epoch => {
                fence.held.insert(r, epoch);
            }
            (_, b) => {
                return Err(current_holder(
                    pool,
                    r,
                    b.or_else(|| lost.get(&r).copied()),
                )?)
            }
        }
    }
    Ok(fence)
}

/// The refusal for `region`, naming who holds it now.
fn current_holder(
    pool: &Pool,
    region: RegionId,
    held_epoch: Option<u64>,
) -> Result<StoreError, StoreError> {
    let row = pool.run("reading a region's lease", async |c: &mut Conn| {
        c.query_opt(
            "SELECT owner, epoch FROM regions WHERE region_x = $1 AND region_z = $2",
            &[&region.x, &region.z],
        )
        .await
    })?;
    let (owner, current_epoch) = match row {
        Some(r) => (
            r.get::<_, Option<String>>(0),
            Some(from_sql(r.get(1), "epoch", super::lease::show(region))?),
        ),
        None => (None, None),
    };
    Ok(StoreError::Fenced {
        region,
        held_epoch,
        current_epoch,
        owner,
    })
}

/// Inside the commit transaction: locks the fence's region rows and
/// refuses the batch unless each still has this node's owner and epoch,
/// then counts the batch's edits in them.
/// `world`: the world's id the node started on; a restore since (which
/// also frees every region at a higher epoch) refuses the batch.
pub(super) async fn check(
    c: &mut Conn,
    fence: &Fence,
    world: Option<&String>,
) -> Result<(), StoreError> {
    let (xs, zs): (Vec<i32>, Vec<i32>) = fence.held.keys().map(|r| (r.x, r.z)).unzip();
    let rows = c
        .query(
            "SELECT r.region_x, r.region_z, r.owner, r.epoch, r.last_seq, \
                 (SELECT generation FROM world WHERE id = 1) FROM regions r \
             JOIN unnest($1::int4[], $2::int4[]) AS u(x, z) \
               ON r.region_x = u.x AND r.region_z = u.z \
             ORDER BY r.region_x, r.region_z FOR UPDATE OF r",
            &[&xs, &zs],
        )
        .await?;
    if let Some(r) = rows.first() {
        let found: Option<String> = r.get(5);
        super::commit::same_world(world, found.unwrap_or_default())?;
    }
    let mut current: BTreeMap<RegionId, (Option<String>, i64, i64)> = BTreeMap::new();
    for r in rows {
        current.insert(
            RegionId {
                x: r.get(0),
                z: r.get(1),
            },
            (r.get(2), r.get(3), r.get(4)),
        );
    }
    let (first, last) = fence.seqs;
    for (&region, &held) in &fence.held {
        let (owner, epoch, region_last) = current.remove(&region).unwrap_or((None, 0, 0));
        if owner.as_deref() != Some(&fence.node_id) || epoch != to_sql(held, "epoch")? {
            return Err(StoreError::Fenced {
                region,
                held_epoch: Some(held),
                current_epoch: u64::try_from(epoch).ok().filter(|&e| e > 0),
                owner,
            });
        }
        if first <= region_last {
            return Err(StoreError::batch(format!(
                "first seq {first} is not above {}'s last seq {region_last}",
                super::lease::show(region)
            )));
        }
    }
    // The batch's seqs lie in a block of this node's, kept until the
    // commit ends (a compaction waits for it, `seqs::compact`); seqs below
    // every block are a node's that never reserved one (tools, tests).
    let block = c
        .query_opt(
            "SELECT node, last_seq FROM seq_blocks WHERE first_seq <= $1 \
             ORDER BY first_seq DESC LIMIT 1 FOR KEY SHARE",
            &[&first],
        )
        .await?;
    if let Some(b) = block {
        let (node, block_last): (String, i64) = (b.get(0), b.get(1));
        if node != fence.node_id || block_last < last {
            return Err(StoreError::SeqsRetired {
                first: from_sql(first, "first seq", "batch")?,
                last: from_sql(last, "last seq", "batch")?,
            });
        }
    }
    // The renewal skips rows this transaction holds: it renews them itself
    // (a slow commit would otherwise let them run out, and another node
    // claim them, meanwhile). A lease already run out stays so: only the
    // renewal takes it on again.
    c.execute(
        "UPDATE regions AS r SET last_seq = GREATEST(r.last_seq, $3), \
         lease_expires = CASE WHEN r.lease_expires > clock_timestamp() \
             THEN GREATEST(r.lease_expires, \
                 clock_timestamp() + $4::float8 * interval '1 millisecond') \
             ELSE r.lease_expires END \
         FROM unnest($1::int4[], $2::int4[]) AS u(x, z) \
         WHERE r.region_x = u.x AND r.region_z = u.z",
        &[&xs, &zs, &last, &fence.lease_ms],
    )
    .await?;
    if !fence.edits.is_empty() {
        let (xs, zs): (Vec<i32>, Vec<i32>) = fence.edits.keys().map(|r| (r.x, r.z)).unzip();
        let ns: Vec<i64> = fence.edits.values().copied().collect();
        c.execute(
            "UPDATE regions AS r SET edits = r.edits + u.n \
             FROM unnest($1::int4[], $2::int4[], $3::int8[]) AS u(x, z, n) \
             WHERE r.region_x = u.x AND r.region_z = u.z",
            &[&xs, &zs, &ns],
        )
        .await?;
    }
    Ok(())
}
