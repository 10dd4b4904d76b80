//! The frame cache every session shares: one client asking for whole
//! chunks (a thin client, `CAP_SNAPSHOTS`) past the cache's size no longer
//! empties it. Its frames are kept apart, within their own bound, and the
//! patches of modified chunks other sessions were sent are still sent
//! from the cache, not built again.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, Verdict};
use strata_terrain::{Edit, FixedVec3};

/// Reports `feet` until the server says the view around it is loaded.
async fn view_loaded(c: &Client, feet: FixedVec3) -> bool {
    eventually(Duration::from_secs(30), || {
        let _ = c.send_position(feet);
        c.view_loaded().is_some()
    })
    .await
}

#[tokio::test]
async fn a_thin_clients_whole_frames_do_not_push_out_the_shared_patches() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        // A radius-1 view is 27 chunks: more than the shared cache holds.
        let config = format!(
            "{FAST_EDITS}[interest]\nview_radius = 1\n\
             [engine]\nworkers = 2\nsnapshot_cache_entries = 16\nfull_frame_cache_entries = 8\n\
             [metrics]\nlisten = \"{metrics}\"\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let built = || {
            let text = scrape(metrics);
            ["workers", "engine"]
                .iter()
                .map(|on| {
                    let name = format!("strata_snapshot_frames_built_total{{on=\"{on}\"}}");
                    metric(&text, &name).unwrap_or(0.0)
                })
                .sum::<f64>()
        };
        // Modify the ground under the editor's feet.
        let (feet, ground) = spot(70, 40);
        let ed = process_client(&data, addr, "ed").await;
        assert!(view_loaded(&ed, feet).await);
        let mine = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(1.5),
            strength: 255,
        };
        assert!(matches!(
            ed.edit(mine).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        // A newcomer there is sent the modified chunks as patches, built
        // once and kept.
        let ana = process_client(&data, addr, "ana").await;
        assert!(view_loaded(&ana, feet).await);
        let patched = ana.replica().stats.patched;
        assert!(patched >= 1, "{:?}", ana.replica().stats);
        let after_ana = built();
        assert!(after_ana >= patched as f64);
        // A thin client far away loads its whole view as whole frames.
        let thin = process_client_opts(
            &data,
            addr,
            "thin",
            strata_client_sim::ClientOptions {
                capabilities: strata_protocol::CAP_SNAPSHOTS,
                ..Default::default()
            },
        )
        .await;
        let (far, _) = spot(400, 40);
        assert!(view_loaded(&thin, far).await);
        assert_eq!(thin.replica().stats.snapshots, 27);
        let after_thin = built();
        assert!(after_thin >= after_ana + 27.0);
        // Another newcomer by the editor: its patches come from the cache.
        let bo = process_client(&data, addr, "bo").await;
        assert!(view_loaded(&bo, feet).await);
        assert_eq!(bo.replica().stats.patched, patched);
        assert_eq!(built(), after_thin, "shared patches were built again");
        let text = scrape(metrics);
        let evicted = |o: &str| {
            metric(
                &text,
                &format!("strata_snapshot_cache_total{{outcome=\"{o}\"}}"),
            )
        };
        assert!(evicted("evicted_requested") >= Some(19.0), "{text}");
        assert_eq!(evicted("evicted"), None, "{text}");
        for c in [ed, ana, thin, bo] {
            c.close().await;
        }
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}
