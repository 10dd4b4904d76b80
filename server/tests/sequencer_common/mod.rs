//! Shared fixtures for the sequencer and validation tests: a flat stone
//! world (solid below y = 0), sessions placed away from spawn, and edits.
#![allow(dead_code)]

use std::sync::Arc;

use strata_protocol::{EditRequest, PositionUpdate, Role};
use strata_server::sequencer::{Sequencer, SequencerConfig};
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::{Fixed, FixedVec3, StructureLibrary};
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{ChunkPos, Edit, MaterialTable, Voxel, VoxelPos, World};

pub const PLAYER: u64 = 1;
pub const ADMIN: u64 = 2;
/// Where tests stand: far outside the default spawn zone.
pub const HOME: (i32, i32) = (100, 100);

pub fn world() -> World {
    World::new(Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    }))
}

pub fn sequencer(cfg: SequencerConfig, validation: ValidationConfig) -> Sequencer {
    let zones = Sequencer::default_zones(&validation);
    Sequencer::new(
        world(),
        cfg,
        validation,
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        zones,
    )
    .without_store()
}

/// A storeless sequencer with a player and an admin standing near [`HOME`].
pub fn ready(validation: ValidationConfig) -> Sequencer {
    let mut s = sequencer(SequencerConfig::default(), validation);
    join_at(&mut s, PLAYER, Role::Player, HOME.0, HOME.1);
    join_at(&mut s, ADMIN, Role::Admin, HOME.0 - 2, HOME.1);
    s
}

pub fn join_at(s: &mut Sequencer, id: u64, role: Role, x: i32, z: i32) {
    s.session_joined(id, format!("p{id}"), role);
    s.update_position(id, at(1, x, 0, z), 0)
        .expect("standing on flat ground");
}

pub fn at(seq: u32, x: i32, y: i32, z: i32) -> PositionUpdate {
    PositionUpdate {
        seq,
        pos: FixedVec3::from_voxels(x, y, z),
    }
}

pub fn mine(x: i32, y: i32, z: i32, r: i32) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(x, y, z),
        radius: Fixed::from_voxels(r),
        strength: 255,
    }
}

pub fn req(id: u64, edit: Edit) -> EditRequest {
    EditRequest {
        client_edit_id: id,
        edit,
    }
}

pub fn fill(min: (i32, i32, i32), max: (i32, i32, i32)) -> Edit {
    Edit::FillBox {
        min: VoxelPos::new(min.0, min.1, min.2),
        max: VoxelPos::new(max.0, max.1, max.2),
        material: ids::BRICK,
    }
}

/// Everything a rejection must leave alone.
#[derive(Debug, PartialEq)]
pub struct Snapshot {
    versions: Vec<(ChunkPos, u64)>,
    next_seq: u64,
    queued: usize,
}

pub fn snapshot(s: &Sequencer) -> Snapshot {
    let mut versions: Vec<_> = s.world().modified().map(|(p, c)| (p, c.version)).collect();
    versions.sort();
    Snapshot {
        versions,
        next_seq: s.next_seq(),
        queued: s.queued(),
    }
}
