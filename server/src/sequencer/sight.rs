//! Line of sight for a batch: [`Sequencer::admit`] runs every other rule
//! when an edit arrives, and [`Sequencer::check_sighted`] checks the sight
//! of all those admitted since, in parallel, just before the tick applies
//! them. The engine thread then spends a lookup per edit, not a mesh
//! build and a raycast.
//!
//! The decisions are [`Sequencer::submit`]'s, in arrival order, with one
//! difference: the sight is checked against the world as it stands when
//! the batch is checked (no edit applies between arrival and the check,
//! so that is the world the edit would apply to). The edit token is taken
//! on admission (accepted and refused edits both cost one), and so is the
//! volume, given back if the sight check refuses.

use rayon::prelude::*;
use strata_protocol::{EditRequest, RejectReason};
use strata_terrain::ChunkPos;

use super::submit::{near_any, Prechecked};
use super::{Queued, Sequencer};
use crate::validate::line_of_sight;

/// An edit that passed every rule but line of sight.
#[derive(Debug, Clone)]
pub(super) struct Sighted {
    pub(super) session_id: u64,
    pub(super) player: String,
    pub(super) request: EditRequest,
    pub(super) eye: glam::DVec3,
    target: glam::DVec3,
    tolerance: f64,
    pub(super) volume_cost: u64,
    pub(super) ray: Vec<ChunkPos>,
    queued_at: std::time::Instant,
}

/// An edit [`Sequencer::check_sighted`] refused.
#[derive(Debug, Clone, PartialEq)]
pub struct SightRefusal {
    pub session_id: u64,
    pub client_edit_id: u64,
    pub reason: RejectReason,
}

impl Sequencer {
    /// Every rule of [`Self::submit`] but line of sight, whose chunks must
    /// be resident (or the request is `Busy`); the edit then waits for
    /// [`Self::check_sighted`]. A refusal here costs what `submit`'s does.
    pub fn admit(
        &mut self,
        session_id: u64,
        request: EditRequest,
        now_ms: u64,
    ) -> Result<(), RejectReason> {
        let pre = self.precheck(session_id, &request.edit, now_ms)?;
        self.admit_prechecked(session_id, request, pre, now_ms)
    }

    /// [`Self::admit`] for an edit that passed [`Self::precheck`] just now
    /// (nothing but loads since): its rules are not run again.
    pub fn admit_prechecked(
        &mut self,
        session_id: u64,
        request: EditRequest,
        pre: Prechecked,
        now_ms: u64,
    ) -> Result<(), RejectReason> {
        let edit = &request.edit;
        // One look at each chunk read: one not resident makes the edit
        // wait; the ray's neighbourhoods are loaded (generated) for its
        // meshes.
        let mut generate = Vec::new();
        for &p in pre.reads() {
            if self.world.peek(p).is_some() {
                continue;
            }
            if !self.residency.may_generate(p) {
                return Err(self.rejected(session_id, RejectReason::Busy, now_ms));
            }
            if near_any(&pre.ray, p) {
                generate.push(p);
            }
        }
        self.world.load(generate);
        let Prechecked { cheap, ray, .. } = pre;
        let tolerance = edit.radius().map_or(0.0, |r| r.to_f64()) + self.validation.los_tolerance;
        let limits = self.limits_of(session_id, now_ms);
        limits.edits.take(1);
        limits.volume.take(cheap.volume_cost);
        let player = self
            .sessions
            .get(&session_id)
            .map(|s| s.player.clone())
            .unwrap_or_default();
        self.sighting.push(Sighted {
            session_id,
            player,
            request,
            eye: cheap.eye,
            target: cheap.target,
            tolerance,
            volume_cost: cheap.volume_cost,
            ray,
            queued_at: std::time::Instant::now(),
        });
        Ok(())
    }

    /// Edits admitted and not yet checked.
    pub fn sighting(&self) -> usize {
        self.sighting.len()
    }

    /// Checks the sight of every admitted edit: the meshes their rays
    /// cross are built first (in parallel), then the rays are cast in
    /// parallel on the current rayon pool. Seen edits are queued in
    /// arrival order; the others are returned, charged a rejection token
    /// (their volume given back). Rays are checked in groups whose chunks
    /// fit in half the mesh cache, so none is evicted before its ray.
    pub fn check_sighted(&mut self, now_ms: u64) -> Vec<SightRefusal> {
        let batch = std::mem::take(&mut self.sighting);
        let room = (self.collision.capacity() / 2).max(1);
        let mut seen: Vec<Result<(), RejectReason>> = Vec::with_capacity(batch.len());
        let mut rest = batch.as_slice();
        while !rest.is_empty() {
            let mut chunks: Vec<ChunkPos> = Vec::new();
            let mut n = 0;
            while n < rest.len() && (n == 0 || chunks.len() + rest[n].ray.len() <= room) {
                chunks.extend(&rest[n].ray);
                n += 1;
            }
            let (group, tail) = rest.split_at(n);
            rest = tail;
            chunks.sort_unstable();
            chunks.dedup();
            self.collision.ensure(&self.world, &chunks);
            let cast =
                |s: &Sighted| line_of_sight::check(&self.collision, s.eye, s.target, s.tolerance);
            if group.len() > 1 {
                seen.par_extend(group.par_iter().map(cast));
            } else {
                seen.extend(group.iter().map(cast));
            }
        }
        let mut refused = Vec::new();
        for (s, result) in batch.into_iter().zip(seen) {
            match result {
                Ok(()) => self.queue.push_back(Queued {
                    session_id: s.session_id,
                    player: s.player,
                    request: s.request,
                    volume_cost: s.volume_cost,
                    queued_at: s.queued_at,
                    ray: s.ray,
                }),
                Err(reason) => {
                    self.refuse_sighted(&s, now_ms);
                    refused.push(SightRefusal {
                        session_id: s.session_id,
                        client_edit_id: s.request.client_edit_id,
                        reason,
                    });
                }
            }
        }
        refused
    }

    /// The rest of a refusal's cost: the edit token went on admission.
    fn refuse_sighted(&mut self, s: &Sighted, now_ms: u64) {
        let Some(limits) = self.limits.get_mut(&s.player) else {
            return;
        };
        limits.refill(now_ms);
        limits.volume.give(s.volume_cost);
        let live = self.sessions.contains_key(&s.session_id);
        if live && !limits.rejections.take(1) && !self.disconnect.contains(&s.session_id) {
            self.disconnect.push(s.session_id);
        }
    }
}
