//! Which chunks each session receives: a cube of chunks around its centre.
//!
//! The centre follows the last accepted position unless the client sent an
//! explicit `Subscribe`. New chunks come nearest first (the shell sends them
//! under its per-tick byte budget); chunks are dropped only once they are
//! beyond `radius + hysteresis`, so walking back and forth over a chunk
//! border does not resend the same chunks, and the centre moves to a new
//! chunk only once the feet are [`RECENTRE_MARGIN`] voxels past the old
//! one, so it does not re-centre (a walk over the whole view) at every
//! crossing either. Rows outside the world's vertical
//! bounds are never subscribed. A player's subscription stays near its
//! last accepted position or, before one, near its start ([`Anchor`]):
//! its cube reaches at most `view_radius + hysteresis` chunks from there
//! when accepted, and an accepted position [`RECENTRE_MARGIN`] voxels
//! past where it reaches no farther moves it to the position's chunk (its
//! radius kept).

use std::collections::BTreeSet;

use serde::{Deserialize, Serialize};
use strata_protocol::Start;
use strata_terrain::edit::FixedVec3;
use strata_terrain::{ChunkPos, CHUNK_SIZE};

use crate::validate::WorldBounds;

/// Default view radius in chunks (Chebyshev), also the cap for `Subscribe`.
pub const DEFAULT_VIEW_RADIUS: u8 = 8;
/// Extra chunks beyond the radius before a chunk is unsubscribed.
pub const DEFAULT_HYSTERESIS: u8 = 2;
/// Largest view radius a config may set (a radius-32 cube is 274,625 chunks).
pub const MAX_VIEW_RADIUS: u8 = 32;
/// Largest hysteresis a config may set: a session keeps chunks out to
/// `view_radius + hysteresis`, so this bounds what walking away leaves held.
pub const MAX_HYSTERESIS: u8 = 16;

/// Voxels the feet must be past the centre chunk before the view
/// re-centres: walking to and fro over a chunk border re-centres once per
/// `2 * RECENTRE_MARGIN` voxels walked at most, not at every crossing.
pub const RECENTRE_MARGIN: i32 = 4;

/// The `[interest]` config section.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InterestConfig {
    /// See [`DEFAULT_VIEW_RADIUS`]; clamped to [`MAX_VIEW_RADIUS`].
    pub view_radius: u8,
    /// See [`DEFAULT_HYSTERESIS`].
    pub hysteresis: u8,
}

impl Default for InterestConfig {
    fn default() -> Self {
        Self {
            view_radius: DEFAULT_VIEW_RADIUS,
            hysteresis: DEFAULT_HYSTERESIS,
        }
    }
}

impl InterestConfig {
    pub fn radius(&self) -> u8 {
        self.view_radius.min(MAX_VIEW_RADIUS)
    }
}

/// What changed in a session's interest set.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct InterestChange {
    /// Newly covered chunks, nearest to the centre first.
    pub subscribe: Vec<ChunkPos>,
    /// Chunks no longer covered, in position order.
    pub unsubscribe: Vec<ChunkPos>,
    /// The centre or radius changed: a new view is owed its
    /// `InterestComplete` once its chunks are sent.
    pub recentred: bool,
}

impl InterestChange {
    pub fn is_empty(&self) -> bool {
        self.subscribe.is_empty() && self.unsubscribe.is_empty()
    }
}

/// What a player's `Subscribe` centre must stay near.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Anchor {
    /// The chunk of the last accepted position (or a resumed one).
    Chunk(ChunkPos),
    /// No position yet: the chunk columns of the spawn square, where the
    /// first position may be (any row).
    Spawn { x: i32, z: i32, radius: u32 },
}

impl Anchor {
    /// The anchor of a session with no accepted position, from its start.
    pub fn of_start(start: Start) -> Self {
        match start {
            Start::Resume { feet } => {
                Anchor::Chunk(crate::validate::position::feet_voxel(feet).chunk())
            }
            Start::Spawn { x, z, radius } => Anchor::Spawn { x, z, radius },
        }
    }

    /// Chebyshev distance in chunks from `c` to the anchor.
    fn distance(self, c: ChunkPos) -> u64 {
        match self {
            Anchor::Chunk(near) => u64::from(c.chebyshev(near)),
            Anchor::Spawn { x, z, radius } => {
                // Distance from a coordinate to the chunks spanning a range of voxels.
                let to_span = |v: i32, mid: i32| {
                    let chunk = |w: i64| w.div_euclid(CHUNK_SIZE as i64);
                    let (lo, hi) = (mid as i64 - radius as i64, mid as i64 + radius as i64);
                    let v = v as i64;
                    (chunk(lo) - v).max(v - chunk(hi)).max(0) as u64
                };
                to_span(c.x, x).max(to_span(c.z, z))
            }
        }
    }
}

/// Who chose the centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Explicit {
    /// Nobody: the centre follows positions.
    No,
    /// A player's `Subscribe`: kept while it stays within reach of the
    /// player's accepted positions.
    Near,
    /// An admin's `Subscribe`: kept wherever the admin goes.
    Anywhere,
}

/// One session's interest set.
#[derive(Debug, Clone)]
pub struct Interest {
    cfg: InterestConfig,
    bounds: WorldBounds,
    center: Option<ChunkPos>,
    radius: u8,
    /// Set by an explicit `Subscribe`; positions then no longer move the
    /// centre (a player's, while it stays within reach).
    explicit: Explicit,
    subscribed: BTreeSet<ChunkPos>,
}

impl Interest {
    pub fn new(cfg: InterestConfig, bounds: WorldBounds) -> Self {
        Self {
            cfg,
            bounds,
            center: None,
            radius: cfg.radius(),
            explicit: Explicit::No,
            subscribed: BTreeSet::new(),
        }
    }

    pub fn center(&self) -> Option<ChunkPos> {
        self.center
    }

    pub fn radius(&self) -> u8 {
        self.radius
    }

    /// Follows an accepted feet position. After an explicit subscribe it
    /// keeps that view instead, a player's only while the view stays
    /// within reach of the feet' chunk ([`Self::within_reach`]): once the
    /// feet are [`RECENTRE_MARGIN`] voxels past that, the view moves to
    /// the feet' chunk, keeping the radius asked for.
    pub fn follow_position(&mut self, feet: FixedVec3) -> InterestChange {
        let voxel = crate::validate::position::feet_voxel(feet);
        let chunk = voxel.chunk();
        let r = self.cfg.radius();
        match self.explicit {
            Explicit::Anywhere => return InterestChange::default(),
            Explicit::Near => {
                // Kept while the feet are in reach of it, or fewer than
                // RECENTRE_MARGIN voxels past that (with no hysteresis a
                // view of the whole radius is in reach of one chunk only,
                // and flipping over its border would move it each time).
                let reach = self.max_centre_distance(self.radius);
                let kept = self
                    .center
                    .is_some_and(|c| voxels_past_cube(voxel, c, reach) < RECENTRE_MARGIN);
                if kept {
                    return InterestChange::default();
                }
                // Out of reach: the view moves to the feet, at the radius
                // the player asked for.
                return self.recenter(chunk, self.radius);
            }
            Explicit::No => {}
        }
        if let Some(c) = self.center {
            if chunk != c && self.radius == r && voxels_past(voxel, c) < RECENTRE_MARGIN {
                return InterestChange::default();
            }
        }
        self.recenter(chunk, r)
    }

    /// Whether a view of `center` and `radius` (capped at the view radius)
    /// reaches no farther than `view_radius + hysteresis` chunks
    /// (Chebyshev) from `anchor`: what a player's own view, re-centred
    /// lazily and kept with its hysteresis, may reach.
    pub fn within_reach(&self, center: ChunkPos, radius: u8, anchor: Anchor) -> bool {
        anchor.distance(center) <= u64::from(self.max_centre_distance(radius))
    }

    /// How far (Chebyshev, in chunks) from its anchor a player's view of
    /// `radius` may be centred: `view_radius + hysteresis - min(radius,
    /// view_radius)`.
    fn max_centre_distance(&self, radius: u8) -> u8 {
        let r = self.cfg.radius();
        r.saturating_add(self.cfg.hysteresis) - radius.min(r)
    }

    /// Whether a player's `Subscribe` of `center` and `radius` may be
    /// accepted: its view within reach of `anchor`
    /// ([`Self::within_reach`]). `Err` carries the farthest allowed
    /// centre distance for that radius.
    pub fn check_centre(&self, center: ChunkPos, radius: u8, anchor: Anchor) -> Result<(), u8> {
        if self.within_reach(center, radius, anchor) {
            Ok(())
        } else {
            Err(self.max_centre_distance(radius))
        }
    }

    /// A player's explicit `Subscribe`; the radius is capped by the
    /// config's view radius. Positions then no longer move the centre
    /// while the view stays within reach of them.
    pub fn subscribe(&mut self, center: ChunkPos, radius: u8) -> InterestChange {
        self.explicit = Explicit::Near;
        let r = radius.min(self.cfg.radius());
        self.recenter(center, r)
    }

    /// An admin's explicit `Subscribe`: kept wherever the admin goes.
    pub fn subscribe_anywhere(&mut self, center: ChunkPos, radius: u8) -> InterestChange {
        let change = self.subscribe(center, radius);
        self.explicit = Explicit::Anywhere;
        change
    }

    /// Whether deltas of `pos` go to this session.
    pub fn covers(&self, pos: ChunkPos) -> bool {
        self.may_cover(pos) && self.subscribed.contains(&pos)
    }

    /// Whether `pos` is within the keep distance of the center, where every
    /// subscribed chunk lies: false rules out [`Self::covers`] with no
    /// lookup at all, which is how most sessions miss most changes.
    #[inline]
    pub fn may_cover(&self, pos: ChunkPos) -> bool {
        let keep = self.radius as u32 + self.cfg.hysteresis as u32;
        self.center.is_some_and(|c| pos.chebyshev(c) <= keep)
    }

    /// Every covered chunk, in position order.
    pub fn subscribed(&self) -> impl Iterator<Item = ChunkPos> + '_ {
        self.subscribed.iter().copied()
    }

    fn recenter(&mut self, center: ChunkPos, radius: u8) -> InterestChange {
        if self.center == Some(center) && self.radius == radius {
            return InterestChange::default();
        }
        self.center = Some(center);
        self.radius = radius;
        let keep = radius as u32 + self.cfg.hysteresis as u32;
        let unsubscribe: Vec<ChunkPos> = self
            .subscribed
            .iter()
            .copied()
            .filter(|p| p.chebyshev(center) > keep)
            .collect();
        for p in &unsubscribe {
            self.subscribed.remove(p);
        }
        let mut subscribe: Vec<ChunkPos> = cube(center, radius, self.bounds)
            .filter(|p| !self.subscribed.contains(p))
            .collect();
        subscribe.sort_by_key(|p| nearest_first(*p, center));
        self.subscribed.extend(subscribe.iter().copied());
        InterestChange {
            subscribe,
            unsubscribe,
            recentred: true,
        }
    }
}

/// How far `v` lies outside chunk `c`, in voxels along its farthest axis
/// (0 inside).
fn voxels_past(v: strata_terrain::VoxelPos, c: ChunkPos) -> i32 {
    voxels_past_cube(v, c, 0)
}

/// How far `v` lies outside the chunks within `d` (Chebyshev) of `c`, in
/// voxels along its farthest axis (0 inside).
fn voxels_past_cube(v: strata_terrain::VoxelPos, c: ChunkPos, d: u8) -> i32 {
    let past = |v: i32, c: i32| {
        let lo = (i64::from(c) - i64::from(d)) * CHUNK_SIZE as i64;
        let hi = (i64::from(c) + i64::from(d) + 1) * CHUNK_SIZE as i64 - 1;
        let v = i64::from(v);
        (lo - v).max(v - hi).clamp(0, i64::from(i32::MAX)) as i32
    };
    past(v.x, c.x).max(past(v.y, c.y)).max(past(v.z, c.z))
}

/// The sort key of the chunk stream: squared Euclidean distance in chunks
/// from `center`, ties by `y`, then `z`, then `x`.
pub fn nearest_first(p: ChunkPos, center: ChunkPos) -> (i64, i32, i32, i32) {
    let d = |a: i32, b: i32| (a as i64 - b as i64).pow(2);
    let dist2 = d(p.x, center.x) + d(p.y, center.y) + d(p.z, center.z);
    (dist2, p.y, p.z, p.x)
}

/// Chunks within Chebyshev `radius` of `center`, clipped to the vertical bounds.
fn cube(center: ChunkPos, radius: u8, bounds: WorldBounds) -> impl Iterator<Item = ChunkPos> {
    let r = radius as i32;
    let (lo, hi) = bounds.chunk_y_range();
    let span = |c: i32| (c.saturating_sub(r), c.saturating_add(r));
    let (x0, x1) = span(center.x);
    let (y0, y1) = span(center.y);
    let (z0, z1) = span(center.z);
    let (y0, y1) = (y0.max(lo), y1.min(hi));
    (z0..=z1).flat_map(move |z| {
        (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| ChunkPos::new(x, y, z)))
    })
}
