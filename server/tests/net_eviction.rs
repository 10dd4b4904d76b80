//! Memory stays bounded: past `engine.resident_chunks` the server drops
//! chunks far from every player, modified ones included, and loads them
//! from the store again when a player comes back and edits there.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_terrain::hash::chunk_hash;
use strata_terrain::{Edit, FixedVec3, VoxelPos};

fn mine(v: VoxelPos) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(v.x, v.y, v.z),
        radius: r(2.5),
        strength: 255,
    }
}

#[tokio::test]
async fn cold_chunks_are_dropped_and_reloaded_from_the_store() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        let config = format!(
            "{FAST_EDITS}[engine]\nresident_chunks = 27\npremesh_radius = 0\n\
             [metrics]\nlisten = \"{metrics}\"\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let resident = || metric(&scrape(metrics), "strata_resident_chunks").unwrap_or(0.0);

        // Ana edits at A and leaves.
        let (feet_a, ground_a) = spot(70, 40);
        let ana = process_client(&data, addr, "ana").await;
        ana.send_position(feet_a).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let Verdict::Accepted { .. } = ana.edit(mine(ground_a)).await.unwrap() else {
            panic!("first edit at A refused");
        };
        assert!(
            eventually(Duration::from_secs(5), || resident() >= 27.0).await,
            "A's chunks are resident"
        );
        ana.close().await;
        assert!(
            eventually(Duration::from_secs(5), || resident() == 0.0).await,
            "with nobody playing every chunk is cold and dropped: {} resident",
            resident()
        );

        // Bob's chunks, far away, are hot: they stay past the limit.
        let (feet_b, ground_b) = spot(70 + 320, 40);
        let bob = process_client(&data, addr, "bob").await;
        bob.send_position(feet_b).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let Verdict::Accepted { .. } = bob.edit(mine(ground_b)).await.unwrap() else {
            panic!("edit at B refused");
        };
        tokio::time::sleep(Duration::from_millis(1200)).await;
        bob.edit(mine(VoxelPos::new(ground_b.x + 1, ground_b.y, ground_b.z)))
            .await
            .unwrap();
        assert!(resident() >= 27.0, "bob's chunks stay resident");

        // Ana comes back: chunk A is loaded from the store, not regenerated.
        let ana = process_client(&data, addr, "ana").await;
        ana.replica().record_history();
        ana.send_position(feet_a).unwrap();
        let target = ground_a.chunk();
        assert!(
            eventually(Duration::from_secs(10), || ana
                .replica()
                .get(target)
                .is_some_and(|h| h.version == 1))
            .await,
            "ana gets chunk A at version 1"
        );
        let Verdict::Accepted { .. } = ana
            .edit(mine(VoxelPos::new(ground_a.x, ground_a.y, ground_a.z + 1)))
            .await
            .unwrap()
        else {
            panic!("second edit at A refused");
        };
        assert!(
            eventually(Duration::from_secs(10), || ana
                .replica()
                .get(target)
                .is_some_and(|h| h.version == 2))
            .await,
            "the second edit continues A's history"
        );
        let stats = ana.replica().stats;
        assert_eq!(stats.hash_mismatches, 0, "{stats:?}");
        assert_eq!(stats.gaps, 0, "{stats:?}");
        assert_eq!(
            ana.replica().history().unwrap().get(&target),
            Some(&vec![1, 2])
        );
        let held = chunk_hash(&ana.replica().get(target).unwrap().chunk);
        ana.close().await;
        bob.close().await;
        child.kill().unwrap();
        child.wait().unwrap();
        // The store agrees with what the client rebuilt.
        // Killed: read as a restarted server would, with the generator.
        let store = Backend::Sled.open_store(&data);
        let stored = store
            .load_chunk(target)
            .unwrap()
            .expect("chunk A is stored");
        assert_eq!(stored.version, 2);
        assert_eq!(chunk_hash(&stored.chunk), held);
    })
    .await
    .expect("test finished in time");
}
