//! Online admin protocol: a consistent snapshot under concurrent edits,
//! restored into a new data dir that a server then serves exactly; online
//! snapshots refused on a cluster node; and player tokens that can reach
//! no admin request.

use crate::common;
use crate::snapshot_common;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use common::*;
use snapshot_common::{assert_snapshot_is_log_at, spot};
use strata_client_sim::{Client, Verdict};
use strata_protocol::admin::{
    AdminHello, AdminRequest, AdminResponse, ZoneSpec, ADMIN_ALPN, ADMIN_PROTOCOL_VERSION,
};
use strata_protocol::io::FramedReader;
use strata_protocol::{encode_frame, Direction, ErrorCode, FrameBuffer, Role};
use strata_server::admin::remote::AdminClient;
use strata_server::admin::snapshot_cmd::{self, RestoreArgs};
use strata_server::app;
use strata_server::client_tls::client_config_pinned_with_alpn;
use strata_server::cluster::ClusterConfig;
use strata_server::engine::snapshot::SnapshotRefused;
use strata_server::snapshot::verify;
use strata_server::store::{ChunkStore, SledStore, StoreBackend};
use strata_terrain::hash::chunk_hash;
use strata_terrain::{ChunkPos, Edit, FixedVec3, VoxelPos};

/// Edits per second each test player may make (the default is far lower).
const EDIT_RATE: u64 = 1000;

async fn start_fast(dir: &std::path::Path) -> app::Running {
    let mut cfg = test_config(dir);
    cfg.validation.edit_rate.capacity = EDIT_RATE;
    cfg.validation.edit_rate.per_second = EDIT_RATE;
    cfg.validation.volume_rate.capacity = 1 << 30;
    cfg.validation.volume_rate.per_second = 1 << 30;
    app::start(cfg).await.expect("server starts")
}

/// Edits near `ground` until `stop`, alternating mining and building so
/// every edit changes voxels. Returns the accepted seqs.
async fn keep_editing(c: Arc<Client>, ground: VoxelPos, stop: Arc<AtomicBool>) -> Vec<u64> {
    let mut seqs = Vec::new();
    let mut i = 0i32;
    while !stop.load(Ordering::Relaxed) {
        let center =
            FixedVec3::from_voxels(ground.x + (i % 5) - 2, ground.y, ground.z + (i % 3) - 1);
        let edit = if i % 2 == 0 {
            Edit::Mine {
                center,
                radius: r(2.0),
                strength: 255,
            }
        } else {
            Edit::Build {
                center,
                radius: r(2.0),
                material: 7,
                strength: 255,
            }
        };
        if let Ok(Verdict::Accepted { seq }) = c.edit(edit).await {
            seqs.push(seq);
        }
        i += 1;
    }
    seqs
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn online_snapshot_under_load_restores_the_world_at_its_seq() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let tmp = tempfile::tempdir().unwrap();
        let data = tmp.path().join("data");
        let server = start_fast(&data).await;
        let admin_token = token(&server, "root", Role::Admin);
        let mut admin = AdminClient::connect(server.addr, &server.cert_der, &admin_token).await.unwrap();
        // A zone, so the snapshot carries one.
        let zone = ZoneSpec { name: "keep".into(), min: VoxelPos::new(500, 0, 500), max: VoxelPos::new(510, 10, 510) };
        assert!(matches!(admin.request(&AdminRequest::ZoneAdd(zone.clone())).await.unwrap(), AdminResponse::Zones(z) if z.contains(&zone)));

        let stop = Arc::new(AtomicBool::new(false));
        let mut workers = Vec::new();
        let mut grounds = Vec::new();
        for (i, x) in [70, 100, 130].into_iter().enumerate() {
            let c = Arc::new(connect(&server, &format!("p{i}"), Role::Player).await);
            let (feet, ground) = spot(x, 40);
            c.send_position(feet).unwrap();
            assert!(eventually(Duration::from_secs(10), || c.replica().get(ground.chunk()).is_some()).await);
            grounds.push(ground);
            workers.push(tokio::spawn(keep_editing(c, ground, stop.clone())));
        }
        tokio::time::sleep(Duration::from_millis(400)).await;
        let file = tmp.path().join("world.snap");
        let created = snapshot_cmd::create_online(&mut admin, &file, 0).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        stop.store(true, Ordering::Relaxed);
        let mut acked = Vec::new();
        for w in workers {
            acked.extend(w.await.unwrap());
        }
        admin.close().await;
        server.shutdown().await.unwrap();

        let s = created.seq;
        assert!(acked.iter().any(|&q| q <= s), "edits before the snapshot");
        assert!(acked.iter().any(|&q| q > s), "edits kept flowing after the snapshot's seq");
        let report = verify(&file, |_| {}).unwrap();
        assert!(report.is_ok(), "{:?}", report.issues);
        assert_eq!(report.header.as_ref().unwrap().zones.last(), Some(&zone));

        // The snapshot equals the log replayed to S, chunk hash for chunk hash.
        let (store, mut world, versions) = assert_snapshot_is_log_at(&data, &file, s);
        // No acknowledged edit after S appears in it.
        for q in acked.iter().filter(|&&q| q > s) {
            let e = store.log_entry(*q).unwrap().unwrap();
            for (pos, v) in e.changes {
                assert!(versions.get(&pos).is_none_or(|&have| have < v), "seq {q} leaked into the snapshot");
            }
        }
        drop(store);

        // Restore into a new data dir; a server there serves exactly that world.
        let restored = tmp.path().join("restored");
        let n = snapshot_cmd::restore(&RestoreArgs { drop_access: false, file: file.clone(), data_dir: restored.clone(), force: false, config: None }).unwrap();
        assert_eq!(n, versions.len() as u64);
        let again = snapshot_cmd::restore(&RestoreArgs { drop_access: false, file: file.clone(), data_dir: restored.clone(), force: false, config: None });
        assert!(again.unwrap_err().to_string().contains("--force"));
        let server = start_fast(&restored).await;
        let c = connect(&server, "viewer", Role::Player).await;
        assert_eq!(c.welcome().last_seq, s);
        for g in &grounds {
            c.subscribe(g.chunk(), 1).await.unwrap();
            let pos = g.chunk();
            assert!(eventually(Duration::from_secs(10), || c.replica().get(pos).is_some()).await);
            let held = c.replica().get(pos).unwrap().clone();
            assert_eq!(held.version, versions.get(&pos).copied().unwrap_or(0));
            assert_eq!(chunk_hash(&held.chunk), chunk_hash(&world.chunk(pos).chunk));
        }
        // Edits continue after S on the restored world, and its store checks clean.
        let mut admin = AdminClient::connect(server.addr, &server.cert_der, &token(&server, "root", Role::Admin)).await.unwrap();
        match admin.request(&AdminRequest::Zones).await.unwrap() {
            AdminResponse::Zones(z) => assert!(z.contains(&zone)),
            other => panic!("{other:?}"),
        }
        admin.close().await;
        c.close().await;
        let dd = server.data_dir.world_db_path();
        server.shutdown().await.unwrap();
        let report = SledStore::open(&dd).unwrap().check().unwrap();
        assert!(report.is_ok(), "{:?}", report.issues);
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cluster_node_refuses_online_snapshots() {
    let Some(db) = strata_tests::postgres::database("a_cluster_node_refuses_online_snapshots")
    else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let tmp = tempfile::tempdir().unwrap();
        let mut cfg = test_config(tmp.path());
        cfg.store.backend = StoreBackend::Postgres;
        cfg.store.postgres.url = db.url();
        cfg.cluster = Some(ClusterConfig {
            node_id: "a".into(),
            ..ClusterConfig::default()
        });
        let server = app::start(cfg).await.expect("node starts");
        let mut admin = AdminClient::connect(
            server.addr,
            &server.cert_der,
            &token(&server, "root", Role::Admin),
        )
        .await
        .unwrap();
        let file = tmp.path().join("world.snap");
        let err = snapshot_cmd::create_online(&mut admin, &file, 0)
            .await
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&SnapshotRefused::Clustered.to_string()),
            "{err}"
        );
        assert!(err.contains("offline snapshot"), "{err}");
        assert!(!file.exists());
        let left: Vec<_> = std::fs::read_dir(tmp.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .filter(|n| n.to_string_lossy().ends_with(".partial"))
            .collect();
        assert!(left.is_empty(), "{left:?}");
        admin.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Every admin request kind, with arguments.
fn all_requests() -> Vec<AdminRequest> {
    vec![
        AdminRequest::Stats,
        AdminRequest::Players,
        AdminRequest::Kick {
            player: "victim".into(),
        },
        AdminRequest::Zones,
        AdminRequest::ZoneAdd(ZoneSpec {
            name: "evil".into(),
            min: VoxelPos::new(0, 0, 0),
            max: VoxelPos::new(1, 1, 1),
        }),
        AdminRequest::ZoneRemove {
            name: "spawn".into(),
        },
        AdminRequest::InspectChunk {
            pos: ChunkPos::new(0, 0, 0),
        },
        AdminRequest::Snapshot {
            max_pending_chunks: 0,
        },
    ]
}

#[tokio::test]
async fn player_tokens_reach_no_admin_request() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let tmp = tempfile::tempdir().unwrap();
        let server = start_fast(tmp.path()).await;
        let victim = connect(&server, "victim", Role::Player).await;
        let player_token = token(&server, "mallory", Role::Player);
        for req in all_requests() {
            let hello = AdminRequest::Hello(AdminHello { protocol_version: ADMIN_PROTOCOL_VERSION, token: player_token.clone() });
            let frames = vec![
                encode_frame(&hello, Direction::ClientToServer).unwrap(),
                encode_frame(&req, Direction::ClientToServer).unwrap(),
            ];
            let (answers, code) = admin_exchange(&server, frames).await;
            assert_eq!(answers.len(), 1, "{req:?}: {answers:?}");
            assert!(matches!(&answers[0], AdminResponse::Error { code: ErrorCode::Forbidden, message } if message.contains("role admin")), "{req:?}: {answers:?}");
            assert_eq!(code, Some(ErrorCode::Forbidden.close_code() as u64));
            // Without a Hello at all, the request is not served either.
            let (answers, _) = admin_exchange(&server, vec![encode_frame(&req, Direction::ClientToServer).unwrap()]).await;
            assert!(matches!(&answers[..], [AdminResponse::Error { code: ErrorCode::NotAuthenticated, .. }]), "{req:?}: {answers:?}");
        }
        // Admin requests cannot be expressed on the player protocol: even an
        // admin-role player session gets Malformed for their bytes.
        for req in all_requests() {
            let c = connect(&server, "root", Role::Admin).await;
            c.send_raw(encode_frame(&req, Direction::ClientToServer).unwrap()).await.unwrap();
            let end = tokio::time::timeout(Duration::from_secs(10), c.closed()).await.expect("session closed");
            assert!(end.to_string().contains("Malformed"), "{req:?}: {end}");
        }
        // Nothing happened: the victim is still connected, zones unchanged.
        assert!(!victim.is_closed());
        let mut admin = AdminClient::connect(server.addr, &server.cert_der, &token(&server, "root", Role::Admin)).await.unwrap();
        match admin.request(&AdminRequest::Zones).await.unwrap() {
            AdminResponse::Zones(z) => assert!(z.iter().all(|z| z.name != "evil")),
            other => panic!("{other:?}"),
        }
        // An admin may kick; the victim's session ends with Kicked.
        assert_eq!(admin.request(&AdminRequest::Kick { player: "victim".into() }).await.unwrap(), AdminResponse::Kicked { sessions: 1 });
        let end = tokio::time::timeout(Duration::from_secs(10), victim.closed()).await.unwrap();
        assert!(end.to_string().contains("Kicked"), "{end}");
        admin.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// `raw_exchange` on the admin ALPN, decoding the answers.
async fn admin_exchange(
    server: &app::Running,
    frames: Vec<Vec<u8>>,
) -> (Vec<AdminResponse>, Option<u64>) {
    let mut endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    endpoint.set_default_client_config(
        client_config_pinned_with_alpn(&server.cert_der, ADMIN_ALPN).unwrap(),
    );
    let conn = endpoint
        .connect(server.addr, "localhost")
        .unwrap()
        .await
        .unwrap();
    let (mut send, recv) = conn.open_bi().await.unwrap();
    for f in frames {
        send.write_all(&f).await.unwrap();
    }
    let mut reader = FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient));
    let mut got = Vec::new();
    while let Ok(Some(m)) = reader.next::<AdminResponse>().await {
        got.push(m);
    }
    let code = match conn.closed().await {
        quinn::ConnectionError::ApplicationClosed(a) => Some(a.error_code.into_inner()),
        _ => None,
    };
    (got, code)
}
