//! `Sequencer::submit`: every validation rule, in order, before queueing.

use strata_protocol::{EditRequest, RejectReason};
use strata_terrain::{ChunkPos, Edit, VoxelBox};

use super::residency::{edit_footprint, with_neighbours};
use super::session::PlayerLimits;
use super::{Queued, Sequencer};
use crate::validate::{caps, line_of_sight, permissions, position, reach, zones};

/// What the cheap rules worked out, for the rest of the checks.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Cheap {
    pub(super) eye: glam::DVec3,
    pub(super) target: glam::DVec3,
    pub(super) volume_cost: u64,
    pub(super) bbox: VoxelBox,
}

/// An edit that passed [`Sequencer::precheck`], with what the rest of its
/// checks read: worked out once, for loading and for
/// [`Sequencer::admit_prechecked`].
#[derive(Debug, Clone, PartialEq)]
pub struct Prechecked {
    pub(super) cheap: Cheap,
    /// The chunks the sight ray crosses.
    pub(super) ray: Vec<ChunkPos>,
    /// Sorted: the edit's box and read margin, the ray's chunks and their
    /// neighbours.
    reads: Vec<ChunkPos>,
}

impl Prechecked {
    /// Every chunk admitting and applying the edit reads, sorted.
    pub fn reads(&self) -> &[ChunkPos] {
        &self.reads
    }

    /// The chunks the sight ray crosses, whose collision meshes its check
    /// reads.
    pub fn ray(&self) -> &[ChunkPos] {
        &self.ray
    }
}

/// The chunks of the box `lo..=hi` and the 27 around each of `ray`'s,
/// sorted and without repeats: listed in order over their bounds, no sort
/// (the ray ends at the edit, so the bounds are the box and a little).
fn box_and_ray(lo: ChunkPos, hi: ChunkPos, ray: &[ChunkPos]) -> Vec<ChunkPos> {
    let (mut a, mut b) = (lo, hi);
    for r in ray {
        a = ChunkPos::new(
            a.x.min(r.x.saturating_sub(1)),
            a.y.min(r.y.saturating_sub(1)),
            a.z.min(r.z.saturating_sub(1)),
        );
        b = ChunkPos::new(
            b.x.max(r.x.saturating_add(1)),
            b.y.max(r.y.saturating_add(1)),
            b.z.max(r.z.saturating_add(1)),
        );
    }
    let in_box = |p: ChunkPos| {
        (lo.x..=hi.x).contains(&p.x) && (lo.y..=hi.y).contains(&p.y) && (lo.z..=hi.z).contains(&p.z)
    };
    let near_ray = |p: ChunkPos| near_any(ray, p);
    let span = |lo: i32, hi: i32| u64::from(hi.abs_diff(lo)) + 1;
    let volume = |a: ChunkPos, b: ChunkPos| {
        span(a.x, b.x)
            .saturating_mul(span(a.y, b.y))
            .saturating_mul(span(a.z, b.z))
    };
    let listed = volume(lo, hi).saturating_add(27 * ray.len() as u64);
    if volume(a, b) > listed.saturating_mul(4) {
        // A long ray (a large `reach`) spans far more than it touches.
        return sorted_union(lo, hi, ray);
    }
    // `ChunkPos` orders by x, then y, then z.
    let mut out = Vec::new();
    for x in a.x..=b.x {
        for y in a.y..=b.y {
            for z in a.z..=b.z {
                let p = ChunkPos::new(x, y, z);
                if in_box(p) || near_ray(p) {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// Whether `p` is one of `chunks` or touches one (the 27 around each).
pub(super) fn near_any(chunks: &[ChunkPos], p: ChunkPos) -> bool {
    chunks
        .iter()
        .any(|r| r.x.abs_diff(p.x) <= 1 && r.y.abs_diff(p.y) <= 1 && r.z.abs_diff(p.z) <= 1)
}

/// [`box_and_ray`] by collecting, sorting and deduplicating.
fn sorted_union(lo: ChunkPos, hi: ChunkPos, ray: &[ChunkPos]) -> Vec<ChunkPos> {
    let mut v: Vec<ChunkPos> = (lo.x..=hi.x)
        .flat_map(|x| {
            (lo.y..=hi.y).flat_map(move |y| (lo.z..=hi.z).map(move |z| ChunkPos::new(x, y, z)))
        })
        .collect();
    for &r in ray {
        v.extend(with_neighbours(r));
    }
    v.sort_unstable();
    v.dedup();
    v
}

/// The chunks of an edit's footprint (its box, read margin and mesh
/// apron) and the 27 around each of `ray`'s, sorted.
fn footprint_and_ray(bbox: &VoxelBox, margin: i32, ray: &[ChunkPos]) -> Vec<ChunkPos> {
    let footprint = edit_footprint(bbox, margin);
    box_and_ray(footprint.min.chunk(), footprint.max.chunk(), ray)
}

impl Sequencer {
    /// Everything validating and applying `edit` reads, given the eye (if any).
    /// `None` if the terrain core refuses the edit.
    pub(super) fn read_set(&self, edit: &Edit, eye: Option<glam::DVec3>) -> Option<Vec<ChunkPos>> {
        let (lo, hi, ray) = self.read_bounds(edit, eye)?;
        Some(box_and_ray(lo, hi, &ray))
    }

    /// What [`Self::read_set`] lists, as the footprint's corner chunks and
    /// the chunks of the line of sight (the set adds the 27 around each).
    pub(super) fn read_bounds(
        &self,
        edit: &Edit,
        eye: Option<glam::DVec3>,
    ) -> Option<(ChunkPos, ChunkPos, Vec<ChunkPos>)> {
        let bbox = edit.validate(&self.ctx()).ok()?;
        let ray = eye
            .map(|eye| (eye, reach::target_point(edit, &bbox, eye)))
            .filter(|(eye, target)| eye.distance(*target) <= self.validation.reach)
            .map_or_else(Vec::new, |(eye, target)| {
                line_of_sight::sight_chunks(eye, target)
            });
        let footprint = edit_footprint(&bbox, edit.read_margin());
        Some((footprint.min.chunk(), footprint.max.chunk(), ray))
    }

    /// The rules of [`Self::submit`] that read no terrain: role permission,
    /// radius/power caps, the terrain core's own validation, a validated
    /// position, reach, vertical bounds, protected zones, the rate buckets
    /// and queue capacity. The engine runs them before it loads or
    /// generates any chunk the edit would read. A refusal costs the player
    /// an edit token (see [`Self::submit`]).
    pub fn precheck(
        &mut self,
        session_id: u64,
        edit: &Edit,
        now_ms: u64,
    ) -> Result<Prechecked, RejectReason> {
        let cheap = match self.cheap_checks(session_id, edit, now_ms) {
            Ok(c) => c,
            Err(r) => return Err(self.rejected(session_id, r, now_ms)),
        };
        let ray = line_of_sight::sight_chunks(cheap.eye, cheap.target);
        let reads = footprint_and_ray(&cheap.bbox, edit.read_margin(), &ray);
        Ok(Prechecked { cheap, ray, reads })
    }

    /// Validates an edit request and queues it for the next tick.
    ///
    /// Rules, in order (the first failure names the reason): everything
    /// [`Self::precheck`] checks, then line of sight, whose chunks from
    /// [`Self::chunks_needed`] must be resident (or the request is `Busy`).
    /// A rejected request changes nothing but the player's budgets: it
    /// costs one edit token (if any is left), so a stream of refused edits
    /// is throttled like accepted ones, and one rejection token; a player
    /// out of rejection tokens is listed by [`Self::take_disconnects`].
    /// `Busy` (a full queue or chunks still loading) costs nothing.
    pub fn submit(
        &mut self,
        session_id: u64,
        request: EditRequest,
        now_ms: u64,
    ) -> Result<(), RejectReason> {
        match self.checks(session_id, &request.edit, now_ms) {
            Ok(cost) => {
                self.queue_edit(session_id, request, cost);
                Ok(())
            }
            Err(r) => Err(self.rejected(session_id, r, now_ms)),
        }
    }

    /// Every rule; returns the edit's volume cost.
    fn checks(&mut self, session_id: u64, edit: &Edit, now_ms: u64) -> Result<u64, RejectReason> {
        let c = self.cheap_checks(session_id, edit, now_ms)?;
        self.check_sight(edit, c.eye, c.target)?;
        Ok(c.volume_cost)
    }

    pub(super) fn cheap_checks(
        &mut self,
        session_id: u64,
        edit: &Edit,
        now_ms: u64,
    ) -> Result<Cheap, RejectReason> {
        let session = self
            .sessions
            .get(&session_id)
            .ok_or_else(|| RejectReason::Invalid {
                message: "unknown session".to_string(),
            })?;
        let (role, feet) = (session.role, session.position);
        let v = &self.validation;
        permissions::check(role, edit.kind(), &v.player_kinds)?;
        caps::check(edit, v.max_radius_fixed(), v.max_power_capped())?;
        // Before validation, which walks a structure's template: a flood of
        // edits costs a bucket lookup each once the bucket is empty.
        if !self.limits_of(session_id, now_ms).edits.can_take(1) {
            return Err(RejectReason::RateLimited);
        }
        let v = &self.validation;
        let bbox = edit
            .validate(&self.ctx())
            .map_err(|e| RejectReason::Invalid {
                message: e.to_string(),
            })?;
        let feet = feet.ok_or(RejectReason::NoPosition)?;
        let eye = position::eye(feet.feet, v);
        let target = reach::target_point(edit, &bbox, eye);
        reach::check(eye, target, v.reach)?;
        v.bounds.check_box(&bbox)?;
        zones::check(&self.zones, role, &bbox)?;
        let volume_cost =
            v.volume_weight
                .charge(edit.kind(), bbox.volume(), v.volume_rate.capacity);
        let limits = self.limits_of(session_id, now_ms);
        if !limits.volume.can_take(volume_cost) {
            return Err(RejectReason::VolumeRateLimited);
        }
        if self.queue.len() + self.sighting.len() >= self.cfg.queue_capacity {
            return Err(RejectReason::Busy);
        }
        Ok(Cheap {
            eye,
            target,
            volume_cost,
            bbox,
        })
    }

    /// The player's buckets, refilled to `now_ms`.
    pub(super) fn limits_of(&mut self, session_id: u64, now_ms: u64) -> &mut PlayerLimits {
        let player = self
            .sessions
            .get(&session_id)
            .map_or("", |s| s.player.as_str());
        // A lookup first: the key is allocated only for a new player.
        if !self.limits.contains_key(player) {
            let fresh = PlayerLimits::new(&self.validation, now_ms);
            self.limits.insert(player.to_string(), fresh);
        }
        let limits = self
            .limits
            .get_mut(player)
            .expect("inserted above when missing");
        limits.refill(now_ms);
        limits
    }

    /// [`Self::rejected`] for a refusal decided outside the sequencer (a
    /// region another cluster node holds).
    pub fn charge_refusal(
        &mut self,
        session_id: u64,
        reason: RejectReason,
        now_ms: u64,
    ) -> RejectReason {
        self.rejected(session_id, reason, now_ms)
    }

    /// Charges a refusal to the player's budgets; returns `reason`. `Busy`
    /// is the server's state, not the player's doing, and costs nothing.
    pub(super) fn rejected(
        &mut self,
        session_id: u64,
        reason: RejectReason,
        now_ms: u64,
    ) -> RejectReason {
        if reason == RejectReason::Busy || !self.sessions.contains_key(&session_id) {
            return reason;
        }
        let limits = self.limits_of(session_id, now_ms);
        limits.edits.take(1);
        if !limits.rejections.take(1) && !self.disconnect.contains(&session_id) {
            self.disconnect.push(session_id);
        }
        reason
    }

    fn queue_edit(&mut self, session_id: u64, request: EditRequest, volume_cost: u64) {
        let Some(player) = self.sessions.get(&session_id).map(|s| s.player.clone()) else {
            return;
        };
        if let Some(limits) = self.limits.get_mut(&player) {
            limits.edits.take(1);
            limits.volume.take(volume_cost);
        }
        self.queue.push_back(Queued {
            session_id,
            player,
            request,
            volume_cost,
            queued_at: std::time::Instant::now(),
            ray: Vec::new(),
        });
    }

    /// Sessions whose player ran out of rejection tokens since the last
    /// call: the shell disconnects them.
    pub fn take_disconnects(&mut self) -> Vec<u64> {
        std::mem::take(&mut self.disconnect)
    }

    /// Residency of everything the edit reads, then the line-of-sight ray
    /// against collision meshes built for the current chunk versions.
    fn check_sight(
        &mut self,
        edit: &Edit,
        eye: glam::DVec3,
        target: glam::DVec3,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_and_ray_lists_the_sorted_union() {
        let c = ChunkPos::new;
        // A diagonal ray of 40 chunks: its bounds would be 42³ chunks, so
        // the union is sorted instead of listed.
        let long: Vec<ChunkPos> = (0..40).map(|i| c(i, i, i)).collect();
        let cases: [(ChunkPos, ChunkPos, Vec<ChunkPos>); 6] = [
            (c(0, 0, 0), c(2, 2, 2), vec![]),
            (c(0, 0, 0), c(2, 2, 2), vec![c(1, 1, 1)]),
            (
                c(3, -1, 3),
                c(5, 1, 5),
                vec![c(1, 0, 2), c(2, 0, 3), c(3, 0, 3)],
            ),
            (
                c(-4, -4, -4),
                c(-4, -4, -4),
                vec![c(-6, -2, -5), c(-5, -3, -5)],
            ),
            (c(10, 0, 0), c(11, 0, 0), vec![c(0, 5, 0)]),
            (c(38, 38, 38), c(40, 40, 40), long),
        ];
        for (lo, hi, ray) in cases {
            assert_eq!(
                box_and_ray(lo, hi, &ray),
                sorted_union(lo, hi, &ray),
                "{lo:?} {hi:?} {ray:?}"
            );
        }
    }
}
