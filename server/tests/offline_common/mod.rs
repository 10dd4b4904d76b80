//! A stopped server's data dir for the offline admin commands: the store is
//! written exactly as the engine writes it (the world metadata `app::start`
//! records, then the sequencer's commit batches, one tick per edit), over
//! the default fractal generator.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Output};
use std::sync::Arc;

use strata_protocol::{EditRequest, PositionUpdate, Role};
use strata_server::app::world_generator;
use strata_server::config::ServerConfig;
use strata_server::sequencer::{Sequencer, SequencerConfig};
use strata_server::store::{ChunkStore, SledStore, WorldMeta};
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::{ValidationConfig, WorldBounds};
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{Generator, GENERATOR_VERSION};
use strata_terrain::material::ids;
use strata_terrain::{ChunkPos, Edit, Fixed, FixedVec3, MaterialTable, VoxelPos, World};

pub const ADMIN_BIN: &str = env!("CARGO_BIN_EXE_strata-admin");

/// Chunk columns X0 Z0 X1 Z1 holding every edit of [`build`].
pub const REGION: [i32; 4] = [2, 1, 4, 3];
/// The brick box: its centre column and height range.
pub const BRICK: (i32, i32, i32) = (140, 40, 0);

/// What was written, as the server saw it.
#[derive(Debug)]
pub struct Fixture {
    pub dir: tempfile::TempDir,
    /// Per changed chunk: its final version and the mesh hash the server
    /// sent with that version's delta.
    pub deltas: BTreeMap<ChunkPos, (u64, u64)>,
    /// The sequencer after the edits, for its collision mesh hashes.
    pub sequencer: Sequencer,
    /// Height of the brick box's top voxel row.
    pub brick_top: i32,
}

impl Fixture {
    pub fn data_dir(&self) -> &Path {
        self.dir.path()
    }
}

pub fn admin(args: &[&str]) -> Output {
    Command::new(ADMIN_BIN)
        .args(args)
        .output()
        .expect("strata-admin runs")
}

/// Asserts success and returns stdout.
pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "strata-admin failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout.clone()).unwrap()
}

pub fn region_args() -> Vec<String> {
    REGION.iter().map(|v| v.to_string()).collect()
}

fn surface(g: &Generator, x: i32, z: i32) -> i32 {
    g.surface_height(x, z).floor() as i32
}

/// Each edit's player stands next to it, so reach and sight pass as on a
/// live server; edits sit two chunk columns apart so no later edit touches
/// an earlier one's mesh apron.
pub fn build() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let cfg = ServerConfig::default();
    let (generator, params_text) = world_generator(&cfg).unwrap();
    let params = cfg.world.generator.clone();
    let store = SledStore::open(&dir.path().join("world.sled")).unwrap();
    store
        .init_meta(&WorldMeta::new(
            params.seed,
            GENERATOR_VERSION,
            params_text.clone(),
        ))
        .unwrap();

    let mut validation = ValidationConfig {
        bounds: WorldBounds {
            min_y: params.min_y,
            max_y: params.max_y,
        },
        spawn_protection_radius: 0,
        reach: 32.0,
        ..ValidationConfig::default()
    };
    validation.edit_rate = BucketConfig {
        capacity: 100,
        per_second: 100,
    };
    let gen_for_spots = Generator::fractal(params.clone()).unwrap();
    let mut seq = Sequencer::new(
        World::new(Arc::new(generator)),
        SequencerConfig::default(),
        validation,
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        vec![],
    )
    .without_store();

    let (bx, bz, _) = BRICK;
    let brick_top = surface(&gen_for_spots, bx, bz) + 3;
    let sphere_y = surface(&gen_for_spots, 70, 110) + 12;
    let edits: Vec<((i32, i32), Edit)> = vec![
        (
            (72, 40),
            Edit::Mine {
                center: FixedVec3::from_voxels(70, surface(&gen_for_spots, 70, 40), 40),
                radius: Fixed::from_voxels(4),
                strength: 255,
            },
        ),
        (
            (bx + 3, bz + 4),
            Edit::FillBox {
                min: VoxelPos::new(bx - 2, brick_top - 6, bz - 2),
                max: VoxelPos::new(bx + 2, brick_top, bz + 2),
                material: ids::BRICK,
            },
        ),
        (
            (74, 110),
            Edit::Build {
                center: FixedVec3::from_voxels(70, sphere_y, 110),
                radius: Fixed::from_voxels(5),
                material: ids::STONE,
                strength: 255,
            },
        ),
    ];
    let mut deltas = BTreeMap::new();
    for (k, ((px, pz), edit)) in edits.into_iter().enumerate() {
        let id = k as u64 + 1;
        seq.session_joined(id, format!("builder{id}"), Role::Admin);
        let feet = FixedVec3::from_voxels(px, surface(&gen_for_spots, px, pz) + 1, pz);
        seq.update_position(id, PositionUpdate { seq: 1, pos: feet }, 0)
            .expect("standing on the surface");
        let now = 1_000 * id;
        seq.submit(
            id,
            EditRequest {
                client_edit_id: id,
                edit,
            },
            now,
        )
        .unwrap_or_else(|r| panic!("edit {id} refused: {r:?}"));
        let out = seq.tick(now);
        assert_eq!(out.applied.len(), 1);
        for c in out.applied.iter().flat_map(|a| &a.changes) {
            deltas.insert(c.pos, (c.to_version, c.mesh_hash));
        }
        store.commit_batch(&out.batch).unwrap();
    }
    assert!(store.check().unwrap().is_ok());
    drop(store);
    Fixture {
        dir,
        deltas,
        sequencer: seq,
        brick_top,
    }
}
