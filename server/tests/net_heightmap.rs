//! A world from a heightmap file: clients cannot regenerate it from the
//! seed, so the server sends full snapshots of unmodified chunks, and they
//! match the heightmap generator exactly.

use crate::common;

use std::time::Duration;

use common::*;
use strata_protocol::Role;
use strata_server::heightmap::{self, HeightmapSection};
use strata_terrain::gen::{GenParams, HeightmapPlacement};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{ChunkGenerator, VoxelPos};

/// Starts a server on `cfg` and stops it again.
async fn starts_and_stops(cfg: strata_server::config::ServerConfig) {
    let server = strata_server::app::start(cfg).await.unwrap();
    server.shutdown().await.unwrap();
}

/// Writes a raw 16-bit map `width` samples wide and `height` long whose
/// heights rise along x; returns its path.
fn ramp(path: &std::path::Path, width: u32, height: u32) -> std::path::PathBuf {
    let samples: Vec<u8> = (0..width * height)
        .flat_map(|i| ((i % width) as u16 * height as u16).to_le_bytes())
        .collect();
    std::fs::write(path, samples).unwrap();
    path.to_path_buf()
}

#[tokio::test]
async fn heightmap_worlds_stream_full_snapshots() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let map = ramp(&dir.path().join("ramp.raw"), 128, 128);
        let placement = HeightmapPlacement {
            base_y: 10.0,
            ..HeightmapPlacement::default()
        };
        let section = HeightmapSection {
            path: map,
            width: Some(128),
            height: Some(128),
            placement,
        };
        let mut cfg = test_config(&dir.path().join("data"));
        cfg.world.heightmap = Some(section.clone());
        let server = strata_server::app::start(cfg).await.unwrap();
        let c = connect(&server, "ana", Role::Player).await;
        let (generator, _) = heightmap::load(&section, &GenParams::default()).unwrap();
        let (x, z) = (40, 40);
        let y = generator.surface_height(x, z);
        c.send_position(at(x as f64, y + 1.0, z as f64)).unwrap();
        let target = VoxelPos::new(x, y.floor() as i32, z).chunk();
        assert!(
            eventually(Duration::from_secs(10), || c
                .replica()
                .get(target)
                .is_some())
            .await
        );
        let stats = c.replica().stats;
        assert_eq!(
            stats.generated, 0,
            "no chunk is left to the client's generator"
        );
        assert!(stats.snapshots > 0);
        let held = chunk_hash(&c.replica().get(target).unwrap().chunk);
        assert_eq!(held, chunk_hash(&generator.generate(target)));
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A raw map's size is part of the world's record: the same file read at
/// another width and height (another map) is refused. A data dir made
/// before the size was recorded still opens with its map.
#[tokio::test]
async fn a_raw_map_read_at_another_size_is_refused() {
    use strata_server::store::{open_raw, META_WORLD, TREE_META};
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let map = ramp(&dir.path().join("long.raw"), 128, 64);
        let data = dir.path().join("data");
        let sized = |width, height| {
            let mut cfg = test_config(&data);
            cfg.world.heightmap = Some(HeightmapSection {
                path: map.clone(),
                width: Some(width),
                height: Some(height),
                placement: HeightmapPlacement::default(),
            });
            cfg
        };
        starts_and_stops(sized(128, 64)).await;
        let err = strata_server::app::start(sized(64, 128)).await.unwrap_err();
        assert!(format!("{err:#}").contains("generator_params"), "{err:#}");

        // As a data dir from before: the size left out of its record.
        let db = open_raw(&data.join(strata_server::datadir::WORLD_DB_NAME)).unwrap();
        let meta = db.open_tree(TREE_META).unwrap();
        let mut world: serde_json::Value =
            serde_json::from_slice(&meta.get(META_WORLD).unwrap().unwrap()).unwrap();
        let params = world["generator_params"].as_str().unwrap().to_string();
        let old = heightmap::without_raw_size(&params).expect("the size is recorded");
        assert!(params.contains(", raw 128x64\n"), "{params}");
        world["generator_params"] = old.into();
        meta.insert(META_WORLD, serde_json::to_vec(&world).unwrap())
            .unwrap();
        db.flush().unwrap();
        drop((meta, db));
        starts_and_stops(sized(128, 64)).await;
    })
    .await
    .expect("test finished in time");
}
