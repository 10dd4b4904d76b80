//! Routing for cluster clients: every session is told who writes each
//! region its view overlaps (`ServerMessage::RegionOwners`), whenever
//! that set or a holder changes, with a ticket that lets the player
//! `Arrive` at another node. The client library then keeps a connection
//! to each holder and sends each edit to its region's holder.
//!
//! Looked at every [`OWNERS_EVERY`], for every session at once: holders
//! come from the store's cache, with one query for those not cached (a
//! region is cached up to a renewal period). Sent again with a
//! new ticket every [`TICKET_REFRESH_MS`], so a client always holds one
//! well within `TICKET_TTL_MS`.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use strata_protocol::limits::MAX_REGION_OWNERS;
use strata_protocol::{RegionHolder as Holder, RegionOwner, ServerMessage};
use strata_terrain::ChunkPos;
use tracing::error;

use super::{now_ms, Engine};
use crate::sequencer::regions::{RegionId, RegionSpan};
use crate::store::RegionHolder;

/// How often sessions' region holders are looked at.
pub const OWNERS_EVERY: Duration = Duration::from_millis(200);
/// A session's ticket is renewed after this long (ms), a third of
/// `TICKET_TTL_MS`.
pub const TICKET_REFRESH_MS: u64 = strata_protocol::limits::TICKET_TTL_MS / 3;

/// The regions a view of `radius` chunks around `center` overlaps, the
/// nearest [`MAX_REGION_OWNERS`] when there are more.
pub fn view_regions(center: ChunkPos, radius: u8, side: u32) -> BTreeSet<RegionId> {
    let r = i32::from(radius);
    // Saturating: an admin may look anywhere, up to the coordinates' ends.
    let min = ChunkPos::new(
        center.x.saturating_sub(r),
        center.y,
        center.z.saturating_sub(r),
    );
    let max = ChunkPos::new(
        center.x.saturating_add(r),
        center.y,
        center.z.saturating_add(r),
    );
    let mut all: Vec<RegionId> = RegionSpan::of_chunks(min, max, side).regions().collect();
    if all.len() > MAX_REGION_OWNERS {
        let mid = RegionId::of(center, side);
        let off = |a: i32, b: i32| (i64::from(a) - i64::from(b)).abs();
        all.sort_by_key(|g| off(g.x, mid.x).max(off(g.z, mid.z)));
        all.truncate(MAX_REGION_OWNERS);
    }
    all.into_iter().collect()
}

fn to_wire(region: RegionId, holder: RegionHolder) -> RegionOwner {
    RegionOwner {
        region_x: region.x,
        region_z: region.z,
        holder: match holder {
            RegionHolder::Here => Holder::Here,
            RegionHolder::Free => Holder::Free,
            RegionHolder::Node { owner, addr } => Holder::Node { node: owner, addr },
        },
    }
}

/// Free regions a check of [`Engine::bring_free_current`] reloads at
/// most (the rest wait for the next check, unswept).
pub const FREE_RELOADS_PER_PASS: usize = 8;
/// How often the free regions of the sessions' views are checked against
/// their marks (between checks, those found current stay so: a region
/// another node claimed, wrote and let go within one is reloaded at the
/// next).
pub const FREE_CHECK_EVERY: Duration = Duration::from_secs(1);
/// Most free regions whose marks are remembered (past it, all are
/// forgotten and reloaded as they come up again).
pub const MAX_FREE_SEEN: usize = 4096;

impl Engine {
    /// Of `free` (regions no node holds), those whose copies here are
    /// current, reloading those another node wrote since they were last
    /// brought current (their mark moved: every write raises the region's
    /// last seq): at most [`FREE_RELOADS_PER_PASS`] a call. One never
    /// claimed, (0, 0), nobody wrote. A player at home here reads a free
    /// region from this node (its client has no route elsewhere), and its
    /// positions there are swept on these copies.
    pub(super) fn bring_free_current(&mut self, free: &BTreeSet<RegionId>) -> BTreeSet<RegionId> {
        let marks = match self.store.free_region_marks(free) {
            Ok(m) => m,
            Err(e) => {
                self.store_failed(&e);
                crate::log_every::store_error("regions", "reading free regions failed", &e);
                return BTreeSet::new();
            }
        };
        if self.free_seen.len() + marks.len() > MAX_FREE_SEEN {
            self.free_seen.clear();
        }
        let mut current = BTreeSet::new();
        let mut reloads = 0;
        for (r, mark) in marks {
            if mark == (0, 0) || self.free_seen.get(&r) == Some(&mark) {
                current.insert(r);
                continue;
            }
            if reloads == FREE_RELOADS_PER_PASS {
                continue;
            }
            reloads += 1;
            match self.reload_region(r) {
                Ok(moved) => {
                    if moved > 0 {
                        tracing::info!(
                            region_x = r.x,
                            region_z = r.z,
                            chunks_changed = moved,
                            "a free region's copies brought current"
                        );
                    }
                    self.free_seen.insert(r, mark);
                    current.insert(r);
                }
                Err(e) => {
                    self.store_failed(&e);
                    crate::log_every::store_error("read", "reloading a free region failed", &e);
                }
            }
        }
        current
    }

    /// Of `free`, those current here: checked against their marks once per
    /// [`FREE_CHECK_EVERY`], else as the last check found them.
    pub(super) fn current_free(&mut self, free: &BTreeSet<RegionId>) -> BTreeSet<RegionId> {
        let due = self
            .free_checked
            .is_none_or(|at| at.elapsed() >= FREE_CHECK_EVERY);
        if !due {
            return free
                .iter()
                .filter(|r| self.free_current.contains(r))
                .copied()
                .collect();
        }
        let current = self.bring_free_current(free);
        self.free_current = current.iter().copied().collect();
        self.free_checked = Some(Instant::now());
        current
    }
}

impl Engine {
    /// Sends `RegionOwners` to every session whose view's regions or
    /// their holders changed since it was last told.
    pub(super) fn tell_owners(&mut self) {
        let now = Instant::now();
        if !self.store.clustered() || now < self.owners_due {
            return;
        }
        self.owners_due = now + OWNERS_EVERY;
        let side = self.seq.region_chunks();
        let node = self.store.node_id().unwrap_or_default();
        let views: Vec<(u64, BTreeSet<RegionId>)> = self
            .peers
            .iter()
            .filter_map(|(&id, p)| {
                let center = p.interest.center()?;
                Some((id, view_regions(center, p.interest.radius(), side)))
            })
            .collect();
        // Every session's regions in one call: one query at most for all
        // the holders not cached.
        let all: BTreeSet<RegionId> = views.iter().flat_map(|(_, r)| r.iter().copied()).collect();
        let holders: BTreeMap<RegionId, RegionHolder> = match self.store.region_holders(&all) {
            Ok(h) => h.into_iter().collect(),
            Err(e) => {
                self.store_failed(&e);
                error!(error = %e, "reading region holders failed");
                self.free_regions.clear();
                return;
            }
        };
        // Positions are swept through free regions (and this node's), once
        // this node's copies of them are current.
        let free: BTreeSet<RegionId> = holders
            .iter()
            .filter(|(_, h)| matches!(h, RegionHolder::Free))
            .map(|(r, _)| *r)
            .collect();
        self.free_regions = self.current_free(&free).into_iter().collect();
        for (session, regions) in views {
            let owners: Vec<RegionOwner> = regions
                .iter()
                .filter_map(|r| Some(to_wire(*r, holders.get(r)?.clone())))
                .collect();
            let Some(peer) = self.peers.get(&session) else {
                continue;
            };
            let now = now_ms();
            let placed = self.seq.position(session).is_some();
            let stale = placed
                && peer
                    .ticket_ms
                    .is_none_or(|at| now.saturating_sub(at) >= TICKET_REFRESH_MS);
            if peer.owners_told == owners && !stale {
                continue;
            }
            let ticket = self.ticket(session);
            let Some(peer) = self.peers.get_mut(&session) else {
                continue;
            };
            peer.owners_told = owners.clone();
            // When minted (a ticket of an unreported position keeps an
            // older time).
            peer.ticket_ms = ticket.as_ref().map(|_| now);
            self.send_control(
                session,
                &ServerMessage::RegionOwners {
                    region_chunks: side,
                    regions: owners,
                    ticket,
                    node: node.clone(),
                },
            );
        }
    }

    /// A ticket for the session's player where this node last judged it
    /// (see `Session::judged`), timed when the player was known there: its report to
    /// this node, or the ticket or resume that placed it. Never now: a
    /// session parked on this node, reporting here no more while the
    /// player walks on through another node, would get a fresh ticket for
    /// its old spot at every refresh, one that outdates the positions it
    /// reports there: a teleport back.
    fn ticket(&self, session: u64) -> Option<strata_protocol::Ticket> {
        let key = self.ticket_key.as_ref()?;
        let player = &self.seq.session(session)?.player;
        // Where this node last judged it: a player that walked on into
        // another node's region (air to this one) is swept there from
        // the border it crossed, not placed where it claims to be.
        let p = self.seq.judged_position(session)?;
        Some(crate::cluster::ticket::mint(
            key, player, p.feet, p.known_ms,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_view_at_the_coordinates_ends_does_not_overflow() {
        for c in [i32::MAX, i32::MIN] {
            let regions = view_regions(ChunkPos::new(c, 0, c), 32, 8);
            assert!(!regions.is_empty() && regions.len() <= MAX_REGION_OWNERS);
            assert!(regions.contains(&RegionId::of(ChunkPos::new(c, 0, c), 8)));
        }
    }

    #[test]
    fn a_view_overlaps_the_regions_its_square_touches() {
        // Chunk 7 with radius 2 spans chunks 5..=9: regions 0 and 1 of 8.
        let r = view_regions(ChunkPos::new(7, 0, 7), 2, 8);
        let want: BTreeSet<RegionId> = [(0, 0), (1, 0), (0, 1), (1, 1)]
            .into_iter()
            .map(|(x, z)| RegionId { x, z })
            .collect();
        assert_eq!(r, want);
        assert_eq!(view_regions(ChunkPos::new(3, 0, 3), 2, 8).len(), 1);
    }

    #[test]
    fn a_huge_view_of_tiny_regions_names_only_the_nearest() {
        let r = view_regions(ChunkPos::new(0, 0, 0), 32, 1);
        assert_eq!(r.len(), MAX_REGION_OWNERS);
        assert!(r.contains(&RegionId { x: 0, z: 0 }));
        assert!(r.contains(&RegionId { x: 7, z: -7 }));
        assert!(!r.contains(&RegionId { x: 32, z: 32 }));
    }
}
