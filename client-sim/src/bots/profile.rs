//! Load profiles: what each bot does. A profile gives every bot a role;
//! a role fixes its walking speed, how far it roams and which edit it makes.

use std::fmt;
use std::str::FromStr;

use strata_terrain::{Edit, Fixed, FixedVec3, VoxelPos};

use super::rng::Rng;

/// Material ids builders place (dirt, stone in the default table).
pub const BUILD_MATERIALS: [u8; 2] = [2, 3];
/// Explosion power demolition bots use (server default cap: 512).
pub const EXPLOSION_POWER: u16 = 256;

/// The `--profile` choices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    Miners,
    Builders,
    Demolition,
    Explorers,
    Mixed,
}

impl Profile {
    pub const ALL: [Profile; 5] = [
        Profile::Miners,
        Profile::Builders,
        Profile::Demolition,
        Profile::Explorers,
        Profile::Mixed,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Profile::Miners => "miners",
            Profile::Builders => "builders",
            Profile::Demolition => "demolition",
            Profile::Explorers => "explorers",
            Profile::Mixed => "mixed",
        }
    }

    /// The role of bot `index`: `mixed` cycles through every role.
    pub fn role_of(self, index: usize) -> Role {
        match self {
            Profile::Miners => Role::Miner,
            Profile::Builders => Role::Builder,
            Profile::Demolition => Role::Demolisher,
            Profile::Explorers => Role::Explorer,
            Profile::Mixed => Role::ALL[index % Role::ALL.len()],
        }
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Profile {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                format!("unknown profile {s:?}; expected miners, builders, demolition, explorers or mixed")
            })
    }
}

/// What one bot does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Digs small holes around its home.
    Miner,
    /// Piles dirt and stone around its home.
    Builder,
    /// Sets off explosions around its home.
    Demolisher,
    /// Walks across the whole area, smoothing now and then.
    Explorer,
}

impl Role {
    pub const ALL: [Role; 4] = [Role::Miner, Role::Builder, Role::Demolisher, Role::Explorer];

    /// Walking speed in voxels per second (the server allows 20).
    pub fn walk_speed(self) -> f64 {
        match self {
            Role::Explorer => 6.0,
            _ => 1.5,
        }
    }

    /// Explorers roam the whole area; the others stay near home.
    pub fn roams(self) -> bool {
        self == Role::Explorer
    }

    /// The edit aimed at `ground`, a surface voxel near the bot.
    pub fn edit(self, ground: VoxelPos, rng: &mut Rng) -> Edit {
        let at = |dy: i32| FixedVec3::from_voxels(ground.x, ground.y + dy, ground.z);
        match self {
            Role::Miner => Edit::Mine {
                center: at(0),
                radius: Fixed::from_voxels(rng.range(2, 3)),
                strength: 255,
            },
            Role::Builder => Edit::Build {
                center: at(1),
                radius: Fixed::from_voxels(2),
                material: BUILD_MATERIALS[rng.range(0, 1) as usize],
                strength: 255,
            },
            Role::Demolisher => Edit::Explode {
                center: at(0),
                radius: Fixed::from_voxels(3),
                power: EXPLOSION_POWER,
            },
            Role::Explorer => Edit::Smooth {
                center: at(0),
                radius: Fixed::from_voxels(2),
                strength: 128,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_mixed_cycles() {
        for p in Profile::ALL {
            assert_eq!(p.name().parse::<Profile>(), Ok(p));
        }
        assert!("nukes".parse::<Profile>().is_err());
        let roles: Vec<Role> = (0..4).map(|i| Profile::Mixed.role_of(i)).collect();
        assert_eq!(roles, Role::ALL);
        assert_eq!(Profile::Miners.role_of(3), Role::Miner);
        let mut rng = Rng::new(1, 1);
        let g = VoxelPos::new(600, 10, 600);
        assert!(matches!(
            Role::Builder.edit(g, &mut rng),
            Edit::Build { .. }
        ));
    }
}
