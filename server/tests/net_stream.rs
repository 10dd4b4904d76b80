//! Snapshot streaming under the smallest time and byte budgets: each tick
//! serves at least one session, sessions take turns, and every session
//! still receives its whole view. Frames are built on the workers, and
//! sent again from the cache.

use crate::common;

use std::time::Duration;

use common::*;
use strata_protocol::Role;
use strata_server::app;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkPos, VoxelPos};

/// Chunks within Chebyshev `r` of `c` (the test world's bounds are far).
fn cube(c: ChunkPos, r: i32) -> Vec<ChunkPos> {
    let mut v = Vec::new();
    for z in -r..=r {
        for y in -r..=r {
            for x in -r..=r {
                v.push(ChunkPos::new(c.x + x, c.y + y, c.z + z));
            }
        }
    }
    v
}

/// A server process's config: view radius 2, two engine workers, metrics
/// on `metrics`.
fn two_workers_config(metrics: std::net::SocketAddr) -> String {
    format!(
        "{FAST_EDITS}[interest]\nview_radius = 2\n[engine]\nworkers = 2\n[metrics]\nlisten = \"{metrics}\"\n"
    )
}

/// A thin client's options: every chunk comes whole, so each is built.
fn thin() -> strata_client_sim::ClientOptions {
    strata_client_sim::ClientOptions {
        capabilities: strata_protocol::CAP_SNAPSHOTS,
        ..Default::default()
    }
}

#[tokio::test]
async fn tiny_stream_budgets_serve_sessions_in_turn_and_deliver_every_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path());
    // The smallest batches, and time for one session per tick.
    cfg.engine.stream_us = 1;
    cfg.net.send_budget_bytes_per_tick = strata_server::config::MIN_SEND_BUDGET_BYTES_PER_TICK;
    served_in_turn(cfg, 0).await;
}

/// Thin clients, whose every frame is built: a tick builds only so many
/// (`prebuild.rs`), and the sessions whose frames did not fit go first
/// the next tick, so none waits for another's whole view.
#[tokio::test]
async fn sessions_whose_frames_wait_for_the_workers_are_served_in_turn() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path());
    cfg.engine.workers = 1;
    served_in_turn(cfg, strata_protocol::CAP_SNAPSHOTS).await;
}

/// Three sessions with `capabilities` join far apart: when the first has
/// its whole view, the others have at least half of theirs, and then all
/// of it.
async fn served_in_turn(cfg: strata_server::config::ServerConfig, capabilities: u32) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let radius = i32::from(cfg.interest.view_radius);
        let server = app::start(cfg).await.expect("server starts");
        let g = Generator::fractal(GenParams::default()).unwrap();
        let mut clients = Vec::new();
        let mut views = Vec::new();
        for (i, name) in ["ana", "bo", "cy"].into_iter().enumerate() {
            let c = connect_caps(&server, name, capabilities).await;
            let x = 70 + 40 * i as i32;
            let y = g.surface_height(x, 40);
            c.send_position(at(x as f64, y + 1.0, 40.0)).unwrap();
            views.push(cube(
                VoxelPos::new(x, y.floor() as i32 + 1, 40).chunk(),
                radius,
            ));
            clients.push(c);
        }
        let want = views[0].len();
        let held = |c: &strata_client_sim::Client| c.replica().len();
        // Taking turns: when the first session has everything, the others
        // are nearly done too (one at a time, they would have nothing).
        assert!(
            eventually(Duration::from_secs(30), || clients
                .iter()
                .any(|c| held(c) >= want))
            .await
        );
        let least = clients.iter().map(held).min().unwrap();
        assert!(
            least >= want / 2,
            "sessions were not served in turn: {:?} of {want}",
            clients.iter().map(held).collect::<Vec<_>>()
        );
        assert!(
            eventually(Duration::from_secs(30), || clients
                .iter()
                .all(|c| held(c) >= want))
            .await
        );
        for (c, view) in clients.iter().zip(&views) {
            let r = c.replica();
            let missing: Vec<_> = view.iter().filter(|p| r.get(**p).is_none()).collect();
            assert!(missing.is_empty(), "never sent: {missing:?}");
            assert_eq!(r.len(), view.len());
        }
        for c in clients {
            c.close().await;
        }
    })
    .await
    .expect("test finished in time");
}

/// A thin client (`CAP_SNAPSHOTS`, no generator) loads its whole view as
/// snapshots, a modified chunk included, each hash-checked; an unknown
/// capability bit beside it is ignored; deltas still flow to it.
#[tokio::test]
async fn thin_clients_load_their_view_as_verified_snapshots() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let cfg = test_config(dir.path());
        let radius = i32::from(cfg.interest.view_radius);
        let server = app::start(cfg).await.expect("server starts");
        let (feet, surface) = spot(70, 40);
        let view = cube(VoxelPos::new(70, surface.y + 1, 40).chunk(), radius);
        let edit = |x: f64| strata_terrain::Edit::Mine {
            center: at(x, surface.y as f64, 40.0),
            radius: r(2.0),
            strength: 255,
        };
        // A normal client modifies a chunk first: it would come as a patch.
        let full = connect(&server, "ana", Role::Player).await;
        full.send_position(feet).unwrap();
        // Chunks flow once the position is accepted.
        let pos = surface.chunk();
        assert!(
            eventually(Duration::from_secs(20), || full
                .replica()
                .get(pos)
                .is_some())
            .await
        );
        let v = full.edit(edit(70.0)).await.unwrap();
        assert!(
            matches!(v, strata_client_sim::Verdict::Accepted { .. }),
            "{v:?}"
        );
        let caps = strata_protocol::CAP_SNAPSHOTS | 1 << 31;
        let thin = connect_caps(&server, "bo", caps).await;
        thin.send_position(feet).unwrap();
        assert!(
            eventually(Duration::from_secs(20), || thin.replica().len()
                >= view.len())
            .await
        );
        let s = thin.replica().stats;
        assert_eq!((s.generated, s.patched), (0, 0), "{s:?}");
        assert_eq!(s.snapshots, view.len() as u64, "{s:?}");
        assert_eq!(s.hash_mismatches, 0);
        let (version, hash) = server_chunk(&server, pos).await;
        assert!(version >= 1);
        let held = thin.replica().get(pos).cloned().unwrap();
        assert_eq!((held.version, held.hash), (version, hash));
        // Deltas flow as usual, hash-checked and meshed at the tick end.
        let seq = match full.edit(edit(72.0)).await.unwrap() {
            strata_client_sim::Verdict::Accepted { seq } => seq,
            v => panic!("{v:?}"),
        };
        assert!(eventually(Duration::from_secs(10), || thin.replica().last_seq() >= seq).await);
        let s = thin.replica().stats;
        assert!(s.deltas >= 1 && s.meshes_checked >= 1, "{s:?}");
        assert_eq!(
            (s.hash_mismatches, s.mesh_mismatches, s.generated),
            (0, 0, 0)
        );
        for c in [full, thin] {
            c.close().await;
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Two thin clients load the same view: every frame is built once, on the
/// workers (`prebuild.rs`), none on the engine thread, and the second
/// client's come from the cache. Every chunk hash matches, and so does
/// every mesh hash the clients could check (those of chunks whose 26
/// neighbours they hold).
#[tokio::test]
async fn frames_are_built_on_the_workers_once_and_then_served_from_the_cache() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        let config = two_workers_config(metrics);
        let (mut child, addr) = spawn_server(&data, &config);
        let (feet, surface) = spot(70, 40);
        let view = cube(VoxelPos::new(70, surface.y + 1, 40).chunk(), 2);
        let built = |on: &str| {
            let text = scrape(metrics);
            metric(
                &text,
                &format!("strata_snapshot_frames_built_total{{on=\"{on}\"}}"),
            )
        };
        let mut clients = Vec::new();
        for name in ["ana", "bo"] {
            let c = process_client_opts(&data, addr, name, thin()).await;
            c.send_position(feet).unwrap();
            assert!(
                eventually(Duration::from_secs(30), || c.replica().len() >= view.len()).await,
                "{name} has {} of {} chunks",
                c.replica().len(),
                view.len()
            );
            let s = c.replica().stats;
            assert_eq!(s.snapshots, view.len() as u64, "{s:?}");
            assert_eq!((s.hash_mismatches, s.mesh_mismatches), (0, 0), "{s:?}");
            // The first client's frames were built; the second's were not.
            assert_eq!(built("workers"), Some(view.len() as f64), "{name}");
            clients.push(c);
        }
        assert_eq!(built("engine"), None, "no frame built on the engine thread");
        let text = scrape(metrics);
        let hits = metric(&text, "strata_snapshot_cache_total{outcome=\"hit\"}");
        assert!(hits >= Some(view.len() as f64), "{hits:?} cache hits");
        for c in clients {
            c.close().await;
        }
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A stored chunk that cannot be read leaves out only the frames that need
/// it (its own and its neighbours', for their meshes): the workers still
/// build every other frame of the view, and the engine thread none; and it
/// is not read again every tick.
#[tokio::test]
async fn a_chunk_that_cannot_be_read_leaves_out_only_the_frames_that_need_it() {
    use strata_server::store::keys::chunk_key;
    use strata_server::store::{open_raw, TREE_CHUNKS};
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        let config = two_workers_config(metrics);
        let (feet, surface) = spot(70, 40);
        let center = VoxelPos::new(70, surface.y + 1, 40).chunk();
        let view = cube(center, 2);
        let bad = ChunkPos::new(center.x + 2, center.y + 2, center.z + 2);
        // A first start makes the data dir; the view's corner chunk then
        // gets a stored body that does not decode.
        let (mut child, _) = spawn_server(&data, &config);
        child.kill().unwrap();
        child.wait().unwrap();
        {
            let db = open_raw(&data.join(strata_server::datadir::WORLD_DB_NAME)).unwrap();
            let chunks = db.open_tree(TREE_CHUNKS).unwrap();
            let mut garbage = 1u64.to_be_bytes().to_vec();
            garbage.extend_from_slice(b"\x28\xb5\x2f\xfd not zstd");
            chunks.insert(chunk_key(bad), garbage).unwrap();
            db.flush().unwrap();
        }
        let (mut child, addr) = spawn_server(&data, &config);
        let c = process_client_opts(&data, addr, "ana", thin()).await;
        c.send_position(feet).unwrap();
        let near_bad = |p: &ChunkPos| {
            (p.x - bad.x).abs() <= 1 && (p.y - bad.y).abs() <= 1 && (p.z - bad.z).abs() <= 1
        };
        let servable: Vec<ChunkPos> = view.iter().copied().filter(|p| !near_bad(p)).collect();
        assert_eq!(servable.len(), view.len() - 8);
        assert!(
            eventually(Duration::from_secs(30), || c.replica().len()
                >= servable.len())
            .await,
            "{} of {} chunks",
            c.replica().len(),
            servable.len()
        );
        {
            let r = c.replica();
            assert!(servable.iter().all(|p| r.get(*p).is_some()));
            assert_eq!((r.stats.hash_mismatches, r.stats.mesh_mismatches), (0, 0));
        }
        let text = scrape(metrics);
        let built = |on: &str| {
            metric(
                &text,
                &format!("strata_snapshot_frames_built_total{{on=\"{on}\"}}"),
            )
        };
        assert_eq!(built("workers"), Some(servable.len() as f64));
        assert_eq!(built("engine"), None, "no frame built on the engine thread");
        // Found once, the bad record is left alone for a while: no tick
        // reads it again (it would, and fail, a hundred times a second).
        let read_errors = || {
            let text = scrape(metrics);
            metric(&text, "strata_store_errors_total{op=\"read\"}").unwrap_or(0.0)
        };
        let before = read_errors();
        assert!(before >= 1.0, "the bad record was met");
        tokio::time::sleep(Duration::from_millis(1500)).await;
        assert_eq!(read_errors(), before, "read again within its retry period");
        assert!(servable.iter().all(|p| c.replica().get(*p).is_some()));
        c.close().await;
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}
