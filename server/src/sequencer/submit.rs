//! `Sequencer::submit`: every validation rule, in order, before queueing.

use strata_protocol::{EditRequest, RejectReason};
use strata_terrain::{ChunkPos, Edit};

use super::residency::{edit_chunks, with_neighbours};
use super::session::PlayerLimits;
use super::{Queued, Sequencer};
use crate::validate::{caps, line_of_sight, permissions, position, reach, zones};

impl Sequencer {
    /// Everything validating and applying `edit` reads, given the eye (if any).
    /// `None` if the terrain core refuses the edit.
    pub(super) fn read_set(&self, edit: &Edit, eye: Option<[f64; 3]>) -> Option<Vec<ChunkPos>> {
        let bbox = edit.validate(&self.ctx()).ok()?;
        let mut set: Vec<ChunkPos> = edit_chunks(&bbox, edit.read_margin()).collect();
        if let Some(eye) = eye {
            let target = reach::target_point(edit, &bbox, eye);
            if reach::distance(eye, target) <= self.validation.reach {
                for c in line_of_sight::sight_chunks(eye, target) {
                    set.extend(with_neighbours(c));
                }
            }
        }
        set.sort();
        set.dedup();
        Some(set)
    }

    /// Validates an edit request and queues it for the next tick.
    ///
    /// Rules, in order (the first failure names the reason): role permission,
    /// radius/power caps, the terrain core's own validation, a validated
    /// position, reach, line of sight, vertical bounds, protected zones,
    /// edits-per-second and voxels-per-second buckets, queue capacity. A
    /// rejected request changes nothing (not even the buckets). Chunks from
    /// [`Self::chunks_needed`] must be resident, or the request is `Busy`.
    pub fn submit(
        &mut self,
        session_id: u64,
        request: EditRequest,
        now_ms: u64,
    ) -> Result<(), RejectReason> {
        let session = self
            .sessions
            .get(&session_id)
            .ok_or_else(|| RejectReason::Invalid {
                message: "unknown session".to_string(),
            })?;
        let (role, player, feet) = (session.role, session.player.clone(), session.position);
        let edit = &request.edit;
        let v = &self.validation;

        permissions::check(role, edit.kind(), &v.player_kinds)?;
        caps::check(edit, v.max_radius_fixed(), v.max_power_capped())?;
        let bbox = edit
            .validate(&self.ctx())
            .map_err(|e| RejectReason::Invalid {
                message: e.to_string(),
            })?;
        let feet = feet.ok_or(RejectReason::NoPosition)?;
        let eye = position::eye(feet.feet, v);
        let target = reach::target_point(edit, &bbox, eye);
        reach::check(eye, target, v.reach)?;

        self.check_sight(edit, eye, target)?;

        let v = &self.validation;
        v.bounds.check_box(&bbox)?;
        zones::check(&self.zones, role, &bbox)?;
        let volume_cost = bbox.volume().min(v.volume_rate.capacity);
        let limits = self
            .limits
            .entry(player.clone())
            .or_insert_with(|| PlayerLimits::new(v, now_ms));
        limits.edits.refill(now_ms);
        limits.volume.refill(now_ms);
        if !limits.edits.can_take(1) {
            return Err(RejectReason::RateLimited);
        }
        if !limits.volume.can_take(volume_cost) {
            return Err(RejectReason::VolumeRateLimited);
        }
        if self.queue.len() >= self.cfg.queue_capacity {
            return Err(RejectReason::Busy);
        }
        limits.edits.take(1);
        limits.volume.take(volume_cost);
        self.queue.push_back(Queued {
            session_id,
            player,
            request,
            queued_at: std::time::Instant::now(),
        });
        Ok(())
    }

    /// Residency of everything the edit reads, then the line-of-sight ray
    /// against collision meshes built for the current chunk versions.
    fn check_sight(
        &mut self,
        edit: &Edit,
        eye: [f64; 3],
        target: [f64; 3],
    ) -> Result<(), RejectReason> {
        let needed = self.read_set(edit, Some(eye)).unwrap_or_default();
        if !self
            .residency
            .missing(&self.world, needed.iter().copied())
            .is_empty()
        {
            return Err(RejectReason::Busy);
        }
        let ray = line_of_sight::sight_chunks(eye, target);
        self.world
            .load(ray.iter().flat_map(|c| with_neighbours(*c)));
        self.collision.ensure(&self.world, &ray);
        let tolerance = edit.radius().map_or(0.0, |r| r.to_f64()) + self.validation.los_tolerance;
        line_of_sight::check(&self.collision, eye, target, tolerance)?;
        Ok(())
    }
}
