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

#[tokio::test]
async fn heightmap_worlds_stream_full_snapshots() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let map = dir.path().join("ramp.raw");
        let samples: Vec<u8> = (0..128u32 * 128)
            .flat_map(|i| ((i % 128) as u16 * 128).to_le_bytes())
            .collect();
        std::fs::write(&map, samples).unwrap();
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
