//! Hard limits of the terrain core. The server enforces its own, lower,
//! configurable caps on top of these.

use super::fixed::{Fixed, ONE};

/// Largest sphere radius of any edit.
pub const MAX_RADIUS: Fixed = Fixed(64 * ONE);
/// Smallest sphere radius of any edit.
pub const MIN_RADIUS: Fixed = Fixed(ONE / 4);
/// Largest explosion power (density units at the centre).
pub const MAX_POWER: u16 = 2048;
/// Largest edge of a fill/clear box, in voxels.
pub const MAX_BOX_EDGE: i32 = 128;
/// Width of the smooth rim just inside the radius of Mine and Build, in voxels.
pub const SPHERE_RIM: i32 = 2;
