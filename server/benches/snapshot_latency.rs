//! Edit acknowledgement latency while online snapshots stream.
//!
//! A real server (loopback QUIC, sled in a temp dir, default tick) is
//! filled with several thousand modified chunks. Two workloads then run
//! for a few seconds each, first alone and then while `snapshot create`
//! runs back to back: a player making small edits (one outstanding at a
//! time), and an admin refilling 128-voxel boxes of stored chunks (each
//! edit makes the engine save ~80 pre-images). Prints p50/p99/max of the
//! time from sending an edit to its `EditAccepted`.
//!
//! `cargo bench -p strata-server --bench snapshot_latency`

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use strata_client_sim::{Client, Verdict};
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_protocol::Role;
use strata_server::admin::remote::AdminClient;
use strata_server::admin::snapshot_cmd;
use strata_server::app::{self, Running};
use strata_server::auth;
use strata_server::config::ServerConfig;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::material::ids;
use strata_terrain::{Edit, Fixed, FixedVec3, VoxelPos};

/// Regions filled before measuring (each ~320 sky chunks + ~50 cut terrain chunks).
const REGIONS: i32 = 12;
/// Width (x and z) of a region: four 128-voxel boxes around its player.
const REGION: i32 = 256;
const EDGE: i32 = 128;
/// How long each workload runs in each phase.
const PHASE: Duration = Duration::from_secs(4);

fn config(dir: &Path) -> ServerConfig {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = dir.to_path_buf();
    cfg.validation.spawn_protection_radius = 0;
    cfg.validation.edit_rate.capacity = 10_000;
    cfg.validation.edit_rate.per_second = 10_000;
    cfg.validation.volume_rate.capacity = 1 << 40;
    cfg.validation.volume_rate.per_second = 1 << 40;
    cfg.validation.los_tolerance = 2.0;
    cfg.interest.view_radius = 1;
    cfg
}

fn token(server: &Running, player: &str, role: Role) -> String {
    let ttl = Duration::from_secs(3600);
    auth::issue(
        server.data_dir.secret(),
        player,
        role,
        ttl,
        auth::unix_now(),
    )
    .unwrap()
}

/// A connected player standing on the ground at (x, z); returns the ground voxel.
async fn player(server: &Running, name: &str, role: Role, x: i32, z: i32) -> (Client, VoxelPos) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let y = g.surface_height(x, z);
    let c = Client::connect(server.addr, &server.cert_der, &token(server, name, role))
        .await
        .unwrap();
    c.send_position(FixedVec3::from_f64([x as f64, y + 1.0, z as f64]).unwrap())
        .unwrap();
    let ground = VoxelPos::new(x, y.floor() as i32, z);
    let start = Instant::now();
    while c.replica().get(ground.chunk()).is_none() {
        assert!(start.elapsed() < Duration::from_secs(30), "no interest");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    (c, ground)
}

/// Four boxes around `ground`, each with a corner by the player's head.
fn boxes(ground: VoxelPos, y0: i32, height: i32, fill: Option<u8>) -> Vec<Edit> {
    let (x, z) = (ground.x, ground.z);
    [(x - EDGE, z - EDGE), (x, z - EDGE), (x - EDGE, z), (x, z)]
        .into_iter()
        .map(|(x0, z0)| {
            let (min, max) = (
                VoxelPos::new(x0, y0, z0),
                VoxelPos::new(x0 + EDGE - 1, y0 + height - 1, z0 + EDGE - 1),
            );
            match fill {
                Some(material) => Edit::FillBox { min, max, material },
                None => Edit::ClearBox { min, max },
            }
        })
        .collect()
}

/// Time from sending to acceptance.
async fn timed(c: &Client, e: Edit) -> Duration {
    let t = Instant::now();
    match c.edit(e.clone()).await.unwrap() {
        Verdict::Accepted { .. } => t.elapsed(),
        other => panic!("{e:?}: {other:?}"),
    }
}

/// Small alternating mine/build edits next to `ground` for `PHASE`.
async fn small_edits(c: &Client, ground: VoxelPos) -> Vec<Duration> {
    let (mut out, start, mut i) = (Vec::new(), Instant::now(), 0i32);
    while start.elapsed() < PHASE {
        let center =
            FixedVec3::from_voxels(ground.x + (i % 5) - 2, ground.y, ground.z + (i % 3) - 1);
        let r = Fixed::from_voxels(2);
        let e = if i % 2 == 0 {
            Edit::Mine {
                center,
                radius: r,
                strength: 255,
            }
        } else {
            Edit::Build {
                center,
                radius: r,
                material: ids::DIRT,
                strength: 255,
            }
        };
        out.push(timed(c, e).await);
        i += 1;
    }
    out
}

/// Refills a region's boxes with alternating materials for `PHASE`: every
/// edit changes ~80 stored chunks.
async fn refills(c: &Client, ground: VoxelPos, y0: i32) -> Vec<Duration> {
    let (mut out, start, mut i) = (Vec::new(), Instant::now(), 0usize);
    while start.elapsed() < PHASE {
        let m = if (i / 4) % 2 == 0 {
            ids::DIRT
        } else {
            ids::STONE
        };
        let e = boxes(ground, y0, EDGE, Some(m)).swap_remove(i % 4);
        out.push(timed(c, e).await);
        i += 1;
    }
    out
}

/// Where the snapshot stream goes: a file, as `snapshot create` writes
/// it (with its fsync), or nowhere (the server's side alone).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sink {
    File,
    Discard,
}

/// Streams snapshots back to back until `stop`; returns (count, chunks, total time).
async fn snapshots(
    server: &Running,
    out: &Path,
    sink: Sink,
    stop: Arc<AtomicBool>,
) -> (u32, u64, Duration) {
    let mut admin = AdminClient::connect(
        server.addr,
        &server.cert_der,
        &token(server, "root", Role::Admin),
    )
    .await
    .unwrap();
    let (mut n, mut chunks, start) = (0, 0, Instant::now());
    while !stop.load(Ordering::Relaxed) {
        chunks = match sink {
            Sink::File => {
                snapshot_cmd::create_online(&mut admin, out, 0)
                    .await
                    .unwrap()
                    .chunks
            }
            Sink::Discard => {
                admin
                    .send(&AdminRequest::Snapshot {
                        max_pending_chunks: 0,
                    })
                    .await
                    .unwrap();
                loop {
                    match admin.next().await.unwrap() {
                        AdminResponse::SnapshotEnd { chunks } => break chunks,
                        AdminResponse::SnapshotBegin(_) | AdminResponse::SnapshotChunk { .. } => {}
                        other => panic!("{other:?}"),
                    }
                }
            }
        };
        n += 1;
    }
    admin.close().await;
    (n, chunks, start.elapsed())
}

fn report(label: &str, mut d: Vec<Duration>) {
    d.sort();
    let at = |q: f64| d[((d.len() - 1) as f64 * q) as usize].as_secs_f64() * 1000.0;
    println!(
        "{label:<52} n={:<5} p50={:>6.2} ms  p99={:>6.2} ms  max={:>6.2} ms",
        d.len(),
        at(0.5),
        at(0.99),
        at(1.0)
    );
}

/// Runs `work` alone, then while snapshots stream to each sink, and reports.
async fn measure<F: std::future::Future<Output = Vec<Duration>>>(
    server: &Running,
    dir: &Path,
    label: &str,
    mut work: impl FnMut() -> F,
) {
    report(&format!("{label}, no snapshot"), work().await);
    for sink in [Sink::File, Sink::Discard] {
        let stop = Arc::new(AtomicBool::new(false));
        let file = dir.join("bench.snap");
        let snaps = snapshots(server, &file, sink, stop.clone());
        let (lat, (n, chunks, took)) = tokio::join!(
            async {
                let l = work().await;
                stop.store(true, Ordering::Relaxed);
                l
            },
            snaps
        );
        report(&format!("{label}, snapshots to {sink:?}"), lat);
        println!(
            "{:<52} {n} snapshots of {chunks} chunks, {:.0} ms each",
            "",
            took.as_secs_f64() * 1000.0 / n.max(1) as f64
        );
    }
}

fn main() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let tmp = tempfile::tempdir().unwrap();
        let server = app::start(config(&tmp.path().join("data"))).await.unwrap();
        let built = Instant::now();
        let mut regions = Vec::new();
        for i in 0..REGIONS {
            let x = REGION * i + REGION / 2;
            let (c, ground) =
                player(&server, &format!("builder{i}"), Role::Admin, x, REGION / 2).await;
            // Cut the terrain under the region (dense chunks), fill the sky above (uniform ones).
            for e in boxes(ground, ground.y - 24, 28, None) {
                timed(&c, e).await;
            }
            for e in boxes(ground, ground.y + 4, EDGE, Some(ids::STONE)) {
                timed(&c, e).await;
            }
            regions.push((c, ground));
        }
        let mut admin = AdminClient::connect(
            server.addr,
            &server.cert_der,
            &token(&server, "root", Role::Admin),
        )
        .await
        .unwrap();
        let stats = admin.request(&AdminRequest::Stats).await.unwrap();
        admin.close().await;
        if let AdminResponse::Stats(s) = stats {
            println!(
                "world: {} modified chunks, {:.1} MB on disk, built in {:.1} s",
                s.modified_chunks,
                s.store_bytes as f64 / 1e6,
                built.elapsed().as_secs_f64()
            );
        }

        let (walker, ground) = player(&server, "walker", Role::Player, -200, -200).await;
        measure(&server, tmp.path(), "small edits (1 outstanding)", || {
            small_edits(&walker, ground)
        })
        .await;
        let (c, g) = &regions[REGIONS as usize / 2];
        measure(
            &server,
            tmp.path(),
            "128^3 refills of stored chunks",
            || refills(c, *g, g.y + 4),
        )
        .await;

        walker.close().await;
        for (c, _) in regions {
            c.close().await;
        }
        server.shutdown().await.unwrap();
    });
}
