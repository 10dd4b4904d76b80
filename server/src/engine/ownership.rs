//! A cluster node writes only regions it holds (`store/pg/lease.rs`).
//!
//! Before an edit is queued (after the rules that read nothing, before any
//! chunk is loaded) the engine asks the store for every region of the
//! edit's footprint. One held by another node refuses the edit with
//! [`RejectReason::RegionElsewhere`], naming the holder and its address.
//! Free ones are claimed only once the edit passed every rule, line of
//! sight included, checked on the regions' stored chunks
//! ([`Engine::claim_after_sight`]): an edit a rule refuses claims nothing.
//! A region this node claims, here or in the background (adopted from a
//! crashed node), may have changed while others held it: its chunks are
//! reloaded from the store, and sessions holding older versions are told
//! to drop them (`UnsubscribedMany`, before any delta) and get them again
//! (the one resync a takeover allows). Each batch carries the epoch under
//! which each of its regions was last reloaded ([`Engine::batch_epochs`]),
//! so one built before a region was taken back (lost, then claimed again)
//! is fenced, not written over the reloaded copy. A batch the store
//! fences (the node was paused past its lease and another took a region)
//! is abandoned, not fatal: nothing of it is durable, so its chunks are put
//! back as stored, its edits refused, and numbering moves to a new seq
//! block. Alone on its store (`ChunkStore::clustered` false) none of this
//! runs.

use std::collections::BTreeSet;
use std::time::Duration;

/// Shortest time between two tries to reload regions whose reload failed.
pub const RELOAD_RETRY: Duration = Duration::from_secs(1);
/// How long a free region read from the store for an edit's sight check
/// is taken as current: edits aimed there meanwhile (a player refused
/// again and again, say) cost no more reads.
pub const FREE_REREAD: Duration = Duration::from_secs(1);
/// Most free regions remembered as read ([`FREE_REREAD`]).
pub const MAX_FREE_READ: usize = 1024;

use strata_protocol::{RejectReason, ServerMessage};
use strata_terrain::{ChunkPos, Edit};
use tracing::{debug, error, info, warn};

use super::Engine;
use crate::metrics as m;
use crate::sequencer::batch::TickOutput;
use crate::sequencer::regions::RegionId;
use crate::store::{RegionAccess, RegionHolder, StoreError};

/// Regions an edit needs that this node must claim first.
#[derive(Debug)]
pub(super) struct Claim {
    pub(super) free: BTreeSet<RegionId>,
}

/// The refusal for regions this node may not write now (`access`, what
/// the store answered), and whether it costs the player a rejection token.
fn access_refusal(access: Result<RegionAccess, StoreError>) -> Result<(), (RejectReason, bool)> {
    match access {
        Ok(RegionAccess::Granted) => Ok(()),
        Ok(RegionAccess::Elsewhere {
            region,
            owner,
            addr,
        }) => {
            let reason = RejectReason::RegionElsewhere {
                region_x: region.x,
                region_z: region.z,
                owner,
                addr,
            };
            Err((reason, true))
        }
        // Another node's commit holds a region row: the player tries again.
        Ok(RegionAccess::Contended) => Err((RejectReason::Busy, false)),
        Ok(RegionAccess::AtCapacity { held, max }) => {
            debug!(held, "edit refused: this node holds max_held_regions");
            metrics::counter!(m::REGION_CLAIMS_REFUSED).increment(1);
            // The node's state, not the player's doing: free, like Busy.
            let max_regions = u32::try_from(max).unwrap_or(u32::MAX);
            Err((RejectReason::NodeFull { max_regions }, false))
        }
        Err(e) => {
            crate::log_every::store_error("regions", "claiming regions failed", &e);
            Err((RejectReason::Busy, false))
        }
    }
}

impl Engine {
    /// `Ok` when this node may write every region `edit` touches: with
    /// `None` when it holds them all (or is alone on its store), with the
    /// free regions it must claim first otherwise. Those are claimed only
    /// once the edit passed every rule, line of sight included
    /// ([`Self::claim_after_sight`]): a refused edit leaves no lease.
    ///
    /// Besides [`Sequencer::edit_regions`], the regions of the chunks its
    /// sight ray crosses (`ray`): the sight is checked on this node's copy
    /// of them, current only where it writes. A player mines across a
    /// border only on a node that writes both sides.
    ///
    /// [`Sequencer::edit_regions`]: crate::sequencer::Sequencer::edit_regions
    pub(super) fn check_regions(
        &mut self,
        session: u64,
        edit: &Edit,
        ray: &[ChunkPos],
        now: u64,
    ) -> Result<Option<Claim>, RejectReason> {
        if !self.store.clustered() {
            return Ok(None);
        }
        // An edit the terrain core refuses is refused by the rules next.
        let Some(mut regions) = self.seq.edit_regions(edit) else {
            return Ok(None);
        };
        // Those it writes (or whose meshes it changes): the only ones it
        // may ask another node for, never one its sight ray just crosses.
        let written = regions.clone();
        let side = self.seq.region_chunks();
        regions.extend(ray.iter().map(|&p| RegionId::of(p, side)));
        let holders = match self.store.region_holders(&regions) {
            Ok(h) => h,
            Err(e) => {
                // Held regions are answered from the lease book: only a
                // failure tells of the store.
                self.store_failed(&e);
                crate::log_every::store_error("regions", "reading regions' holders failed", &e);
                return Err(RejectReason::Busy);
            }
        };
        let anchor = RegionId::of(edit.anchor().chunk(), side);
        let (mut free, mut held, mut elsewhere) = (BTreeSet::new(), BTreeSet::new(), Vec::new());
        for (r, h) in holders {
            match h {
                RegionHolder::Here => {
                    held.insert(r);
                }
                RegionHolder::Free => {
                    free.insert(r);
                }
                RegionHolder::Node { owner, addr } => elsewhere.push((r, owner, addr)),
            }
        }
        // The edit's own region first: its holder is where to send it.
        elsewhere.sort_by_key(|(r, ..)| *r != anchor);
        if let Some((r, owner, addr)) = elsewhere.first().cloned() {
            // The edit is this node's to apply when its own region is held
            // here (a free one another node may claim at once, with the
            // rest): the regions it writes into are asked for, if this
            // node has room for them. The refusal is no use of its own
            // region (two nodes whose players only try edits across one
            // border would otherwise keep both, refusing each other).
            if r != anchor && held.contains(&anchor) {
                let asked: BTreeSet<RegionId> = elsewhere
                    .iter()
                    .map(|(r, ..)| *r)
                    .filter(|r| written.contains(r))
                    .collect();
                let room = self
                    .store
                    .max_held_regions()
                    .saturating_sub(self.store.regions_held());
                if asked.len() + free.len() <= room {
                    self.want_regions(&asked);
                }
            }
            let reason = RejectReason::RegionElsewhere {
                region_x: r.x,
                region_z: r.z,
                owner,
                addr,
            };
            return Err(self.seq.charge_refusal(session, reason, now));
        }
        let room = self
            .store
            .max_held_regions()
            .saturating_sub(self.store.regions_held());
        if !free.is_empty() && free.len() <= room {
            // Held ones reported fresh (adopted, say) are reloaded before
            // the sight check reads them; one not reloaded yet refuses.
            self.take_fresh_regions();
            if held.iter().any(|r| self.reload_retry.contains_key(r)) {
                return Err(RejectReason::Busy);
            }
            // The held ones are in use (kept from idle release).
            if !held.is_empty() {
                if let Err(e) = self.store.acquire_regions(&held) {
                    self.store_failed(&e);
                }
            }
            return Ok(Some(Claim { free }));
        }
        // Held, but its reload failed (waiting for its retry): refused
        // before the store marks it in use, so a region whose reload keeps
        // failing is let go once idle, not kept by the edits it refuses.
        self.take_fresh_regions();
        if held.iter().any(|r| self.reload_retry.contains_key(r)) {
            return Err(RejectReason::Busy);
        }
        // Held (marked in use), or more than this node may claim: the
        // store answers now, and claims nothing at capacity.
        let access = self.store.acquire_regions(&regions);
        match &access {
            Err(e) => self.store_failed(e),
            // Taken by another node since the holders were read.
            Ok(RegionAccess::Elsewhere { region, .. })
                if *region != anchor
                    && held.contains(&anchor)
                    && written.contains(region)
                    && self.store.regions_held() < self.store.max_held_regions() =>
            {
                self.want_regions(&BTreeSet::from([*region]));
            }
            Ok(_) => {}
        }
        self.take_fresh_regions();
        // Held, but not reloaded yet (a failed reload waits for its
        // retry): refused before anything is applied on stale chunks.
        if matches!(access, Ok(RegionAccess::Granted))
            && regions.iter().any(|r| self.reload_retry.contains_key(r))
        {
            return Err(RejectReason::Busy);
        }
        match access_refusal(access) {
            Ok(()) => Ok(None),
            Err((reason, true)) => Err(self.seq.charge_refusal(session, reason, now)),
            Err((reason, false)) => Err(reason),
        }
    }

    /// Asks the nodes holding `regions` to hand them over (an edit whose
    /// own region is held here writes into them).
    fn want_regions(&mut self, regions: &BTreeSet<RegionId>) {
        if let Err(e) = self.store.want_regions(regions) {
            self.store_failed(&e);
            crate::log_every::store_error("regions", "asking for regions failed", &e);
        }
    }

    /// Before the first edit in regions this node does not hold: earlier
    /// edits' sight is checked (they keep their place in the queue), and
    /// the regions' chunks are brought to the store's versions, so this
    /// edit's sight is checked on what it will apply to.
    pub(super) fn before_claiming(
        &mut self,
        free: &BTreeSet<RegionId>,
    ) -> Result<(), RejectReason> {
        self.check_sighted();
        let now = std::time::Instant::now();
        for &r in free {
            if self
                .free_read
                .get(&r)
                .is_some_and(|at| now.duration_since(*at) < FREE_REREAD)
            {
                continue;
            }
            if let Err(e) = self.reload_region(r) {
                self.store_failed(&e);
                let what = format!("reading free region ({}, {}) failed", r.x, r.z);
                crate::log_every::store_error("regions", &what, &e);
                return Err(RejectReason::Busy);
            }
            if self.free_read.len() >= MAX_FREE_READ {
                self.free_read.clear();
            }
            self.free_read.insert(r, now);
        }
        Ok(())
    }

    /// The edit just admitted (the only one awaiting its sight check, see
    /// [`Self::before_claiming`]) has its sight checked; seen, it is queued
    /// and `free` claimed for it, or taken back out with the claim's
    /// refusal.
    pub(super) fn claim_after_sight(
        &mut self,
        session: u64,
        client_edit_id: u64,
        claim: &Claim,
        now: u64,
    ) -> Result<(), RejectReason> {
        let free = &claim.free;
        let pool = self.pool.clone();
        let seq = &mut self.seq;
        let refused = pool.install(|| seq.check_sighted(now));
        let mut mine = None;
        for r in refused {
            if (r.session_id, r.client_edit_id) == (session, client_edit_id) {
                mine = Some(r.reason);
            } else {
                self.refuse_edit(r.session_id, r.client_edit_id, r.reason);
            }
        }
        if let Some(reason) = mine {
            return Err(reason);
        }
        let access = self.store.acquire_regions(free);
        if let Err(e) = &access {
            self.store_failed(e);
        }
        match access_refusal(access) {
            Ok(()) => {
                // Reloaded, or its edits refused `Busy` if that failed. A
                // writer that got in since the read moved chunks its sight
                // was checked on: the reload takes it out of the queue,
                // refused `Busy` (free), to be tried again on the current
                // copy (`unqueue_seen_in`, by its box's and its ray's
                // regions: those it was checked for here).
                self.take_fresh_regions();
                Ok(())
            }
            Err((reason, charged)) => {
                self.seq.take_back(session, client_edit_id, charged, now);
                // One claim takes what it can: what it took for this edit
                // (another node had one of the others) goes back.
                if let Err(e) = self.store.release_regions(free) {
                    self.store_failed(&e);
                    warn!(error = %e, "letting go of a refused edit's regions failed; they idle out");
                }
                self.take_fresh_regions();
                Err(reason)
            }
        }
    }

    /// Between ticks: the seq block the store may have moved to, and the
    /// regions claimed in the background. An error when another process
    /// took this node's id: the engine stops.
    pub(super) fn follow_leases(&mut self) -> anyhow::Result<()> {
        if !self.store.clustered() {
            return Ok(());
        }
        if let Some(why) = self.store.superseded() {
            anyhow::bail!(why);
        }
        self.follow_seq_block();
        self.take_fresh_regions();
        metrics::gauge!(m::REGIONS_HELD).set(self.store.regions_held() as f64);
        self.tell_owners();
        self.sweep_known();
        Ok(())
    }

    /// Numbers the next edits in the store's current seq block: above its
    /// floor, none past its end (edits past it wait for the next block,
    /// which the store reserves in the background once told how far the
    /// engine is).
    pub(super) fn follow_seq_block(&mut self) {
        let (floor, last) = self.store.seq_bounds();
        self.seq.raise_next_seq(floor.saturating_add(1));
        self.seq.limit_seqs(last);
        self.store.note_next_seq(self.seq.next_seq());
    }

    /// Positions are swept through this node's regions and those it read
    /// as free.
    fn sweep_known(&mut self) {
        let mut swept = self.free_regions.clone();
        swept.extend(self.region_epochs.keys().copied());
        self.seq.set_swept_regions(Some(swept));
    }

    /// A report whose feet are in a region whose holder this node has not
    /// read (a session's first report: no view overlapped it yet) reads it
    /// now, so a free one is swept and the report judged as any
    /// (`Session::judged`). Another node's stays unswept; the store
    /// answers from its lease book while it knows the holder.
    pub(super) fn know_feet_region(&mut self, feet: strata_terrain::FixedVec3) {
        if !self.store.clustered() {
            return;
        }
        let side = self.seq.region_chunks();
        let region = RegionId::of(crate::validate::position::feet_voxel(feet).chunk(), side);
        if self.free_regions.contains(&region) || self.region_epochs.contains_key(&region) {
            return;
        }
        match self.store.region_holders(&BTreeSet::from([region])) {
            Ok(holders) => {
                // Brought current first (a reload only when another node
                // wrote it since: the next player there finds it seen).
                if holders.iter().any(|(_, h)| *h == RegionHolder::Free)
                    && !self
                        .bring_free_current(&BTreeSet::from([region]))
                        .is_empty()
                {
                    self.free_current.insert(region);
                    self.free_regions.insert(region);
                    self.sweep_known();
                }
            }
            Err(e) => {
                self.store_failed(&e);
                crate::log_every::store_error("regions", "reading a region's holder failed", &e);
            }
        }
    }

    /// Reloads the regions claimed, lost or let go since the last call
    /// (and those whose reload failed, once [`RELOAD_RETRY`] has passed).
    /// A region takes its new epoch only once reloaded: until then a batch
    /// writing it is fenced, never built on chunks another node moved on.
    /// Returns the regions whose reload moved a chunk.
    fn take_fresh_regions(&mut self) -> BTreeSet<RegionId> {
        let mut moved = BTreeSet::new();
        let fresh = self.store.take_fresh_regions();
        let retry_due = self
            .reload_retry_at
            .is_none_or(|at| at.elapsed() >= RELOAD_RETRY);
        if fresh.is_empty() && (self.reload_retry.is_empty() || !retry_due) {
            return moved;
        }
        let mut todo = if retry_due {
            std::mem::take(&mut self.reload_retry)
        } else {
            Default::default()
        };
        // A newer report of a region replaces a retry of it.
        for (r, epoch) in fresh {
            self.reload_retry.remove(&r);
            todo.insert(r, epoch);
        }
        for (r, epoch) in todo {
            match self.reload_region(r) {
                Ok(n) => {
                    if n > 0 {
                        moved.insert(r);
                    }
                    match epoch {
                        Some(e) => self.region_epochs.insert(r, e),
                        None => self.region_epochs.remove(&r),
                    };
                    info!(
                        region_x = r.x,
                        region_z = r.z,
                        chunks_changed = n,
                        "region claimed; stored chunks reloaded"
                    )
                }
                Err(e) => {
                    self.store_failed(&e);
                    self.region_epochs.remove(&r);
                    self.reload_retry.insert(r, epoch);
                    self.reload_retry_at = Some(std::time::Instant::now());
                    error!(error = %e, region_x = r.x, region_z = r.z,
                        "reloading a claimed region failed; its edits are refused until a retry succeeds")
                }
            }
        }
        // Edits queued before a reload that moved chunks had their sight
        // checked on the old copies: refused `Busy` (free), to be sent
        // again against the world as it is.
        if !moved.is_empty() {
            for (session, id) in self.seq.unqueue_seen_in(&moved, super::now_ms()) {
                self.refuse_edit(session, id, RejectReason::Busy);
            }
        }
        // Edits queued in one (claimed for them, or adopted under them)
        // are refused now, not applied to be fenced.
        if !self.reload_retry.is_empty() {
            let failed = self.reload_retry.keys().copied().collect();
            for (session, id) in self.seq.unqueue_in(&failed, super::now_ms()) {
                self.refuse_edit(session, id, RejectReason::Busy);
            }
        }
        moved
    }

    /// Brings the region's chunks to their stored versions; returns how
    /// many had moved on.
    pub(super) fn reload_region(&mut self, region: RegionId) -> Result<usize, StoreError> {
        let mut moved = Vec::new();
        // Only the region's own chunks count as moved: its neighbours'
        // border chunks do not refuse the edit that claimed it.
        let mut own = 0;
        let reloaded = self.reload_chunks(region, &mut moved).and_then(|()| {
            own = moved.len();
            self.reload_border_neighbours(region, &mut moved)
        });
        // What moved before a failure is withdrawn all the same: the retry
        // finds those chunks current and would never tell their holders.
        if !moved.is_empty() {
            self.premesh.invalidate();
        }
        self.withdraw_stale(&moved);
        reloaded.map(|()| own)
    }

    /// Brings the chunks held here next to `region` of the regions around
    /// it that this node does not write up to their stored versions: the
    /// meshes of `region`'s border chunks read their border voxels, which
    /// whoever wrote `region` meanwhile may have changed (an edit within
    /// [`MESH_REACH`] of a border needs both regions). One not held here is
    /// noted at its stored version (read from the store when next needed).
    ///
    /// [`MESH_REACH`]: crate::sequencer::residency::MESH_REACH
    fn reload_border_neighbours(
        &mut self,
        region: RegionId,
        moved: &mut Vec<(ChunkPos, u64)>,
    ) -> Result<(), StoreError> {
        let side = i64::from(self.seq.region_chunks().max(1));
        // `region`'s chunk columns, one more on each side.
        let lo = |r: i32| i64::from(r) * side - 1;
        let hi = |r: i32| (i64::from(r) + 1) * side;
        let next_to = |p: ChunkPos| {
            (lo(region.x)..=hi(region.x)).contains(&i64::from(p.x))
                && (lo(region.z)..=hi(region.z)).contains(&i64::from(p.z))
        };
        let around: BTreeSet<RegionId> = (-1..=1)
            .flat_map(|dz| (-1..=1).map(move |dx| (dx, dz)))
            .filter(|&d| d != (0, 0))
            .map(|(dx, dz)| RegionId {
                x: region.x.saturating_add(dx),
                z: region.z.saturating_add(dz),
            })
            .filter(|r| !self.region_epochs.contains_key(r))
            .collect();
        for (r, holder) in self.store.region_holders(&around)? {
            // Written here: current, and maybe ahead of the store by a
            // commit in flight.
            if holder == RegionHolder::Here {
                continue;
            }
            let listed: Vec<(ChunkPos, u64)> = self
                .store
                .region_versions(r)?
                .into_iter()
                .filter(|&(p, _)| next_to(p))
                .collect();
            self.reload_listed(listed, moved)?;
        }
        Ok(())
    }

    /// Brings each chunk of `region` whose stored version moved to it,
    /// listing in `moved` those done (with the version loaded).
    fn reload_chunks(
        &mut self,
        region: RegionId,
        moved: &mut Vec<(ChunkPos, u64)>,
    ) -> Result<(), StoreError> {
        let listed = self.store.region_versions(region)?;
        self.reload_listed(listed, moved)
    }

    /// Brings each chunk of `listed` (with its stored version) whose
    /// version moved to it: read again where held here, else noted (its
    /// neighbours' cached meshes dropped), listing in `moved` those done.
    fn reload_listed(
        &mut self,
        listed: Vec<(ChunkPos, u64)>,
        moved: &mut Vec<(ChunkPos, u64)>,
    ) -> Result<(), StoreError> {
        let mut load = Vec::new();
        for (pos, version) in listed {
            if self.versions.get(&pos) == Some(&version) {
                continue;
            }
            if self.seq.is_resident(pos) {
                load.push((pos, version));
            } else {
                // Not held here, but its neighbours' meshes read it.
                self.seq.forget_meshes_around(pos);
                self.versions.insert(pos, version);
                moved.push((pos, version));
            }
        }
        self.load_listed(load, moved)
    }

    /// Reads `load` (chunks held here, each with the version the store
    /// listed) from the store and puts them in the world, listing each in
    /// `moved` with the version read.
    fn load_listed(
        &mut self,
        load: Vec<(ChunkPos, u64)>,
        moved: &mut Vec<(ChunkPos, u64)>,
    ) -> Result<(), StoreError> {
        if load.is_empty() {
            return Ok(());
        }
        // Read together (a failure changes none of them: the retry finds
        // them moved still).
        let positions: Vec<ChunkPos> = load.iter().map(|&(p, _)| p).collect();
        let stored = self.store.load_chunks(&positions)?;
        for ((pos, listed), stored) in load.into_iter().zip(stored) {
            // The version loaded, which another node may have moved past
            // the one listed.
            let now = match stored {
                Some(s) => {
                    let v = s.version;
                    self.seq.insert_stored_chunk(pos, s.chunk, v);
                    v
                }
                None => listed,
            };
            self.versions.insert(pos, now);
            moved.push((pos, now));
        }
        Ok(())
    }

    /// Sessions holding any of `chunks` at another version than the one
    /// given are told to drop it (`UnsubscribedMany`) and get it again.
    /// Withdrawn at once, before any delta of this tick: a neighbour's
    /// delta must not be meshed against a stale copy.
    fn withdraw_stale(&mut self, chunks: &[(ChunkPos, u64)]) {
        let mut stale: std::collections::HashMap<u64, Vec<ChunkPos>> = Default::default();
        for &(pos, version) in chunks {
            for (&id, p) in self.peers.iter_mut() {
                if p.held(pos).is_some_and(|v| v != version) {
                    p.resend(pos);
                    stale.entry(id).or_default().push(pos);
                }
            }
        }
        for (id, chunks) in stale {
            // Owed, they go ahead of any later update (this tick's deltas
            // included); a lagging client's wait for room.
            if let Some(p) = self.peers.get_mut(&id) {
                p.withdraw(chunks);
            }
        }
    }
}

impl Engine {
    /// A commit the store fenced, whose session ended before COMMIT, or
    /// numbered in a seq block compacted away: nothing of `out` is
    /// durable. Puts its chunks back as the store holds
    /// them, refuses its edits (`RegionElsewhere` for those that changed a
    /// lost region, `Busy` for the others), and moves to a new seq block so
    /// the abandoned seqs leave no gap inside one (reserved now, or by the
    /// lease thread, edits waiting until then). False for any other
    /// error, or when the chunks cannot be put back (the node must then
    /// stop).
    pub(super) fn abandon_fenced(&mut self, out: &TickOutput, e: &StoreError) -> bool {
        // A session the server ended before COMMIT (idle in its
        // transaction past the lease: a paused node) wrote nothing either.
        let (region, owner) = match e {
            StoreError::Fenced { region, owner, .. } => (Some(*region), owner.clone()),
            StoreError::Uncommitted { .. } | StoreError::SeqsRetired { .. } => (None, None),
            _ => return false,
        };
        if !self.store.clustered() {
            return false;
        }
        let changed: BTreeSet<ChunkPos> = out
            .applied
            .iter()
            .flat_map(|a| a.changes.iter().map(|c| c.pos))
            .collect();
        // A background mesh may have read the batch's content.
        self.premesh.invalidate();
        let mut restored = Vec::with_capacity(changed.len());
        for &pos in &changed {
            match self.restore_chunk(pos) {
                Ok(version) => restored.push((pos, version)),
                Err(e) => {
                    error!(error = %e, ?pos, "putting a fenced batch's chunk back failed");
                    return false;
                }
            }
        }
        // Another node may have changed a chunk since this one's players
        // got it (the batch was fenced because it took the region): their
        // copies are stale, as after a takeover.
        self.withdraw_stale(&restored);
        // Edits queued while it committed may have been seen through what
        // it changed: refused, to be sent again against the world as it is.
        for (session, id) in self.seq.unqueue_sighted(super::now_ms()) {
            self.refuse_edit(session, id, RejectReason::Busy);
        }
        // Failing, the store ends the block at the last seq handed out:
        // edits wait for the block the lease thread reserves.
        if let Err(e) = self.store.reserve_seqs(self.seq.last_seq()) {
            self.store_failed(&e);
            warn!(error = %e, "reserving a seq block after a fenced commit failed; edits wait for the next block");
        }
        self.follow_seq_block();
        let holder = region
            .and_then(|r| self.store.region_holders(&BTreeSet::from([r])).ok())
            .and_then(|h| h.into_iter().next().map(|(_, h)| h));
        // Held here again (the batch was built before this node took the
        // region back): not elsewhere, only too late.
        let region = region.filter(|_| holder != Some(RegionHolder::Here));
        let addr = match holder {
            Some(RegionHolder::Node { addr, .. }) => Some(addr),
            _ => None,
        };
        let side = self.seq.region_chunks();
        for a in &out.applied {
            // Written or read (the batch was fenced by both).
            let lost = region.filter(|r| {
                a.changes.iter().any(|c| RegionId::of(c.pos, side) == *r)
                    || self
                        .seq
                        .edit_regions(&a.edit)
                        .is_some_and(|rs| rs.contains(r))
            });
            let reason = match lost {
                Some(r) => RejectReason::RegionElsewhere {
                    region_x: r.x,
                    region_z: r.z,
                    owner: owner.clone().unwrap_or_default(),
                    addr: addr.clone().unwrap_or_default(),
                },
                None => RejectReason::Busy,
            };
            metrics::counter!(m::EDITS_REJECTED, "reason" => m::reject_label(&reason)).increment(1);
            let msg = ServerMessage::EditRejected {
                client_edit_id: a.client_edit_id,
                reason,
            };
            self.send_control(a.session_id, &msg);
        }
        warn!(
            error = %e,
            edits = out.applied.len(),
            chunks = changed.len(),
            "commit refused: nothing was written; the batch is abandoned and its edits refused"
        );
        true
    }

    /// The epoch each region `batch` writes or its edits read (their
    /// footprints, as claimed for them: [`Sequencer::edit_regions`]) was
    /// last reloaded under (0, which no lease has, for one never
    /// reported): `None` alone on the store. The store fences them all, so
    /// a batch built on a region another node took since is not committed.
    ///
    /// [`Sequencer::edit_regions`]: crate::sequencer::Sequencer::edit_regions
    pub(super) fn batch_epochs(
        &self,
        batch: &crate::store::CommitBatch,
    ) -> Option<std::collections::BTreeMap<RegionId, u64>> {
        if !self.store.clustered() {
            return None;
        }
        let side = self.seq.region_chunks();
        let chunks = batch.chunks.iter().map(|c| c.0);
        let deltas = batch.deltas.iter().map(|d| d.pos);
        let read = batch
            .entries
            .iter()
            .filter_map(|e| self.seq.edit_regions(&e.edit))
            .flatten();
        Some(
            chunks
                .chain(deltas)
                .map(|pos| RegionId::of(pos, side))
                .chain(read)
                .map(|r| (r, self.region_epochs.get(&r).copied().unwrap_or(0)))
                .collect(),
        )
    }

    /// Puts `pos` back as the store holds it (generated if it holds none);
    /// returns the version it is at now.
    fn restore_chunk(&mut self, pos: ChunkPos) -> Result<u64, StoreError> {
        match self.store.load_chunk(pos)? {
            Some(stored) => {
                self.versions.insert(pos, stored.version);
                self.seq
                    .insert_stored_chunk(pos, stored.chunk, stored.version);
                Ok(stored.version)
            }
            None => {
                self.versions.remove(&pos);
                let generator = self.seq.world().generator().clone();
                self.seq
                    .insert_stored_chunk(pos, generator.generate(pos), 0);
                Ok(0)
            }
        }
    }
}
