//! The world's vertical bounds: edits and positions must stay inside them.

use serde::{Deserialize, Serialize};
use strata_protocol::RejectReason;
use strata_terrain::{ChunkPos, VoxelBox, CHUNK_SIZE};

/// Lowest voxel y anything may touch by default (16 chunks down).
pub const DEFAULT_MIN_Y: i32 = -16 * CHUNK_SIZE;
/// Highest voxel y anything may touch by default (16 chunks up, inclusive).
pub const DEFAULT_MAX_Y: i32 = 16 * CHUNK_SIZE - 1;

/// Inclusive vertical range of the world in voxels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorldBounds {
    pub min_y: i32,
    pub max_y: i32,
}

impl Default for WorldBounds {
    fn default() -> Self {
        Self {
            min_y: DEFAULT_MIN_Y,
            max_y: DEFAULT_MAX_Y,
        }
    }
}

impl WorldBounds {
    pub fn contains_y(&self, y: i32) -> bool {
        (self.min_y..=self.max_y).contains(&y)
    }

    /// Chunk rows that hold at least one in-bounds voxel.
    pub fn chunk_y_range(&self) -> (i32, i32) {
        (
            self.min_y.div_euclid(CHUNK_SIZE),
            self.max_y.div_euclid(CHUNK_SIZE),
        )
    }

    pub fn contains_chunk(&self, c: ChunkPos) -> bool {
        let (lo, hi) = self.chunk_y_range();
        (lo..=hi).contains(&c.y)
    }

    /// Rejects a box that leaves the vertical range.
    pub fn check_box(&self, b: &VoxelBox) -> Result<(), RejectReason> {
        if self.contains_y(b.min.y) && self.contains_y(b.max.y) {
            Ok(())
        } else {
            Err(RejectReason::OutOfBounds)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::VoxelPos;

    #[test]
    fn box_and_chunk_rows() {
        let b = WorldBounds {
            min_y: -32,
            max_y: 63,
        };
        assert_eq!(b.chunk_y_range(), (-1, 1));
        let bx = |y0, y1| VoxelBox::from_corners(VoxelPos::new(0, y0, 0), VoxelPos::new(1, y1, 1));
        assert!(b.check_box(&bx(-32, 63)).is_ok());
        assert_eq!(b.check_box(&bx(-33, 0)), Err(RejectReason::OutOfBounds));
        assert_eq!(b.check_box(&bx(0, 64)), Err(RejectReason::OutOfBounds));
        assert!(!b.contains_chunk(ChunkPos::new(0, 2, 0)));
    }
}
