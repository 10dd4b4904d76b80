//! A bot's walk: toward random waypoints inside its bounds, over ground it
//! can stand on, never stepping up or down more than [`MAX_STEP`].

use strata_terrain::{ChunkPos, VoxelPos};

use super::footing::{self, MAX_STEP};
use super::rng::Rng;
use crate::replica::Replica;

/// A bot's position and where it is walking to.
#[derive(Debug, Clone)]
pub struct Walker {
    pub feet: [f64; 3],
    pub waypoint: [f64; 2],
    /// min x, max x, min z, max z.
    pub bounds: [f64; 4],
    pub speed: f64,
}

impl Walker {
    pub fn new_waypoint(&mut self, rng: &mut Rng) {
        let [x0, x1, z0, z1] = self.bounds;
        self.waypoint = [x0 + rng.unit() * (x1 - x0), z0 + rng.unit() * (z1 - z0)];
    }

    /// Moves toward the waypoint over walkable ground, or stays and picks
    /// another waypoint. Either way the feet follow the ground below.
    pub fn step(&mut self, replica: &Replica, dt: f64, rng: &mut Rng) {
        let [x, y, z] = self.feet;
        let (dx, dz) = (self.waypoint[0] - x, self.waypoint[1] - z);
        let dist = (dx * dx + dz * dz).sqrt();
        if dist < 0.5 {
            self.new_waypoint(rng);
        } else {
            let k = (self.speed * dt / dist).min(1.0);
            match footing::stand(replica, x + dx * k, z + dz * k, y) {
                Some(f) if (f[1] - y).abs() <= MAX_STEP => {
                    self.feet = f;
                    return;
                }
                _ => self.new_waypoint(rng),
            }
        }
        if let Some(f) = footing::stand(replica, x, z, y) {
            self.feet = f;
        }
    }

    pub fn chunk(&self) -> ChunkPos {
        let [x, y, z] = self.feet;
        VoxelPos::new(x.floor() as i32, y.floor() as i32, z.floor() as i32).chunk()
    }
}
