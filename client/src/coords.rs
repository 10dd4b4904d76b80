//! The client API's vectors are glam's: `DVec3` for positions in voxels
//! (f64 holds every Q24.8 value the wire carries exactly; f32 does not past
//! 65 536 voxels) and `IVec3` for voxel and chunk coordinates. The wire and
//! everything hashed keep the terrain core's own types; these functions are
//! the only crossing.

use glam::{DVec3, IVec3};
use strata_terrain::{ChunkPos, FixedVec3, VoxelPos, CHUNK_SIZE};

/// A position on the wire (Q24.8, rounded to nearest); `None` when a
/// coordinate is not finite or out of the fixed-point range.
pub fn to_fixed(p: DVec3) -> Option<FixedVec3> {
    FixedVec3::from_f64(p.to_array())
}

/// A wire position as a vector.
pub fn from_fixed(p: FixedVec3) -> DVec3 {
    DVec3::from_array(p.to_f64())
}

/// The voxel holding point `p` (floor of each coordinate).
pub fn voxel_at(p: DVec3) -> Option<VoxelPos> {
    let f = p.floor();
    let inside = |v: f64| v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX);
    (inside(f.x) && inside(f.y) && inside(f.z))
        .then(|| VoxelPos::new(f.x as i32, f.y as i32, f.z as i32))
}

/// The chunk holding point `p`.
pub fn chunk_at(p: DVec3) -> Option<ChunkPos> {
    voxel_at(p).map(VoxelPos::chunk)
}

pub fn chunk_pos(v: IVec3) -> ChunkPos {
    ChunkPos::new(v.x, v.y, v.z)
}

pub fn chunk_vec(c: ChunkPos) -> IVec3 {
    IVec3::new(c.x, c.y, c.z)
}

pub fn voxel_pos(v: IVec3) -> VoxelPos {
    VoxelPos::new(v.x, v.y, v.z)
}

pub fn voxel_vec(v: VoxelPos) -> IVec3 {
    IVec3::new(v.x, v.y, v.z)
}

/// World voxel coordinates of a chunk's local (0, 0, 0), where its mesh's
/// chunk-local positions start; `None` when they do not fit an `i32` (a
/// chunk far outside the world, which no replica holds).
pub fn chunk_origin(c: ChunkPos) -> Option<IVec3> {
    let v = |c: i32| c.checked_mul(CHUNK_SIZE);
    Some(IVec3::new(v(c.x)?, v(c.y)?, v(c.z)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_floor_into_voxels_and_chunks() {
        let p = DVec3::new(-0.5, 31.99, 32.0);
        assert_eq!(voxel_at(p), Some(VoxelPos::new(-1, 31, 32)));
        assert_eq!(chunk_at(p), Some(ChunkPos::new(-1, 0, 1)));
        assert_eq!(
            chunk_origin(ChunkPos::new(-1, 0, 1)),
            Some(IVec3::new(-32, 0, 32))
        );
        assert_eq!(voxel_at(DVec3::new(f64::NAN, 0.0, 0.0)), None);
        assert_eq!(voxel_at(DVec3::new(3e9, 0.0, 0.0)), None);
    }

    #[test]
    fn far_chunk_origins_do_not_overflow() {
        assert_eq!(chunk_origin(ChunkPos::new(1 << 26, 0, 0)), None);
        assert_eq!(chunk_origin(ChunkPos::new(0, i32::MIN, 0)), None);
        let edge = (1 << 26) - 1;
        assert_eq!(
            chunk_origin(ChunkPos::new(edge, -(1 << 26), 0)),
            Some(IVec3::new(edge * 32, i32::MIN, 0))
        );
    }

    #[test]
    fn wire_positions_round_to_a_256th_of_a_voxel() {
        let p = to_fixed(DVec3::new(1.5, -2.25, 100.0 + 1.0 / 512.0 + 1e-9)).unwrap();
        assert_eq!(from_fixed(p), DVec3::new(1.5, -2.25, 100.0 + 1.0 / 256.0));
        assert_eq!(to_fixed(DVec3::new(0.0, f64::INFINITY, 0.0)), None);
    }
}
