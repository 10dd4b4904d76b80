//! Client-side prediction against an in-process server over real QUIC: an
//! accepted edit shows at once and is counted exact, a rejected one rolls
//! back, and another player's edit sequenced before ours (while our
//! updates are held back) makes a misprediction. Afterwards the predicted
//! view always equals the authoritative replica.

use std::time::Duration;

use strata_client_sim::{Client, ClientOptions, PredictionStats, Verdict};
use strata_protocol::{RejectReason, Role};
use strata_server::app::{self, Running};
use strata_server::auth;
use strata_server::config::ServerConfig;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::material::ids;
use strata_terrain::{ChunkPos, Edit, Fixed, FixedVec3, VoxelPos};

const TEST_TIMEOUT: Duration = Duration::from_secs(30);
const WAIT: Duration = Duration::from_secs(10);

async fn start(dir: &std::path::Path) -> Running {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = dir.to_path_buf();
    cfg.validation.spawn_protection_radius = 0;
    cfg.interest.view_radius = 2;
    cfg.engine.tick_ms = 5;
    app::start(cfg).await.unwrap()
}

async fn connect(server: &Running, player: &str, predict: bool) -> Client {
    let token = auth::issue(
        server.data_dir.secret(),
        player,
        Role::Player,
        Duration::from_secs(600),
        auth::unix_now(),
    )
    .unwrap();
    let opts = ClientOptions {
        predict,
        ..Default::default()
    };
    Client::connect_opts(server.addr, &server.cert_der, &token, opts)
        .await
        .unwrap()
}

/// Polls `f` every 10 ms until it is true or [`WAIT`] passes.
async fn eventually(mut f: impl FnMut() -> bool) -> bool {
    let start = std::time::Instant::now();
    while start.elapsed() < WAIT {
        if f() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    f()
}

/// The surface voxel of column `(x, z)` (away from spawn), and the feet
/// position above it.
fn spot(x: i32, z: i32) -> (VoxelPos, FixedVec3) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let y = g.surface_height(x, z);
    let feet = FixedVec3::from_f64([x as f64, y + 1.0, z as f64]).unwrap();
    (VoxelPos::new(x, y.floor() as i32, z), feet)
}

/// Stands the client at `feet` and waits until it holds every chunk
/// within one chunk of `around`.
async fn stand(c: &Client, feet: FixedVec3, around: &[VoxelPos]) {
    c.send_position(feet).unwrap();
    let needed: Vec<ChunkPos> = around
        .iter()
        .flat_map(|v| {
            let p = v.chunk();
            (-1..=1).flat_map(move |dz| {
                (-1..=1).flat_map(move |dy| (-1..=1).map(move |dx| p.offset(dx, dy, dz).unwrap()))
            })
        })
        .collect();
    assert!(
        eventually(|| {
            let r = c.replica();
            needed.iter().all(|p| r.get(*p).is_some())
        })
        .await,
        "the chunks around arrive"
    );
}

fn stats(c: &Client) -> PredictionStats {
    c.prediction_stats().expect("predicting")
}

/// Waits until nothing is pending, then checks the predicted view shows
/// exactly the replica.
async fn assert_settled(c: &Client, touched: &[VoxelPos]) {
    assert!(eventually(|| stats(c).pending == 0).await, "{:?}", stats(c));
    assert!(c.predicted_chunks().is_empty());
    for v in touched {
        let r = c.replica().get(v.chunk()).unwrap().chunk.clone();
        assert_eq!(*c.predicted_chunk(v.chunk()).unwrap(), *r);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn accepted_edits_show_at_once_and_are_exact_and_rejected_ones_roll_back() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let a = connect(&server, "ana", true).await;
        let (_, feet) = spot(80, 48);
        let (target, _) = spot(82, 48);
        let (far, _) = spot(110, 48);
        stand(&a, feet, &[target, far]).await;

        // Hold our updates so the edit's own delta cannot reach the
        // replica: after the verdict, only the predicted view shows it.
        a.pause_updates();
        let before = a.replica().voxel(target).unwrap();
        let edit = Edit::Mine {
            center: FixedVec3::from_voxels(target.x, target.y, target.z),
            radius: Fixed::from_voxels(3),
            strength: 255,
        };
        let (verdict, changes) = a.edit_acked(edit).await.unwrap();
        assert!(matches!(verdict, Verdict::Accepted { .. }), "{verdict:?}");
        assert!(!changes.is_empty());
        assert_eq!(a.replica().voxel(target), Some(before));
        let shown = a.predicted_voxel(target).unwrap();
        assert!(shown.density < before.density, "{shown:?} vs {before:?}");
        let s = stats(&a);
        assert_eq!((s.made, s.pending, s.exact), (1, 1, 0), "{s:?}");
        a.resume_updates();
        assert_settled(&a, &[target]).await;
        let s = stats(&a);
        assert_eq!((s.made, s.exact, s.mispredicted), (1, 1, 0), "{s:?}");
        for c in &changes {
            assert_eq!(a.replica().get(c.pos).unwrap().version, c.version);
        }
        assert_eq!(a.predicted_voxel(target), a.replica().voxel(target));

        // Out of reach: refused by the server, predicted by the client.
        let before = a.replica().voxel(far).unwrap();
        let edit = Edit::Mine {
            center: FixedVec3::from_voxels(far.x, far.y, far.z),
            radius: Fixed::from_voxels(3),
            strength: 255,
        };
        let verdict = a.edit(edit).await.unwrap();
        assert!(
            matches!(verdict, Verdict::Rejected(RejectReason::OutOfReach { .. })),
            "{verdict:?}"
        );
        let s = stats(&a);
        assert_eq!((s.made, s.rolled_back, s.pending), (2, 1, 0), "{s:?}");
        assert_eq!(a.predicted_voxel(far), Some(before));
        assert_settled(&a, &[target, far]).await;
        assert_eq!(a.replica().stats.mesh_mismatches, 0);
        a.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finishes in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn another_players_edit_sequenced_first_is_a_misprediction() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let a = connect(&server, "ana", true).await;
        let b = connect(&server, "bo", false).await;
        let (ground, feet) = spot(80, 48);
        let theirs_at = VoxelPos::new(ground.x + 3, ground.y + 3, ground.z);
        let ours_at = VoxelPos::new(ground.x + 5, ground.y + 3, ground.z);
        stand(&a, feet, &[theirs_at, ours_at]).await;
        stand(&b, feet, &[theirs_at]).await;
        let build = |at: VoxelPos, material| Edit::Build {
            center: FixedVec3::from_voxels(at.x, at.y, at.z),
            radius: Fixed::from_voxels(2),
            material,
            strength: 255,
        };
        // Ana lags: Bo's edit is sequenced and acknowledged before hers,
        // but her prediction is made on the world without it.
        a.pause_updates();
        let theirs = b.edit(build(theirs_at, ids::BRICK)).await.unwrap();
        let ours = a.edit(build(ours_at, ids::STONE)).await.unwrap();
        match (theirs, ours) {
            (Verdict::Accepted { seq: t }, Verdict::Accepted { seq: o }) => assert!(t < o),
            v => panic!("both edits are accepted: {v:?}"),
        }
        let s = stats(&a);
        assert_eq!((s.made, s.pending), (1, 1), "{s:?}");
        a.resume_updates();
        assert_settled(&a, &[theirs_at, ours_at]).await;
        let s = stats(&a);
        assert_eq!(
            (s.made, s.exact, s.mispredicted, s.rolled_back),
            (1, 0, 1, 0),
            "{s:?}"
        );
        // Both edits are in the view the player sees.
        let brick = a.predicted_voxel(theirs_at).unwrap();
        assert_eq!((brick.density, brick.material), (255, ids::BRICK));
        assert_eq!(a.predicted_voxel(ours_at).unwrap().material, ids::STONE);
        a.close().await;
        b.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finishes in time");
}
