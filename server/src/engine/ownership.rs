//! A cluster node writes only regions it holds (`store/pg/lease.rs`).
//!
//! Before an edit is queued (after the rules that read nothing, before any
//! chunk is loaded) the engine asks the store for every region of the
//! edit's footprint. One held by another node refuses the edit with
//! [`RejectReason::RegionElsewhere`], naming the holder and its address.
//! A region this node claims, here or in the background (adopted from a
//! crashed node), may have changed while others held it: its chunks are
//! reloaded from the store, and sessions holding older versions get the
//! chunk again (the one resync a takeover allows). Alone on its store
//! (`ChunkStore::clustered` false) none of this runs.

use strata_protocol::RejectReason;
use strata_terrain::Edit;
use tracing::{error, info};

use super::Engine;
use crate::sequencer::regions::RegionId;
use crate::store::{RegionAccess, StoreError};

impl Engine {
    /// `Ok` when this node may write every region `edit` touches.
    pub(super) fn check_regions(
        &mut self,
        session: u64,
        edit: &Edit,
        now: u64,
    ) -> Result<(), RejectReason> {
        if !self.store.clustered() {
            return Ok(());
        }
        // An edit the terrain core refuses is refused by the rules next.
        let Some(regions) = self.seq.edit_regions(edit) else {
            return Ok(());
        };
        let access = self.store.acquire_regions(&regions);
        self.take_fresh_regions();
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
                Err(self.seq.charge_refusal(session, reason, now))
            }
            Err(e) => {
                error!(error = %e, "claiming regions failed");
                Err(RejectReason::Busy)
            }
        }
    }

    /// Between ticks: the seq block the store may have moved to, and the
    /// regions claimed in the background.
    pub(super) fn follow_leases(&mut self) {
        if !self.store.clustered() {
            return;
        }
        self.seq
            .raise_next_seq(self.store.seq_floor().saturating_add(1));
        self.take_fresh_regions();
        self.tell_owners();
    }

    fn take_fresh_regions(&mut self) {
        for r in self.store.take_fresh_regions() {
            match self.reload_region(r) {
                Ok(n) => info!(
                    region_x = r.x,
                    region_z = r.z,
                    chunks_changed = n,
                    "region claimed; stored chunks reloaded"
                ),
                Err(e) => error!(error = %e, region_x = r.x, region_z = r.z,
                    "reloading a claimed region failed"),
            }
        }
    }

    /// Brings the region's chunks to their stored versions; returns how
    /// many had moved on.
    fn reload_region(&mut self, region: RegionId) -> Result<usize, StoreError> {
        let mut changed = 0;
        for (pos, version) in self.store.region_versions(region)? {
            if self.versions.get(&pos) == Some(&version) {
                continue;
            }
            changed += 1;
            self.versions.insert(pos, version);
            if self.seq.is_resident(pos) {
                if let Some(stored) = self.store.load_chunk(pos)? {
                    self.seq
                        .insert_stored_chunk(pos, stored.chunk, stored.version);
                }
            }
            for p in self.peers.values_mut() {
                if p.known.get(&pos).is_some_and(|&v| v != version) {
                    p.resend(pos);
                }
            }
        }
        Ok(changed)
    }
}
