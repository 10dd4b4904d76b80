//! A game-loop session on a cluster: two nodes on one PostgreSQL world,
//! each writing its own region. `Session::connect_cluster` at the west
//! node walks the player across the border: the session joins the east
//! node, an edit beyond the border goes there, and the changed chunk is
//! read from the east node's copy with matching meshes. The C ABI's
//! `strata_connect_cluster` opens the same kind of session. A view the
//! player asked for moves with the player on every node alike, and the
//! east node, joined once it reaches region 1, is asked for it there.

use crate::common::wait_for;

use std::ffi::CString;
use std::path::Path;
use std::time::{Duration, Instant};

use strata::*;
use strata_client::coords::{chunk_at, to_fixed};
use strata_client::glam::DVec3;
use strata_client::terrain::ChunkPos;
use strata_client::{edits, ClientOptions, ClusterClient, Event, Session, SessionOptions};
use strata_protocol::{Refusal, RejectReason, Role};
use strata_server::app::{self, Running};
use strata_server::cluster::ClusterConfig;
use strata_server::config::ServerConfig;
use strata_server::datadir::{CERT_NAME, KEY_NAME, SECRET_NAME};
use strata_server::validate::spawn::SpawnArea;

/// Region 0 is x in 0..256, region 1 x in 256..512 (8-chunk regions).
const WEST_X: i32 = 200;
const EAST_X: i32 = 330;
const Z: i32 = 128;
const WAIT: Duration = Duration::from_secs(20);

fn node_config(
    dir: &Path,
    db: &strata_tests::postgres::PgDb,
    id: &str,
    spawn_x: i32,
) -> ServerConfig {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = dir.to_path_buf();
    cfg.validation.spawn_protection_radius = 0;
    cfg.validation.max_speed = 64.0;
    cfg.validation.spawn = SpawnArea {
        x: spawn_x,
        z: Z,
        radius: 32,
        ..SpawnArea::default()
    };
    cfg.interest.view_radius = 2;
    cfg.engine.tick_ms = 5;
    cfg.store.backend = strata_server::store::StoreBackend::Postgres;
    cfg.store.postgres.url = db.url();
    cfg.cluster = Some(ClusterConfig {
        node_id: id.into(),
        lease_ms: 5_000,
        renew_ms: 500,
        ..ClusterConfig::default()
    });
    cfg
}

fn token(node: &Running, player: &str) -> String {
    strata_server::auth::issue(
        node.data_dir.secret(),
        player,
        Role::Player,
        Duration::from_secs(600),
        strata_server::auth::unix_now(),
    )
    .unwrap()
}

/// Feet on the surface of column (x, Z), and the surface voxel's centre.
fn spot(x: i32) -> (DVec3, DVec3) {
    let g = strata_client::terrain::gen::Generator::fractal(Default::default()).unwrap();
    let y = g.surface_height(x, Z);
    (
        DVec3::new(f64::from(x), y + 1.0, f64::from(Z)),
        DVec3::new(f64::from(x), y.floor(), f64::from(Z)),
    )
}

fn chunk_of(x: i32) -> ChunkPos {
    let (_, v) = spot(x);
    ChunkPos::new(x >> 5, (v.y as i32) >> 5, Z >> 5)
}

fn eventually(mut f: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < WAIT {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

/// Edits at `x` and waits for its acceptance; returns the changed chunks.
fn mine(s: &Session, seen: &mut Vec<Event>, x: i32) -> Vec<strata_protocol::ChunkVersion> {
    let ticket = s.edit(edits::mine(spot(x).1, 3.0, 60).unwrap()).unwrap();
    wait_for(s, seen, |e| match e {
        Event::EditAccepted {
            ticket: t, changes, ..
        } if *t == ticket => Some(changes.clone()),
        Event::EditRejected { ticket: t, reason } if *t == ticket => {
            panic!("edit at x {x} refused: {reason:?}")
        }
        _ => None,
    })
}

/// The west and east nodes on `db`, sharing keys; the temp dir holding
/// their data dirs comes first (keep it).
fn west_and_east(
    runtime: &tokio::runtime::Runtime,
    db: &strata_tests::postgres::PgDb,
) -> (tempfile::TempDir, Running, Running) {
    let dirs = tempfile::tempdir().unwrap();
    let (west_dir, east_dir) = (dirs.path().join("west"), dirs.path().join("east"));
    let west = runtime
        .block_on(app::start(node_config(&west_dir, db, "west", WEST_X)))
        .unwrap();
    // The nodes share the auth secret (tickets) and the certificate.
    std::fs::create_dir_all(&east_dir).unwrap();
    for f in [SECRET_NAME, CERT_NAME, KEY_NAME] {
        std::fs::copy(west_dir.join(f), east_dir.join(f)).unwrap();
    }
    let east = runtime
        .block_on(app::start(node_config(&east_dir, db, "east", EAST_X)))
        .unwrap();
    (dirs, west, east)
}

/// Bob, on the east node alone, claims region 1 for it.
fn bob_claims_region_one(east: &Running) -> Session {
    let bob = Session::connect(
        east.addr,
        &east.cert_der,
        &token(east, "bob"),
        SessionOptions::default(),
    )
    .unwrap();
    bob.set_position(spot(EAST_X).0).unwrap();
    assert!(eventually(|| bob.chunk(chunk_of(EAST_X)).is_some()));
    let mut bob_seen = Vec::new();
    mine(&bob, &mut bob_seen, EAST_X + 2);
    bob
}

/// A database for `test`, the west and east nodes on it, and Bob, who
/// claimed region 1 for the east node. `None` where PostgreSQL is missing
/// outside CI.
fn two_nodes(
    test: &str,
) -> Option<(
    strata_tests::postgres::PgDb,
    tokio::runtime::Runtime,
    tempfile::TempDir,
    Running,
    Running,
    Session,
)> {
    let db = strata_tests::postgres::database(test)?;
    let runtime = tokio::runtime::Runtime::new().unwrap();
    let (dirs, west, east) = west_and_east(&runtime, &db);
    let bob = bob_claims_region_one(&east);
    Some((db, runtime, dirs, west, east, bob))
}

/// Ann on the cluster from the west node, her first edit claiming region
/// 0; the events seen so far.
fn ann_at_west(west: &Running, opts: SessionOptions) -> (Session, Vec<Event>) {
    let ann =
        Session::connect_cluster(west.addr, &west.cert_der, &token(west, "ann"), opts).unwrap();
    ann.set_position(spot(WEST_X).0).unwrap();
    assert!(eventually(|| ann.chunk(chunk_of(WEST_X)).is_some()));
    let mut seen = Vec::new();
    mine(&ann, &mut seen, WEST_X + 2);
    (ann, seen)
}

/// Walks from `x` towards `until`, two voxels every 50 ms.
fn walk(s: &Session, seen: &mut Vec<Event>, mut x: i32, until: i32) {
    let step = if until < x { -2 } else { 2 };
    while (until - x) * step > 0 {
        x += step;
        s.set_position(spot(x).0).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        while let Some(e) = s.poll() {
            seen.push(e);
        }
    }
}

#[test]
fn a_cluster_session_walks_into_another_nodes_region_and_keeps_playing() {
    let Some((_db, runtime, _dirs, west, east, bob)) = two_nodes("sdk_cluster") else {
        return;
    };

    let opts = SessionOptions::default();

    // Ann plays on the cluster from the west node, predicting her edits:
    // her first edit claims region 0.
    let predicting = SessionOptions {
        predict: true,
        ..opts
    };
    let (ann, mut seen) = ann_at_west(&west, predicting);

    // She walks east across the border, two voxels every 50 ms.
    walk(&ann, &mut seen, WEST_X, EAST_X - 4);
    // Her edit beyond the border: the east node takes it (the west node
    // would refuse it), and the chunk is read from the east node's copy.
    let changes = mine(&ann, &mut seen, EAST_X - 2);
    let changed = changes[0];
    assert!(
        eventually(|| ann
            .chunk(changed.pos)
            .is_some_and(|c| c.version >= changed.version)),
        "ann reads {changed:?} from the east node"
    );
    assert!(eventually(|| bob
        .chunk(changed.pos)
        .is_some_and(|c| c.version >= changed.version)));
    // Reported changed, and meshed from what she reads.
    if !seen
        .iter()
        .any(|e| matches!(e, Event::ChunkChanged { pos } if *pos == changed.pos))
    {
        wait_for(&ann, &mut seen, |e| {
            matches!(e, Event::ChunkChanged { pos } if *pos == changed.pos).then_some(())
        });
    }
    assert!(ann.mesh(changed.pos, 0, 0).unwrap().is_some());
    let stats = ann.stats();
    assert!(stats.meshes_checked > 0, "{stats:?}");
    assert_eq!(stats.mesh_mismatches, 0, "{stats:?}");
    // Predicted on both connections: one edit each.
    let predicted = ann.prediction_stats().expect("predicting");
    assert_eq!(predicted.made, 2, "{predicted:?}");
    assert!(!ann.is_closed());
    ann.close();
    bob.close();

    // The C ABI opens the same kind of session.
    let address = CString::new(west.addr.to_string()).unwrap();
    let player = CString::new(token(&west, "cat")).unwrap();
    let options = StrataConnectOptions {
        size: std::mem::size_of::<StrataConnectOptions>() as u32,
        predict: 0,
        capabilities: 0,
    };
    let mut s: *mut StrataSession = std::ptr::null_mut();
    // SAFETY: live strings, the certificate's bytes, writable out pointer.
    let status = unsafe {
        strata_connect_cluster(
            address.as_ptr(),
            west.cert_der.as_ptr(),
            west.cert_der.len(),
            player.as_ptr(),
            &options,
            &mut s,
        )
    };
    assert_eq!(status, StrataStatus::Ok);
    let mut w = std::mem::MaybeUninit::<StrataWelcome>::uninit();
    // SAFETY: a live session and a writable welcome.
    let status = unsafe { strata_welcome(s, w.as_mut_ptr()) };
    assert_eq!(status, StrataStatus::Ok);
    // SAFETY: written by the call above.
    assert_eq!(unsafe { w.assume_init() }.view_radius, 2);
    // Both nodes' connections close under the one documented bound.
    let closing = Instant::now();
    // SAFETY: the live session, freed once.
    unsafe { strata_session_free(s) };
    let took = closing.elapsed();
    assert!(took < Duration::from_millis(2500), "{took:?}");

    runtime.block_on(async {
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    });
}

/// Each node checks the walls of its own regions: a wall the east node
/// writes, which the west node (Ann's home) does not sweep, refuses her
/// walk through it there, and the session reports that node's refusal
/// with where it holds her.
#[test]
fn a_wall_in_another_nodes_region_is_refused_by_that_node() {
    let Some((_db, runtime, _dirs, west, east, bob)) = two_nodes("sdk_cluster_wall") else {
        return;
    };
    // Bob walls off x = 320 and about 2 each side (region 1), from the feet's height
    // at x = 320 less 1 to 10 above (blobs are solid a voxel less than
    // their radius), top down so each is in sight.
    let mut bob_seen = Vec::new();
    walk(&bob, &mut bob_seen, EAST_X, 324);
    let feet_y = spot(320).0.y.floor();
    for dy in [9.0, 6.0, 3.0, 0.0] {
        let blob = edits::build(DVec3::new(320.0, feet_y + dy, f64::from(Z)), 3.0, 2, 255).unwrap();
        let ticket = bob.edit(blob).unwrap();
        wait_for(&bob, &mut bob_seen, |e| match e {
            Event::EditAccepted { ticket: t, .. } if *t == ticket => Some(()),
            Event::EditRejected { ticket: t, reason } if *t == ticket => {
                panic!("bob's wall refused: {reason:?}")
            }
            _ => None,
        });
    }
    let (ann, mut seen) = ann_at_west(&west, SessionOptions::default());
    walk(&ann, &mut seen, WEST_X, 314);
    std::thread::sleep(Duration::from_millis(300));
    ann.set_position(spot(326).0).unwrap();
    let at = wait_for(&ann, &mut seen, |e| match e {
        Event::PositionRefused {
            reason: strata_protocol::PositionRefusal::PathBlocked { voxel },
            at,
            ..
        } => {
            assert!((317..=323).contains(&voxel.x), "in the wall: {voxel:?}");
            Some(*at)
        }
        _ => None,
    });
    let at = at.expect("east holds ann").to_f64();
    assert!(at[0] < 317.0, "held on the near side: {at:?}");
    ann.close();
    bob.close();
    runtime.block_on(async {
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    });
}

/// A view asked for (`subscribe`) follows the player on every node, and a
/// node joined later is asked for it where it is then, not where it was
/// first asked: out of the player's reach by then, the east node would
/// refuse that (`SubscribeTooFar`) and stream its own view instead.
#[test]
fn a_node_joined_after_the_view_moved_streams_it_where_it_is() {
    let Some((_db, runtime, _dirs, west, east, bob)) = two_nodes("sdk_cluster_moved_view") else {
        return;
    };
    // View radius 2, hysteresis 2: a view of radius 1 may be centred 3
    // chunks from the player's.
    let feet = |x: i32| to_fixed(spot(x).0).unwrap();
    let feet_chunk = |x: i32| chunk_at(spot(x).0).unwrap();
    let start = 170;
    runtime.block_on(async {
        let mut ann = ClusterClient::connect(
            west.addr,
            &west.cert_der,
            &token(&west, "ann"),
            ClientOptions::default(),
        )
        .await
        .unwrap();
        // Ann, at the west end of the spawn square, asks for a view of
        // radius 1 one chunk west of hers: region 0 alone.
        ann.send_position(feet(start)).unwrap();
        let here = feet_chunk(start);
        let asked = ChunkPos::new(here.x - 1, here.y, here.z);
        ann.subscribe(asked, 1).await;
        let home_view = |ann: &ClusterClient| ann.home().view_loaded();
        let mut loaded = false;
        for _ in 0..1000 {
            if home_view(&ann) == Some((asked, 1)) {
                loaded = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert!(loaded, "the west node streams the view asked");

        // She walks east into region 1 (x 256..), two voxels every 50 ms:
        // the view follows her there, and the client joins the east node.
        let mut x = start;
        while x < 300 {
            x += 2;
            ann.send_position(feet(x)).unwrap();
            ann.follow().await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let mut settled = None;
        for _ in 0..1000 {
            ann.follow().await.unwrap();
            let views = ann
                .node(east.addr)
                .map(|c| (home_view(&ann), c.view_loaded()));
            if let Some((Some(w), Some(e))) = views {
                settled = Some((w, e));
                if w == e {
                    break;
                }
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let there = ann.node(east.addr).expect("joined the east node");
        let refused: Vec<Refusal> = ann.nodes().flat_map(|(_, c)| c.refusals()).collect();
        assert!(refused.is_empty(), "{refused:?}");
        // Both nodes stream the view of radius 1 around her chunk: the
        // east node the view where it is, not where it was asked.
        let (w, e) = settled.expect("both nodes loaded a view");
        assert_eq!(e, w, "the east node streams the west node's view");
        let (center, radius) = e;
        assert_eq!(radius, 1, "the radius asked");
        let now = feet_chunk(x);
        assert!(
            center.x >= 8 && center.chebyshev(now) <= 1,
            "{center:?} near {now:?}"
        );
        for c in [now, ChunkPos::new(center.x + 1, center.y, center.z)] {
            assert!(there.replica().get(c).is_some(), "{c:?} on the east node");
            assert_eq!(ann.route(c), east.addr);
            assert!(ann.chunk(c).is_some());
        }
        ann.close().await;
    });
    bob.close();
    runtime.block_on(async {
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    });
}

/// Mines a small hole at column `x` (radius 2: within one region), without
/// waiting; returns its ticket.
fn mine_small(s: &Session, x: i32) -> u64 {
    s.edit(edits::mine(spot(x).1, 2.0, 60).unwrap()).unwrap()
}

/// A node that stops answering (here: its commits wait on a region row
/// another transaction locked) holds up only the edits sent to it: the
/// session sends the next edit, for another node's region, at once, and
/// its verdict comes while the first still waits.
#[test]
fn a_node_that_stops_answering_holds_up_no_other_nodes_edits() {
    let Some((db, runtime, _dirs, west, east, bob)) = two_nodes("sdk_cluster_stall") else {
        return;
    };
    let (ann, mut seen) = ann_at_west(&west, SessionOptions::default());
    // Past the border (region 1 starts at x 256), her last position let
    // reach both nodes.
    walk(&ann, &mut seen, WEST_X, 258);
    std::thread::sleep(Duration::from_millis(200));
    let verdict = |ticket: u64| {
        move |e: &Event| match e {
            Event::EditAccepted { ticket: t, .. } if *t == ticket => Some(true),
            Event::EditRejected { ticket: t, reason } if *t == ticket => {
                panic!("edit {ticket} refused: {reason:?}")
            }
            Event::EditFailed { ticket: t, error } if *t == ticket => {
                panic!("edit {ticket} failed: {error}")
            }
            _ => None,
        }
    };
    // The east node takes her edits in region 1, once she is routed there
    // (until then the west node refuses them, naming it).
    let start = Instant::now();
    loop {
        let first = mine_small(&ann, 261);
        let accepted = wait_for(&ann, &mut seen, |e| match e {
            Event::EditAccepted { ticket, .. } if *ticket == first => Some(true),
            Event::EditRejected {
                ticket,
                reason: RejectReason::RegionElsewhere { .. },
            } if *ticket == first => Some(false),
            _ => verdict(first)(e),
        });
        if accepted {
            break;
        }
        assert!(start.elapsed() < WAIT, "{seen:?}");
        std::thread::sleep(Duration::from_millis(300));
    }

    // East's next commit waits on region 1's row.
    let held = db
        .hold("SELECT 1 FROM regions WHERE region_x = 1 AND region_z = 0 FOR UPDATE")
        .unwrap();
    let stuck = mine_small(&ann, 262);
    // The next edit of that region waits behind it, on the client (sent
    // once the first is answered, it is judged where Ann stands then).
    let behind = mine_small(&ann, 263);
    // Back in region 0 (her sight of region 0 from region 1 would need the
    // east node to write both).
    walk(&ann, &mut seen, 258, 250);
    let west_edit = mine_small(&ann, 246);
    let answered = wait_for(&ann, &mut seen, |e| match e {
        Event::EditAccepted { ticket, .. } | Event::EditRejected { ticket, .. } => {
            [stuck, west_edit].contains(ticket).then_some(*ticket)
        }
        Event::EditFailed { ticket, error } if [stuck, west_edit].contains(ticket) => {
            panic!("edit {ticket} failed: {error}")
        }
        _ => None,
    });
    assert_eq!(answered, west_edit, "{seen:?}");
    assert!(
        seen.iter().any(|e| matches!(e,
            Event::EditAccepted { ticket, .. } if *ticket == west_edit)),
        "{seen:?}"
    );
    // Once the row is free the east node commits and answers.
    held.release();
    wait_for(&ann, &mut seen, verdict(stuck));
    wait_for(&ann, &mut seen, |e| match e {
        Event::EditAccepted { ticket, .. } | Event::EditRejected { ticket, .. } => {
            (*ticket == behind).then_some(())
        }
        _ => None,
    });
    let order: Vec<u64> = seen
        .iter()
        .filter_map(|e| match e {
            Event::EditAccepted { ticket, .. } | Event::EditRejected { ticket, .. } => {
                Some(*ticket)
            }
            _ => None,
        })
        .filter(|t| [stuck, behind, west_edit].contains(t))
        .collect();
    assert_eq!(order, vec![west_edit, stuck, behind]);

    ann.close();
    bob.close();
    runtime.block_on(async {
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    });
}
