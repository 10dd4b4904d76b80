//! What a server may make a client hold: chunks inside the world (the
//! protocol's coordinate limit and, when the `Welcome` names them, the
//! world's rows), and no more of them than a view of the server's radius
//! can cover. Each chunk costs the client a dense 64 KiB copy (and, for a
//! `Generated`, a generator run) for some 20 bytes on the wire: a server
//! that asks for more breaks the protocol, and the client ends the
//! connection ([`Violation`]).
//!
//! Chunks are not checked against the view itself: the server re-centres
//! the view on positions it accepts (the client cannot tell which), keeps
//! chunks out to a hysteresis the `Welcome` does not give, and a cluster
//! node sets its view from an `Arrive` ticket; updates in flight across
//! any of those would end an honest connection. The cap below bounds what
//! any view can leave held instead.

use serde::Deserialize;
use strata_protocol::Welcome;
use strata_terrain::edit::COORD_LIMIT_VOXELS;
use strata_terrain::{ChunkPos, CHUNK_SIZE};
use thiserror::Error;

/// Largest view radius a server may give (PROTOCOL.md, `Welcome`); a
/// larger one counts as this for [`ChunkLimits::max_held`].
pub const MAX_VIEW_RADIUS: u8 = 32;
/// Largest hysteresis a server may keep chunks for beyond the view's
/// radius (PROTOCOL.md, "Interest"). The `Welcome` does not say which it
/// uses, so the cap assumes this one.
pub const MAX_HYSTERESIS: u8 = 16;
/// Largest chunk coordinate (by absolute value) a view can be centred on:
/// the chunk of a position at the coordinate limit. A `Subscribe` centre
/// past it is refused before it is sent.
pub const MAX_CENTER_CHUNK: i32 = COORD_LIMIT_VOXELS / CHUNK_SIZE;
/// Largest chunk coordinate (by absolute value) a server may send: a view
/// centred at most [`MAX_CENTER_CHUNK`] away reaches this far with the
/// largest radius and hysteresis.
pub const MAX_CHUNK_COORD: i32 = MAX_CENTER_CHUNK + MAX_VIEW_RADIUS as i32 + MAX_HYSTERESIS as i32;

/// The protocol's documented vertical bounds, when `generator_params`
/// leaves them out.
const DEFAULT_MIN_Y: i64 = -128;
const DEFAULT_MAX_Y: i64 = 255;
/// Largest `|min_y|` or `|max_y|` a world may have (the terrain core's
/// `WORLD_Y_LIMIT`); past it the rows are not trusted.
const WORLD_Y_LIMIT: i64 = 1 << 20;

/// How a server broke the protocol; the client ends the connection.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum Violation {
    #[error("chunk {pos:?} lies outside the world (chunk coordinates within ±{max})")]
    OutsideWorld { pos: ChunkPos, max: i32 },
    #[error("chunk {pos:?} lies outside the world's rows {lo}..={hi}")]
    OutsideRows { pos: ChunkPos, lo: i32, hi: i32 },
    #[error("a new chunk {pos:?} past the {max} chunks any view of this server covers")]
    TooManyChunks { pos: ChunkPos, max: usize },
    #[error("an op, which the client did not ask for")]
    UnaskedOp,
    #[error("{chunks} chunks in one UnsubscribedMany; at most {max}")]
    UnsubscribeTooLarge { chunks: usize, max: usize },
    #[error("{chunks} chunk versions in one EditAccepted; at most {max}")]
    EditChangesTooMany { chunks: usize, max: usize },
}

/// Where a server's chunks may lie and how many may be held at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkLimits {
    /// The world's chunk rows (inclusive), when the `Welcome` gave them.
    rows: Option<(i32, i32)>,
    max_held: usize,
}

/// The vertical bounds in `generator_params` (other keys ignored).
#[derive(Debug, Deserialize)]
#[serde(default)]
struct Vertical {
    min_y: i64,
    max_y: i64,
}

impl Default for Vertical {
    fn default() -> Self {
        Self {
            min_y: DEFAULT_MIN_Y,
            max_y: DEFAULT_MAX_Y,
        }
    }
}

/// The chunk rows `generator_params` bounds the world to; `None` when it
/// is not TOML or its bounds make no sense (then only the coordinate limit
/// applies).
fn rows_of(generator_params: &str) -> Option<(i32, i32)> {
    let v: Vertical = toml::from_str(generator_params).ok()?;
    let sane = |y: i64| y.abs() <= WORLD_Y_LIMIT;
    if !(sane(v.min_y) && sane(v.max_y) && v.min_y <= v.max_y) {
        return None;
    }
    let row = |y: i64| y.div_euclid(i64::from(CHUNK_SIZE)) as i32;
    Some((row(v.min_y), row(v.max_y)))
}

impl ChunkLimits {
    /// The limits a server's `Welcome` sets: its view radius and the
    /// world's rows from `generator_params`.
    pub fn from_welcome(w: &Welcome) -> Self {
        Self::new(w.view_radius, rows_of(&w.generator_params))
    }

    /// Limits for a view radius (clamped to [`MAX_VIEW_RADIUS`]) and, when
    /// known, the world's chunk rows `(lo, hi)`: a held chunk lies within
    /// radius + [`MAX_HYSTERESIS`] of the view's centre on each axis (the
    /// server drops it past radius + hysteresis before it sends the next
    /// view's chunks), so at most a cube of that reach, cut to the rows.
    pub fn new(view_radius: u8, rows: Option<(i32, i32)>) -> Self {
        let reach = usize::from(view_radius.min(MAX_VIEW_RADIUS) + MAX_HYSTERESIS);
        let side = 2 * reach + 1;
        let tall = rows.map_or(side, |(lo, hi)| {
            let n = (i64::from(hi) - i64::from(lo) + 1).max(0);
            usize::try_from(n).unwrap_or(usize::MAX).min(side)
        });
        Self {
            rows,
            max_held: side * side * tall,
        }
    }

    /// Most chunks a client of this server holds at once.
    pub fn max_held(&self) -> usize {
        self.max_held
    }

    /// The world's chunk rows, when known.
    pub fn rows(&self) -> Option<(i32, i32)> {
        self.rows
    }

    /// Whether a server may send anything about chunk `pos`.
    pub fn check(&self, pos: ChunkPos) -> Result<(), Violation> {
        let max = MAX_CHUNK_COORD;
        let inside = |c: i32| (-max..=max).contains(&c);
        if !(inside(pos.x) && inside(pos.y) && inside(pos.z)) {
            return Err(Violation::OutsideWorld { pos, max });
        }
        match self.rows {
            Some((lo, hi)) if !(lo..=hi).contains(&pos.y) => {
                Err(Violation::OutsideRows { pos, lo, hi })
            }
            _ => Ok(()),
        }
    }
}

/// Whether a view may be centred on `center`: within [`MAX_CENTER_CHUNK`]
/// on each axis, as the chunk of any position the server accepts is.
pub fn center_in_world(center: ChunkPos) -> bool {
    let inside = |c: i32| (-MAX_CENTER_CHUNK..=MAX_CENTER_CHUNK).contains(&c);
    inside(center.x) && inside(center.y) && inside(center.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cap_covers_the_largest_view_and_hysteresis_cut_to_the_rows() {
        // Radius 8 in the default world (rows -4..=7): 49 x 49 x 12.
        let l = ChunkLimits::new(8, rows_of("seed = 1\nmin_y = -128\nmax_y = 255\n"));
        assert_eq!(l.rows(), Some((-4, 7)));
        assert_eq!(l.max_held(), 49 * 49 * 12);
        // The documented defaults when the keys are left out.
        assert_eq!(rows_of(""), Some((-4, 7)));
        // Rows unknown (not TOML): the whole cube; a radius past the
        // protocol's is taken as its.
        assert_eq!(rows_of("not = [toml"), None);
        assert_eq!(ChunkLimits::new(255, None).max_held(), 97 * 97 * 97);
        // Nonsense bounds are not trusted.
        assert_eq!(rows_of("min_y = 10\nmax_y = 0\n"), None);
        assert_eq!(rows_of("min_y = -99999999\n"), None);
        // A world taller than the view: the cube's height.
        let tall = ChunkLimits::new(0, Some((-1000, 1000)));
        assert_eq!(tall.max_held(), 33 * 33 * 33);
    }

    #[test]
    fn chunks_outside_the_world_or_its_rows_are_violations() {
        let l = ChunkLimits::new(2, Some((-4, 7)));
        assert_eq!(l.check(ChunkPos::new(0, 0, 0)), Ok(()));
        // The farthest a view at the coordinate limit reaches.
        let edge = ChunkPos::new(MAX_CHUNK_COORD, 7, -MAX_CHUNK_COORD);
        assert_eq!(l.check(edge), Ok(()));
        let far = ChunkPos::new(1 << 26, 0, 0);
        assert_eq!(
            l.check(far),
            Err(Violation::OutsideWorld {
                pos: far,
                max: MAX_CHUNK_COORD
            })
        );
        let high = ChunkPos::new(0, 8, 0);
        assert_eq!(
            l.check(high),
            Err(Violation::OutsideRows {
                pos: high,
                lo: -4,
                hi: 7
            })
        );
        // Without rows, y is bounded by the coordinate limit only.
        assert_eq!(ChunkLimits::new(2, None).check(high), Ok(()));
        assert!(center_in_world(ChunkPos::new(MAX_CENTER_CHUNK, 0, 0)));
        assert!(!center_in_world(ChunkPos::new(0, 0, -MAX_CENTER_CHUNK - 1)));
    }
}
