//! Routing on a cluster: two nodes on one PostgreSQL world, each writing
//! its own region. A player connected to the first walks across the
//! border into the second's region and keeps playing: the first node
//! names the second (`RegionOwners`), the client library connects there
//! and arrives with the first node's ticket, and its edit beyond the
//! border goes to the second node. Nothing is disconnected and every
//! replica's versions rise one by one with matching meshes.
//!
//! And bots (`strata-bots --follow-owners`) sent to the wrong node move
//! to the one their `RegionElsewhere` names and keep editing there.
//! A node at its region limit refuses an edit in a free region with
//! `NodeFull`, and the client library passes it to the other node.
//! Bans made on either node hold on both (the access list is shared).
//! A login whose stored position is not read in time, or fails, is
//! refused retryable, with at most `[cluster] position_reads` at once.

use crate::common;

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use common::*;
use strata_client_sim::{client::Verdict, ClientOptions, ClusterClient};
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_protocol::{ErrorCode, RegionHolder, Role};
use strata_server::admin::remote::AdminClient;
use strata_server::app::{self, Running};
use strata_server::cluster::ClusterConfig;
use strata_server::datadir::{CERT_NAME, KEY_NAME, SECRET_NAME};
use strata_server::engine::RELOAD_RETRY;
use strata_server::net::admin_session::ACCESS_RELOAD_PERIOD;
use strata_server::validate::spawn::SpawnArea;
use strata_terrain::{ChunkPos, Edit, FixedVec3};

/// Region 0 is x in 0..256, region 1 is x in 256..512 (8-chunk regions).
const WEST_X: i32 = 200;
const EAST_X: i32 = 330;
const Z: i32 = 128;

/// The nodes share the auth secret (tickets) and the certificate.
fn share_keys(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for f in [SECRET_NAME, CERT_NAME, KEY_NAME] {
        std::fs::copy(from.join(f), to.join(f)).unwrap();
    }
}

async fn node(dir: &Path, db: &strata_tests::postgres::PgDb, id: &str, spawn_x: i32) -> Running {
    node_leasing(dir, db, (id, spawn_x), 5_000, 500).await
}

/// The west and east nodes on `db`, sharing keys, with the default
/// leases; the temp dir holding their data dirs comes first (keep it).
async fn west_and_east(db: &strata_tests::postgres::PgDb) -> (tempfile::TempDir, Running, Running) {
    let dirs = tempfile::tempdir().unwrap();
    let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
    let west = node(&da, db, "west", WEST_X).await;
    share_keys(&da, &db_dir);
    let east = node(&db_dir, db, "east", EAST_X).await;
    (dirs, west, east)
}

/// [`node`] with its lease and renewal period.
async fn node_leasing(
    dir: &Path,
    db: &strata_tests::postgres::PgDb,
    (id, spawn_x): (&str, i32),
    lease_ms: u64,
    renew_ms: u64,
) -> Running {
    let cfg = node_config(dir, db, (id, spawn_x), lease_ms, renew_ms);
    app::start(cfg).await.expect("node starts")
}

/// A cluster node's configuration, spawning players at `spawn_x`.
fn node_config(
    dir: &Path,
    db: &strata_tests::postgres::PgDb,
    (id, spawn_x): (&str, i32),
    lease_ms: u64,
    renew_ms: u64,
) -> strata_server::config::ServerConfig {
    let mut cfg = test_config(dir);
    cfg.store.backend = strata_server::store::StoreBackend::Postgres;
    cfg.store.postgres.url = db.url();
    cfg.cluster = Some(ClusterConfig {
        node_id: id.into(),
        lease_ms,
        renew_ms,
        ..ClusterConfig::default()
    });
    cfg.validation.spawn = SpawnArea {
        x: spawn_x,
        z: Z,
        radius: 32,
        ..SpawnArea::default()
    };
    cfg.validation.max_speed = 64.0;
    cfg
}

/// Bob on the east node claims region 1 for it; Ann, a cluster client
/// at home on the west node, claims region 0 for that one and follows the
/// west node's word until she is connected to the east node too.
async fn bob_east_ann_west(
    west: &Running,
    east: &Running,
) -> (strata_client_sim::Client, ClusterClient) {
    let opts = ClientOptions {
        record_history: true,
        ..Default::default()
    };
    let bob_token = token(east, "bob", Role::Player);
    let bob = strata_client_sim::Client::connect_opts(
        east.addr,
        &east.cert_der,
        &bob_token,
        opts.clone(),
    )
    .await
    .unwrap();
    bob.send_position(feet(EAST_X)).unwrap();
    assert!(
        eventually(TEST_TIMEOUT, || bob
            .replica()
            .get(chunk_of(EAST_X))
            .is_some())
        .await
    );
    let (v, _) = bob.edit_acked(mine_at(EAST_X + 2)).await.unwrap();
    assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

    let ann_token = token(west, "ann", Role::Player);
    let mut ann = ClusterClient::connect(west.addr, &west.cert_der, &ann_token, opts)
        .await
        .unwrap();
    ann.send_position(feet(WEST_X)).unwrap();
    assert!(
        eventually(TEST_TIMEOUT, || ann
            .home()
            .replica()
            .get(chunk_of(WEST_X))
            .is_some())
        .await
    );
    let (to, (v, _)) = ann.edit(mine_at(WEST_X + 2)).await.unwrap();
    assert_eq!(to, west.addr);
    assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

    // The west node names the east node as region 1's writer; the client
    // connects there and arrives with the ticket.
    follow_until_joined(&mut ann, east.addr).await;
    (bob, ann)
}

/// Follows the nodes' word until the client joined `node` (and no other).
async fn follow_until_joined(ann: &mut ClusterClient, node: SocketAddr) {
    let mut joined = Vec::new();
    for _ in 0..500 {
        joined.extend(ann.follow().await.unwrap());
        if !joined.is_empty() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(joined, vec![node]);
}

/// A player on `node`, standing at `x` with its chunk in hand.
async fn standing(node: &Running, name: &str, x: i32) -> strata_client_sim::Client {
    let c = connect(node, name, Role::Player).await;
    c.send_position(feet(x)).unwrap();
    assert!(eventually(TEST_TIMEOUT, || c.replica().get(chunk_of(x)).is_some()).await);
    c
}

/// Bob on the east node, his first edit claiming region 1 for it.
async fn bob_claims_region_one(east: &Running) -> strata_client_sim::Client {
    let bob = standing(east, "bob", EAST_X).await;
    let (v, _) = bob.edit_acked(mine_at(EAST_X + 2)).await.unwrap();
    assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
    bob
}

fn mine_at(x: i32) -> Edit {
    let (_, v) = spot(x, Z);
    Edit::Mine {
        center: at(v.x as f64, v.y as f64, v.z as f64),
        radius: r(3.0),
        strength: 60,
    }
}

fn chunk_of(x: i32) -> ChunkPos {
    spot(x, Z).1.chunk()
}

fn feet(x: i32) -> FixedVec3 {
    spot(x, Z).0
}

/// Every replica's chunk histories rise one version at a time, and no
/// mesh differed from the server's.
fn assert_in_order(name: &str, c: &strata_client_sim::Client) {
    let r = c.replica();
    assert!(
        r.mesh_mismatches().is_empty(),
        "{name}: {:?}",
        r.mesh_mismatches()
    );
    for (pos, versions) in r.history().expect("recording") {
        for w in versions.windows(2) {
            assert!(
                w[1] == w[0] + 1 || (w[0] == 0 && w[1] > 0),
                "{name}: {pos:?} went {versions:?}"
            );
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_player_walks_into_another_nodes_region_and_keeps_playing() {
    let Some(db) = strata_tests::postgres::database("cluster_routing") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let (bob, mut ann) = bob_east_ann_west(&west, &east).await;
        let owners = ann.home().region_owners().expect("RegionOwners");
        let east_holds = owners.regions.iter().any(|r| {
            r.region_x == 1
                && matches!(&r.holder, RegionHolder::Node { node, addr }
                    if node == "east" && addr.parse::<SocketAddr>().ok() == Some(east.addr))
        });
        assert!(east_holds, "{owners:?}");
        let arrived = ann.node(east.addr).unwrap().arrived().expect("Arrived");
        assert_eq!(arrived, feet(WEST_X));

        // Ann walks east across the border, two voxels every 50 ms.
        let mut x = WEST_X;
        while x < EAST_X - 4 {
            x += 2;
            ann.send_position(feet(x)).unwrap();
            ann.follow().await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let there = chunk_of(EAST_X - 4);
        assert_eq!(ann.route(there), east.addr);
        assert!(
            eventually(TEST_TIMEOUT, || {
                ann.node(east.addr)
                    .is_some_and(|c| c.replica().get(there).is_some())
            })
            .await
        );
        // Her edit beyond the border goes to the east node.
        let (to, (v, changes)) = ann.edit(mine_at(EAST_X - 2)).await.unwrap();
        assert_eq!(to, east.addr);
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let changed = changes[0];
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .chunk(changed.pos)
                .is_some_and(|(_, version, _)| version >= changed.version))
            .await,
            "ann's routed replica reached {changed:?}"
        );
        // Bob, on the east node only, sees her edit too.
        assert!(
            eventually(TEST_TIMEOUT, || bob
                .replica()
                .get(changed.pos)
                .is_some_and(|h| h.version >= changed.version))
            .await
        );

        // Nobody was disconnected, and every stream stayed in order.
        for (addr, c) in ann.nodes() {
            assert!(!c.is_closed(), "ann's connection to {addr} closed");
            assert_in_order(&format!("ann@{addr}"), c);
        }
        assert!(!bob.is_closed());
        assert_in_order("bob", &bob);

        // The east node stops (releasing its leases): ann is moved back to
        // the west node, which takes region 1 over at her next edit there
        // and resends the chunks it held older versions of.
        bob.close().await;
        let east_addr = east.addr;
        east.shutdown().await.unwrap();
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .node(east_addr)
                .is_none_or(|c| c.is_closed()))
            .await
        );
        // The west node's word on region 1 changes once its cached holder
        // expires (`renew_ms`): the region is free.
        let mut moved = false;
        for _ in 0..500 {
            ann.follow().await.unwrap();
            let free = ann.home().region_owners().is_some_and(|o| {
                o.regions
                    .iter()
                    .any(|r| r.region_x == 1 && r.holder == RegionHolder::Free)
            });
            if free && ann.route(there) == west.addr {
                moved = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(moved, "region 1 free and routed to the west node");
        let (to, (v, again)) = ann.edit(mine_at(EAST_X - 2)).await.unwrap();
        assert_eq!(to, west.addr);
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let taken = again
            .iter()
            .find(|c| c.pos == changed.pos)
            .expect("same chunk");
        assert!(
            taken.version > changed.version,
            "{taken:?} after {changed:?}"
        );
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .chunk(taken.pos)
                .is_some_and(|(_, version, _)| version >= taken.version))
            .await
        );
        assert!(ann.home().replica().mesh_mismatches().is_empty());
        assert!(!ann.home().is_closed());
        ann.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// An edit reaching across the border into a region another node holds
/// is refused by the node it belongs to, which asks for that region (the
/// client library does not send it on to the holder, which would refuse it
/// too). The holder keeps the region while its player edits there, and
/// hands it over once he has left it alone for `handoff_idle_ms`: the edit
/// sent again is applied across the border, and the old holder names the
/// new one to its player.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_edit_across_a_border_is_applied_once_the_quiet_side_hands_its_region_over() {
    let Some(db) = strata_tests::postgres::database("cluster_handoff") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
        let start = |dir: &Path, id: &str, x: i32| {
            let mut cfg = node_config(dir, &db, (id, x), 5_000, 200);
            if let Some(c) = cfg.cluster.as_mut() {
                c.handoff_idle_ms = 1_000;
            }
            app::start(cfg)
        };
        let west = start(&da, "west", WEST_X).await.expect("node starts");
        share_keys(&da, &db_dir);
        let east = start(&db_dir, "east", EAST_X).await.expect("node starts");
        let (bob, mut ann) = bob_east_ann_west(&west, &east).await;
        let mut x = WEST_X;
        while x < 250 {
            x += 2;
            ann.send_position(feet(x)).unwrap();
            ann.follow().await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // Centred in region 0, reaching past x = 256 into region 1.
        let across = mine_at(254);
        let refused = |v: &Verdict| {
            matches!(v, Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 1, region_z: 0, owner, ..
            }) if owner == "east")
        };
        let epoch = || {
            sql(
                &db,
                "SELECT epoch FROM regions WHERE region_x = 1 AND region_z = 0",
            )
        };
        let before = epoch().await;
        for i in 0..6 {
            let (v, _) = bob.edit_acked(mine_at(EAST_X + 2 + i % 2)).await.unwrap();
            assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
            let (to, (v, _)) = ann.edit(across.clone()).await.unwrap();
            assert_eq!(to, west.addr, "sent on to the holder");
            assert!(refused(&v), "while bob edits there: {v:?}");
            tokio::time::sleep(Duration::from_millis(250)).await;
        }
        assert_eq!(epoch().await, before, "region 1 changed hands while in use");
        let mut applied = None;
        // Within her edit rate (5 a second).
        for _ in 0..60 {
            let (to, (v, changes)) = ann.edit(across.clone()).await.unwrap();
            assert_eq!(to, west.addr);
            if matches!(v, Verdict::Accepted { .. }) {
                applied = Some(changes);
                break;
            }
            assert!(refused(&v), "{v:?}");
            tokio::time::sleep(Duration::from_millis(300)).await;
        }
        let changes = applied.expect("the quiet region was handed over");
        let side = strata_server::sequencer::regions::DEFAULT_REGION_CHUNKS as i32;
        assert!(
            changes.iter().any(|c| c.pos.x >= side),
            "no change in region 1: {changes:?}"
        );
        let (v, _) = bob.edit_acked(mine_at(EAST_X + 2)).await.unwrap();
        assert!(
            matches!(&v, Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 1, owner, ..
            }) if owner == "west"),
            "{v:?}"
        );
        for (addr, c) in ann.nodes() {
            assert!(!c.is_closed(), "ann's connection to {addr} closed");
            assert_in_order(&format!("ann@{addr}"), c);
        }
        assert_in_order("bob", &bob);
        bob.close().await;
        ann.close().await;
        east.shutdown().await.unwrap();
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// A refusal naming a node the client is connected to, at another address
/// than the connection's (a load balancer's, the address it advertises),
/// sends the edit on over that connection: no second session is opened
/// there (it would end the first).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refusal_naming_a_connected_node_elsewhere_uses_its_connection() {
    let Some(db) = strata_tests::postgres::database("cluster_named_elsewhere") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let (bob, mut ann) = bob_east_ann_west(&west, &east).await;
        let refused = (
            Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 1,
                region_z: 0,
                owner: "east".into(),
                addr: "127.0.0.2:9".into(),
            }),
            Vec::new(),
        );
        let edit = mine_at(EAST_X - 2);
        // Known by its id once it has told its own (at a position).
        ann.send_position(feet(WEST_X)).unwrap();
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .node(east.addr)
                .and_then(|c| c.region_owners())
                .is_some_and(|o| o.node == "east"))
            .await
        );
        let next = ann.next_hop(west.addr, &edit, &refused, &[west.addr]).await;
        assert_eq!(next, strata_client_sim::cluster::NextHop::Again(east.addr));
        let addrs: Vec<SocketAddr> = ann.nodes().map(|(a, _)| a).collect();
        assert_eq!(addrs.len(), 2, "{addrs:?}");
        bob.close().await;
        ann.close().await;
        east.shutdown().await.unwrap();
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// An edit whose own region is free and which reaches into a region
/// another node holds is no node's yet: the node it was sent to asks for
/// nothing, and the client library sends it on to the holder, which
/// claims the free region and applies it at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_edit_from_a_free_region_across_a_border_goes_to_the_holder() {
    let Some(db) = strata_tests::postgres::database("cluster_free_border") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let bob = bob_claims_region_one(&east).await;
        let opts = ClientOptions::default();
        let ann_token = token(&west, "ann", Role::Player);
        let mut ann = ClusterClient::connect(west.addr, &west.cert_der, &ann_token, opts)
            .await
            .unwrap();
        let mut x = WEST_X;
        ann.send_position(feet(x)).unwrap();
        while x < 250 {
            x += 2;
            ann.send_position(feet(x)).unwrap();
            ann.follow().await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // Joined to the east node (named as region 1's holder), with the
        // border chunk in hand there.
        for _ in 0..500 {
            ann.follow().await.unwrap();
            if ann.node(east.addr).is_some() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .node(east.addr)
                .is_some_and(|c| c.replica().get(chunk_of(254)).is_some()))
            .await
        );
        let (to, (v, _)) = ann.edit(mine_at(254)).await.unwrap();
        assert_eq!(to, east.addr, "{v:?}");
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let asked = sql(
            &db,
            "SELECT count(*) FROM regions WHERE wanted_by IS NOT NULL",
        )
        .await;
        assert_eq!(asked, ["0"], "a region was asked for");
        let owners = sql(&db, "SELECT owner FROM regions ORDER BY region_x").await;
        assert_eq!(owners, ["east", "east"]);
        assert!(bob.replica().mesh_mismatches().is_empty());
        bob.close().await;
        ann.close().await;
        east.shutdown().await.unwrap();
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bots_refused_for_another_nodes_region_move_there_and_keep_editing() {
    use strata_client_sim::bots::{self, BotsConfig, Profile, Tokens, VerifyMode};
    let Some(db) = strata_tests::postgres::database("cluster_routing_bots") else {
        return;
    };
    let dirs = tempfile::tempdir().unwrap();
    let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
    // Both nodes spawn players around x = 130, in region 0.
    let west = node(&da, &db, "west", 130).await;
    share_keys(&da, &db_dir);
    let east = node(&db_dir, &db, "east", 130).await;
    // An edit on the west node claims region 0 for it.
    let ann = connect(&west, "ann", Role::Player).await;
    ann.send_position(feet(128)).unwrap();
    assert!(eventually(TEST_TIMEOUT, || ann.replica().get(chunk_of(128)).is_some()).await);
    let (v, _) = ann.edit_acked(mine_at(126)).await.unwrap();
    assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

    // Bots sent to the east node, living in region 0.
    let run = BotsConfig {
        server: east.addr,
        cert_der: east.cert_der.clone(),
        tokens: Tokens::Minted(east.data_dir.secret().clone()),
        bots: 2,
        duration: Duration::from_secs(3),
        profile: Profile::Mixed,
        edit_rate: 2.0,
        view_radius: 2,
        verify: VerifyMode::Modified,
        seed: 7,
        stalled: 0,
        ramp: true,
        ack_log: None,
        progress: false,
        area_origin: (110, Z - 20),
        region_chunks: 8,
        silence_limit: bots::DEFAULT_SILENCE_LIMIT,
        predict: false,
        capabilities: 0,
        follow_owners: true,
        player_prefix: "bot".into(),
        link_delay: Duration::ZERO,
        verify_timeout: bots::DEFAULT_VERIFY_TIMEOUT,
        stalled_window: None,
    };
    let s = tokio::time::timeout(Duration::from_secs(90), bots::run(run))
        .await
        .expect("the run ends")
        .unwrap();
    assert!(s.consistent(), "{}", s.human());
    assert!(s.handoffs >= 1, "{}", s.human());
    assert!(s.edits_accepted > 0, "{}", s.human());
    ann.close().await;
    west.shutdown().await.unwrap();
    east.shutdown().await.unwrap();
}

/// Region (0, 1): z in 256..512, an edit's footprint well inside it.
const NORTH_Z: i32 = 300;

fn mine_at_xz(x: i32, z: i32) -> Edit {
    let (_, v) = spot(x, z);
    Edit::Mine {
        center: at(v.x as f64, v.y as f64, v.z as f64),
        radius: r(3.0),
        strength: 60,
    }
}

/// A node at `[cluster] max_held_regions` refuses an edit in a region no
/// node holds with `NodeFull`, costing the player no edit token. The cluster
/// client sends it on to the other node it is connected to, which claims
/// the region, and routes the region's edits there from then on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_node_passes_an_edit_in_a_free_region_to_a_node_with_room() {
    use strata_protocol::RejectReason;
    let Some(db) = strata_tests::postgres::database("cluster_node_full") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
        // One region at most, on a lease no idle release reaches here.
        let mut cfg = node_config(&da, &db, ("west", WEST_X), 60_000, 500);
        if let Some(c) = cfg.cluster.as_mut() {
            c.max_held_regions = 1;
        }
        let west = app::start(cfg).await.expect("node starts");
        share_keys(&da, &db_dir);
        let east = node(&db_dir, &db, "east", EAST_X).await;
        // Bob's edit claims region 1 for the east node, Ann's region 0 for
        // the west node: now it is full.
        let (bob, mut ann) = bob_east_ann_west(&west, &east).await;

        // Ann walks north into region (0, 1), which no node holds.
        let mut z = Z;
        while z < NORTH_Z - 2 {
            z += 2;
            ann.send_position(spot(WEST_X, z).0).unwrap();
            ann.follow().await.unwrap();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let north = spot(WEST_X, NORTH_Z).1.chunk();
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .nodes()
                .all(|(_, c)| c.replica().get(north).is_some()))
            .await
        );
        assert_eq!(ann.route(north), west.addr, "nobody holds it: home");
        // Asked alone, the west node says why, and charges nothing for it:
        // more refusals than the edit-rate bucket holds leave it full.
        let edit = mine_at_xz(WEST_X, NORTH_Z);
        for _ in 0..12 {
            let (v, _) = ann.home().edit_acked(edit.clone()).await.unwrap();
            assert_eq!(
                v,
                Verdict::Rejected(RejectReason::NodeFull { max_regions: 1 })
            );
        }
        // The cluster client passes it to the east node, which takes the
        // region.
        let (to, (v, changes)) = ann.edit(edit.clone()).await.unwrap();
        assert_eq!(to, east.addr);
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        assert_eq!(ann.route(north), east.addr);
        let changed = changes[0];
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .chunk(changed.pos)
                .is_some_and(|(_, version, _)| version >= changed.version))
            .await
        );
        // The next edit there goes straight to its new writer.
        let (to, (v, _)) = ann.edit(edit).await.unwrap();
        assert_eq!(to, east.addr);
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        for (addr, c) in ann.nodes() {
            assert!(!c.is_closed(), "ann's connection to {addr} closed");
            assert_in_order(&format!("ann@{addr}"), c);
        }
        ann.close().await;
        bob.close().await;
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// Runs one statement on the test's database.
/// Runs `statement`; returns the first column of the rows it gave.
async fn sql(db: &strata_tests::postgres::PgDb, statement: &str) -> Vec<String> {
    let (client, conn) = tokio_postgres::connect(&db.url(), tokio_postgres::NoTls)
        .await
        .unwrap();
    let driver = tokio::spawn(conn);
    let rows = client.simple_query(statement).await.unwrap();
    drop(client);
    let _ = driver.await;
    rows.into_iter()
        .filter_map(|m| match m {
            tokio_postgres::SimpleQueryMessage::Row(r) => r.get(0).map(str::to_string),
            _ => None,
        })
        .collect()
}

/// West on `db` with renewals far apart (it learns of a takeover only
/// from its next commit's fence), and ann standing there, her first edit
/// accepted: its verdict and changes.
async fn west_with_ann(
    dir: &Path,
    db: &strata_tests::postgres::PgDb,
) -> (
    Running,
    strata_client_sim::Client,
    strata_client_sim::client::Acked,
) {
    let west = node_leasing(dir, db, ("west", WEST_X), 60_000, 10_000).await;
    let ann = standing(&west, "ann", WEST_X).await;
    let acked = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
    (west, ann, acked)
}

/// Another node ("thief", at 127.0.0.1:9) takes region (0, 0) while its
/// holder is unaware: the lease is run out and the thief claims it.
async fn thief_takes_region_zero(
    db: &strata_tests::postgres::PgDb,
) -> strata_server::store::PgStore {
    thief_takes_region(db, 0).await
}

/// [`thief_takes_region_zero`] for region (`x`, 0).
async fn thief_takes_region(
    db: &strata_tests::postgres::PgDb,
    x: i32,
) -> strata_server::store::PgStore {
    use strata_server::sequencer::regions::RegionId;
    use strata_server::store::{ChunkStore, PgStore};
    sql(
        db,
        &format!(
            "UPDATE regions SET lease_expires = now() - interval '1 second' \
             WHERE region_x = {x} AND region_z = 0"
        ),
    )
    .await;
    let url = db.url();
    tokio::task::spawn_blocking(move || {
        let pg = strata_server::store::pg::PgConfig {
            url,
            ..Default::default()
        };
        let other = ClusterConfig {
            node_id: "thief".into(),
            lease_ms: 60_000,
            renew_ms: 10_000,
            advertise: "127.0.0.1:9".into(),
            adopt: false,
            ..ClusterConfig::default()
        };
        let s = PgStore::open_node(&pg, 8, &other).unwrap();
        // A node of the same world: the same generator.
        let (g, _) = strata_server::app::world_generator(&test_config(Path::new("."))).unwrap();
        s.attach_generator(Arc::new(g));
        assert_eq!(s.claim_regions(&[RegionId { x, z: 0 }]).unwrap().len(), 1);
        s
    })
    .await
    .unwrap()
}

/// An edit by a region's border writes one region and reaches (its
/// meshes' apron, claimed for it) the next. Once another node took that next
/// region, unknown to this one, the edit's batch is fenced all the same:
/// it was built on that region's chunks as this node last had them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_batch_reading_a_region_taken_over_is_fenced_too() {
    use strata_server::sequencer::regions::RegionId;
    let Some(db) = strata_tests::postgres::database("cluster_fenced_read") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (west, ann, (v, _)) = west_with_ann(&dirs.path().join("a"), &db).await;
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        // Region 0 ends at x = 256; what a mine of radius 3 at 252 changes
        // (250..=254: 255 lies at the radius) stops short of it, and the
        // meshes' apron reaches two voxels past.
        let bea = standing(&west, "bea", 230).await;
        walk(&bea, (232..=248).step_by(2)).await;
        let (v, changes) = bea.edit_acked(mine_at(252)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        assert!(!changes.is_empty());
        assert!(
            changes
                .iter()
                .all(|c| RegionId::of(c.pos, 8) == RegionId { x: 0, z: 0 }),
            "it writes region 0 alone: {changes:?}"
        );
        let _thief = thief_takes_region(&db, 1).await;
        let (v, _) = bea.edit_acked(mine_at(252)).await.unwrap();
        assert_eq!(
            v,
            Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 1,
                region_z: 0,
                owner: "thief".into(),
                addr: "127.0.0.1:9".into(),
            })
        );
        assert!(!bea.is_closed());
        ann.close().await;
        bea.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_batch_fenced_after_a_takeover_is_refused_and_the_node_goes_on() {
    use strata_server::store::ChunkStore;
    let Some(db) = strata_tests::postgres::database("cluster_fenced_batch") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (west, ann, (v, first)) = west_with_ann(&dirs.path().join("a"), &db).await;
        let Verdict::Accepted { seq } = v else {
            panic!("{v:?}")
        };
        let thief = thief_takes_region_zero(&db).await;

        // West's next edit there is fenced: refused, naming the thief.
        let (v, _) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert_eq!(
            v,
            Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 0,
                region_z: 0,
                owner: "thief".into(),
                addr: "127.0.0.1:9".into(),
            })
        );
        // West goes on, refusing the lost region from then on, and its
        // player's copy never saw the abandoned edit.
        assert!(!ann.is_closed());
        let (v, _) = ann.edit_acked(mine_at(WEST_X - 2)).await.unwrap();
        assert!(
            matches!(
                v,
                Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere { .. })
            ),
            "{v:?}"
        );
        let pos = first[0].pos;
        assert_eq!(ann.replica().get(pos).unwrap().version, first[0].version);
        // Its operators are told the last durable seq, not the floor of
        // the seq block it reserved after the fenced batch.
        assert_eq!(admin_stats(&west).await.last_seq, seq);
        let stored = tokio::task::spawn_blocking(move || {
            let last = thief.edit_log(1..=u64::MAX).map(|e| e.unwrap().seq).max();
            (last, thief.load_chunk(pos).unwrap().map(|c| c.version))
        })
        .await
        .unwrap();
        assert_eq!(stored, (Some(seq), Some(first[0].version)));
        ann.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// A fenced batch whose node cannot reserve a new seq block (the world
/// row's block table refuses new rows) does not stop the node: it hands
/// out no seq past the abandoned ones, and edits wait until its lease
/// thread reserves the next block, numbered from that block's first seq.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fenced_batch_whose_next_seq_block_fails_leaves_edits_waiting_for_one() {
    let Some(db) = strata_tests::postgres::database("cluster_fenced_no_block") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (west, ann, (v, _)) = west_with_ann(&dirs.path().join("a"), &db).await;
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        // Bea stands in region 1 (free) before region 0 is taken.
        let bea = standing(&west, "bea", 230).await;
        walk(&bea, (232..=270).step_by(2)).await;
        let _thief = thief_takes_region_zero(&db).await;
        sql(
            &db,
            "ALTER TABLE seq_blocks ADD CONSTRAINT no_new_block CHECK (first_seq < 0) NOT VALID",
        )
        .await;
        let blocks = seq_blocks(&db).await;

        let (v, _) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(
            matches!(
                v,
                Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere { .. })
            ),
            "{v:?}"
        );
        // The node goes on; bea's edit in region 1 waits for a seq.
        let id = bea.submit(mine_at(272)).await.unwrap();
        let bea = Arc::new(bea);
        let mut waiting = tokio::spawn({
            let bea = bea.clone();
            async move { bea.verdict(id).await.unwrap().0 }
        });
        if let Ok(v) = tokio::time::timeout(Duration::from_millis(1500), &mut waiting).await {
            panic!("answered without a seq block: {v:?}");
        }
        assert!(!ann.is_closed() && !bea.is_closed(), "the node stopped");
        assert_eq!(seq_blocks(&db).await, blocks);

        sql(&db, "ALTER TABLE seq_blocks DROP CONSTRAINT no_new_block").await;
        let v = waiting.await.unwrap();
        let Verdict::Accepted { seq } = v else {
            panic!("bea's edit refused: {v:?}")
        };
        let now = seq_blocks(&db).await;
        assert_eq!(now.len(), blocks.len() + 1, "{now:?}");
        assert_eq!(seq, now.last().unwrap().0, "numbered from the new block");

        checks_clean(&db).await;
        ann.close().await;
        let bea = Arc::into_inner(bea).expect("the verdict task is done");
        finish(bea, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// The thief of a region changes a chunk this node's player holds, and
/// the node's next batch there is fenced: putting the chunk back as
/// stored moves it past the player's copy, so the player is told to drop
/// that copy and gets the thief's version, as after a takeover.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fenced_batch_over_a_chunk_the_thief_changed_resyncs_the_players_copy() {
    use strata_server::store::{ChunkStore, CommitBatch, LogEntry};
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::hash::chunk_hash;
    use strata_terrain::Voxel;
    let Some(db) = strata_tests::postgres::database("cluster_fenced_resync") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (west, ann, (v, first)) = west_with_ann(&dirs.path().join("a"), &db).await;
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let (pos, held) = (first[0].pos, first[0].version);
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .replica()
                .get(pos)
                .is_some_and(|h| h.version == held))
            .await
        );

        // The thief writes the next version of ann's chunk.
        let thief = thief_takes_region_zero(&db).await;
        let (thief, theirs) = tokio::task::spawn_blocking(move || {
            let stored = thief.load_chunk(pos).unwrap().unwrap();
            assert_eq!(stored.version, held);
            let mut next = stored.chunk.clone();
            for y in 0..4 {
                for x in 0..4 {
                    next.set(x, y, 0, Voxel::new(255, 3));
                }
            }
            let floor = thief.reserve_seqs(0).unwrap();
            let batch = CommitBatch {
                entries: vec![LogEntry {
                    seq: floor + 1,
                    player: "thief".into(),
                    time_ms: 1,
                    edit: mine_at(WEST_X + 2),
                    changes: vec![(pos, held + 1)],
                }],
                deltas: vec![
                    ChunkDelta::encode(pos, held, held + 1, &stored.chunk, &next).unwrap(),
                ],
                last_seq: floor + 1,
                ..CommitBatch::default()
            };
            thief.commit_batch(&batch).unwrap();
            (thief, next)
        })
        .await
        .unwrap();

        // West's next edit there is fenced; ann's copy is withdrawn and
        // replaced by the thief's version.
        let (v, _) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(
            matches!(
                v,
                Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere { .. })
            ),
            "{v:?}"
        );
        assert!(
            eventually(Duration::from_secs(20), || ann
                .replica()
                .get(pos)
                .is_some_and(|h| h.version == held + 1))
            .await,
            "ann still holds {:?}",
            ann.replica().get(pos).map(|h| h.version)
        );
        assert_eq!(ann.replica().get(pos).unwrap().hash, chunk_hash(&theirs));
        assert!(ann.replica().mesh_mismatches().is_empty());
        assert!(!ann.is_closed());
        drop(thief);
        ann.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// West on `db` (renewals far apart), no region claimed, and bea standing
/// at x 230.
async fn west_with_bea(
    dir: &Path,
    db: &strata_tests::postgres::PgDb,
) -> (Running, strata_client_sim::Client) {
    let west = node_leasing(dir, db, ("west", WEST_X), 60_000, 10_000).await;
    let bea = standing(&west, "bea", 230).await;
    (west, bea)
}

/// Reports each of `xs` in turn, 50 ms apart.
async fn walk(c: &strata_client_sim::Client, xs: impl IntoIterator<Item = i32>) {
    for x in xs {
        c.send_position(feet(x)).unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// A node taking a region brings the chunks it holds of the regions
/// around it that it does not write up to their stored versions: the
/// meshes of the region's border chunks read their border voxels, which
/// another node may have changed meanwhile. Here the thief, holding region
/// 0, changes chunk 7's last voxels (x = 255) while west streams its old
/// copy to bea; bea's edit in region 1 makes west claim that region, and
/// bea's copy of chunk 7 becomes the thief's.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_taking_a_region_reloads_the_neighbours_border_chunks_it_holds() {
    use strata_server::store::{ChunkStore, CommitBatch, LogEntry};
    use strata_terrain::{delta::ChunkDelta, hash::chunk_hash, ChunkGenerator, Voxel};
    let Some(db) = strata_tests::postgres::database("cluster_border_reload") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Bea walks into region 1, where her edits will be.
        let (west, bea) = west_with_bea(dir.path(), &db).await;
        walk(&bea, (232..=258).step_by(2)).await;
        let pos = chunk_of(255);
        assert_eq!(pos.x, 7, "the last chunk of region 0");
        assert!(eventually(TEST_TIMEOUT, || bea.replica().get(pos).is_some()).await);

        let thief = thief_takes_region_zero(&db).await;
        let (thief, theirs) = tokio::task::spawn_blocking(move || {
            let (g, _) = strata_server::app::world_generator(&test_config(Path::new("."))).unwrap();
            let generated = g.generate(pos);
            let mut next = generated.clone();
            for y in 0..32 {
                for z in 0..32 {
                    next.set(31, y, z, Voxel::new(255, 3));
                }
            }
            let floor = thief.reserve_seqs(0).unwrap();
            let batch = CommitBatch {
                entries: vec![LogEntry {
                    seq: floor + 1,
                    player: "thief".into(),
                    time_ms: 1,
                    edit: mine_at(250),
                    changes: vec![(pos, 1)],
                }],
                chunks: vec![(pos, 1, Arc::new(next.clone()))],
                generated: vec![ChunkDelta::encode(pos, 0, 1, &generated, &next).unwrap()],
                last_seq: floor + 1,
                ..CommitBatch::default()
            };
            thief.commit_batch(&batch).unwrap();
            (thief, next)
        })
        .await
        .unwrap();
        assert_eq!(
            bea.replica().get(pos).unwrap().version,
            0,
            "west knows nothing"
        );

        // Far enough from the border that region 1 alone is claimed.
        let (v, _) = bea.edit_acked(mine_at(262)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        assert!(
            eventually(Duration::from_secs(20), || bea
                .replica()
                .get(pos)
                .is_some_and(|h| h.version == 1))
            .await,
            "bea still holds {:?}",
            bea.replica().get(pos).map(|h| h.version)
        );
        assert_eq!(bea.replica().get(pos).unwrap().hash, chunk_hash(&theirs));
        assert!(bea.replica().mesh_mismatches().is_empty());
        drop(thief);
        bea.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// An edit's sight is checked on this node's copy of the chunks its ray
/// crosses, current only in regions it writes: a player standing in a
/// region another node holds is refused an edit just across the border
/// (naming that node), and makes it from her side.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_edit_whose_sight_crosses_another_nodes_region_is_refused() {
    let Some(db) = strata_tests::postgres::database("cluster_sight_regions") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let (west, bea) = west_with_bea(dir.path(), &db).await;
        // To region 1 (x from 256), which the thief holds.
        walk(&bea, (232..=256).step_by(2)).await;
        let _thief = thief_takes_region(&db, 1).await;
        // Mining at 248 changes region 0 alone (its meshes too).
        let (v, _) = bea.edit_acked(mine_at(248)).await.unwrap();
        assert_eq!(
            v,
            Verdict::Rejected(strata_protocol::RejectReason::RegionElsewhere {
                region_x: 1,
                region_z: 0,
                owner: "thief".into(),
                addr: "127.0.0.1:9".into(),
            })
        );
        walk(&bea, (242..=254).rev().step_by(2)).await;
        let (v, _) = bea.edit_acked(mine_at(248)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        bea.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// `[cluster] release_idle_ms`: a node lets go of a region no edit asked
/// for in that long (counted in `strata_cluster_regions_released_total`),
/// and its player's next edit there claims it again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_lets_an_idle_region_go_and_claims_it_again_at_the_next_edit() {
    let Some(db) = strata_tests::postgres::database("cluster_release_idle") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 400, 100);
        if let Some(c) = cfg.cluster.as_mut() {
            c.release_idle_ms = 400;
        }
        let west = app::start(cfg).await.expect("node starts");
        // The process's registry (this test binary's nodes share it; only
        // this test releases regions for idleness).
        let registry = strata_server::metrics::shared().unwrap();
        let scrape_now = || registry.render();
        let released = |text: &str| {
            text.lines()
                .find_map(|l| {
                    l.strip_prefix("strata_cluster_regions_released_total{why=\"idle\"} ")
                })
                .and_then(|v| v.trim().parse::<f64>().ok())
                .unwrap_or(0.0)
        };
        let ann = standing(&west, "ann", WEST_X).await;
        // Counted before the edit claims the region.
        let before = released(&scrape_now());
        let (v, first) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

        // Nobody edits: the region is let go within a few renewals, and the
        // node tells its player so.
        let holder = |c: &strata_client_sim::Client| {
            c.region_owners().and_then(|o| {
                o.regions
                    .into_iter()
                    .find(|r| (r.region_x, r.region_z) == (0, 0))
                    .map(|r| r.holder)
            })
        };
        assert!(
            eventually(TEST_TIMEOUT, || holder(&ann) == Some(RegionHolder::Here)).await,
            "{:?}",
            ann.region_owners()
        );
        assert!(
            eventually(TEST_TIMEOUT, || holder(&ann) == Some(RegionHolder::Free)).await,
            "the idle region was kept: {:?}",
            ann.region_owners()
        );
        let text = scrape_now();
        assert!(released(&text) > before, "counted: {text}");
        // The next edit claims it again, and numbers the chunk on.
        let (v, again) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let (a, b) = (
            first[0],
            again.iter().find(|c| c.pos == first[0].pos).unwrap(),
        );
        assert!(b.version > a.version, "{a:?} then {b:?}");
        assert!(!ann.is_closed());
        assert!(ann.replica().mesh_mismatches().is_empty());
        ann.close().await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// An edit any rule refuses, line of sight included, leaves no lease
/// behind: a node claims the free regions of an edit only once the edit
/// passed every rule, its sight checked on the store's copy.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_edit_refused_for_line_of_sight_claims_no_region() {
    let Some(db) = strata_tests::postgres::database("cluster_sight_claims") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 5_000, 500);
        cfg.validation.reach = 30.0;
        let west = app::start(cfg).await.expect("node starts");
        let ann = standing(&west, "ann", WEST_X).await;
        let held = || sql(&db, "SELECT owner FROM regions WHERE owner IS NOT NULL");
        assert!(held().await.is_empty(), "standing claims nothing");

        // Twelve voxels of rock under her feet: within reach, out of sight.
        let (_, v) = spot(WEST_X, Z);
        let deep = Edit::Mine {
            center: at(v.x as f64, v.y as f64 - 12.0, v.z as f64),
            radius: r(1.0),
            strength: 60,
        };
        for _ in 0..3 {
            let (verdict, _) = ann.edit_acked(deep.clone()).await.unwrap();
            assert_eq!(
                verdict,
                Verdict::Rejected(strata_protocol::RejectReason::NoLineOfSight)
            );
        }
        assert!(held().await.is_empty(), "a refused edit claimed a region");

        // One she sees claims the region and is applied, and so are the
        // next ones there.
        for i in 0..3 {
            let (verdict, _) = ann.edit_acked(mine_at(WEST_X + 2 + i)).await.unwrap();
            assert!(matches!(verdict, Verdict::Accepted { .. }), "{verdict:?}");
        }
        assert_eq!(held().await, ["west"]);
        finish(ann, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// Closes `c` (its meshes all matched the server's) and stops `node`.
async fn finish(c: strata_client_sim::Client, node: Running) {
    assert!(c.replica().mesh_mismatches().is_empty());
    c.close().await;
    node.shutdown().await.unwrap();
}

/// A free region whose chunks the store cannot read in time refuses its
/// edits `Busy` and is not claimed, with no fenced batch (which would cost
/// a seq block), until the store answers again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_free_region_the_store_cannot_read_refuses_its_edits_until_it_can() {
    let Some(db) = strata_tests::postgres::database("cluster_reload_retry") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 5_000, 500);
        cfg.store.postgres.statement_timeout_ms = 300;
        let west = app::start(cfg).await.expect("node starts");
        let ann = standing(&west, "ann", WEST_X).await;

        // Another session holds the deltas table: reading a region's
        // versions waits past the statement timeout.
        let lock = "LOCK TABLE chunk_deltas IN ACCESS EXCLUSIVE MODE";
        let (release, holder) = crate::store_common::hold_until_told(&db, lock);
        let (verdict, _) = ann.edit_acked(mine_at(WEST_X)).await.unwrap();
        assert_eq!(
            verdict,
            Verdict::Rejected(strata_protocol::RejectReason::Busy)
        );
        let (verdict, _) = ann.edit_acked(mine_at(WEST_X)).await.unwrap();
        assert_eq!(
            verdict,
            Verdict::Rejected(strata_protocol::RejectReason::Busy)
        );
        assert!(
            sql(&db, "SELECT owner FROM regions WHERE owner IS NOT NULL")
                .await
                .is_empty(),
            "claimed while unreadable"
        );
        // Readable again: the next edit claims it and is taken.
        readable_again(release, holder, &ann).await;
        assert_eq!(
            sql(&db, "SELECT count(*) FROM seq_blocks").await,
            ["1"],
            "no batch was fenced"
        );
        finish(ann, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// Two live processes under one node id would take regions from each
/// other without end: the later one's start supersedes the earlier, whose
/// engine stops at its next renewal, while the later one serves on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_process_under_the_same_node_id_stops_the_first() {
    let Some(db) = strata_tests::postgres::database("cluster_same_id") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dirs = tempfile::tempdir().unwrap();
        let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
        let first = node_leasing(&da, &db, ("west", WEST_X), 5_000, 100).await;
        let ann = standing(&first, "ann", WEST_X).await;
        let (v, _) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

        share_keys(&da, &db_dir);
        let second = node_leasing(&db_dir, &db, ("west", WEST_X), 5_000, 100).await;
        first.engine_stopped().await;
        assert!(
            eventually(TEST_TIMEOUT, || ann.is_closed()).await,
            "the first process's players are let go"
        );

        let bob = standing(&second, "bob", WEST_X).await;
        let (v, _) = bob.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        finish(bob, second).await;
        let _ = first.shutdown().await;
    })
    .await
    .expect("within the test timeout");
}

/// In region 1 (chunk 8), where both nodes below spawn their players.
const BORDER_X: i32 = 260;

/// The region (x, 0) as `c`'s node last described it.
fn holder_of(c: &strata_client_sim::Client, region_x: i32) -> Option<RegionHolder> {
    c.region_owners()?
        .regions
        .into_iter()
        .find(|r| (r.region_x, r.region_z) == (region_x, 0))
        .map(|r| r.holder)
}

/// The west and east nodes, both spawning at the border, the east one
/// letting regions go idle for `release_idle_ms`; the temp dir holding
/// their data dirs comes first (keep it).
async fn west_and_idle_east(
    db: &strata_tests::postgres::PgDb,
    release_idle_ms: u64,
) -> (tempfile::TempDir, Running, Running) {
    let dirs = tempfile::tempdir().unwrap();
    let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
    let west = node(&da, db, "west", BORDER_X).await;
    share_keys(&da, &db_dir);
    let mut cfg = node_config(&db_dir, db, ("east", BORDER_X), 1_000, 100);
    if let Some(c) = cfg.cluster.as_mut() {
        c.release_idle_ms = release_idle_ms;
    }
    let east = app::start(cfg).await.expect("node starts");
    (dirs, west, east)
}

/// A region its writer lets go idle (`Free`) is still read from that
/// writer's replica, not from the home node's older copy. Once another
/// node takes it, the last writer, named by no node and routed to by no
/// region, is let go.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_region_let_go_is_read_from_its_last_writer_until_another_takes_it() {
    let Some(db) = strata_tests::postgres::database("cluster_free_reads") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_idle_east(&db, 3_000).await;

        // Bob's edits claim region 1 for the east node and keep it there
        // until Ann, at home on the west node, has joined the east node.
        let bob = standing(&east, "bob", BORDER_X + 8).await;
        let (v, _) = bob.edit_acked(mine_at(BORDER_X + 10)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let ann_token = token(&west, "ann", Role::Player);
        let opts = ClientOptions::default();
        let mut ann = ClusterClient::connect(west.addr, &west.cert_der, &ann_token, opts)
            .await
            .unwrap();
        ann.send_position(feet(BORDER_X)).unwrap();
        let pos = chunk_of(BORDER_X + 2);
        assert!(eventually(TEST_TIMEOUT, || ann.home().replica().get(pos).is_some()).await);
        let mut joined = Vec::new();
        for i in 0..500 {
            if i % 10 == 9 {
                bob.edit_acked(mine_at(BORDER_X + 10)).await.unwrap();
            }
            joined.extend(ann.follow().await.unwrap());
            if !joined.is_empty() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert_eq!(joined, vec![east.addr]);
        // Her next position starts the east node's stream.
        ann.send_position(feet(BORDER_X)).unwrap();
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .node(east.addr)
                .is_some_and(|c| c.replica().get(pos).is_some()))
            .await
        );

        // Ann's edit goes to the east node.
        let (to, (v, changes)) = ann.edit(mine_at(BORDER_X + 2)).await.unwrap();
        assert_eq!(to, east.addr);
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let edited = *changes.iter().find(|c| c.pos == pos).expect("changed");
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .chunk(pos)
                .is_some_and(|(_, version, _)| version >= edited.version))
            .await
        );

        // Nobody edits: the east node lets region 1 go, and both nodes
        // report it free. The west node's copy is older than Ann's edit.
        let mut free = false;
        for _ in 0..500 {
            ann.follow().await.unwrap();
            free = holder_of(ann.home(), 1) == Some(RegionHolder::Free)
                && ann
                    .node(east.addr)
                    .is_none_or(|c| holder_of(c, 1) == Some(RegionHolder::Free));
            if free {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(free, "region 1 let go: {:?}", ann.home().region_owners());
        ann.follow().await.unwrap();
        let read = ann.chunk(pos).map(|(_, version, _)| version);
        assert!(
            read >= Some(edited.version),
            "read {read:?} after {edited:?}"
        );
        assert_eq!(ann.route(pos), east.addr);

        // Carl, on the west node only, takes region 1 there: Ann reads it
        // from the west node and lets the east node go.
        let carl = standing(&west, "carl", BORDER_X + 4).await;
        let (v, taken) = carl.edit_acked(mine_at(BORDER_X + 6)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let taken = *taken.iter().find(|c| c.pos == pos).expect("changed");
        assert!(taken.version > edited.version, "{taken:?} after {edited:?}");
        let mut let_go = false;
        for _ in 0..500 {
            ann.follow().await.unwrap();
            if ann.node(east.addr).is_none() {
                let_go = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(let_go, "still connected to {}", east.addr);
        assert_eq!(ann.route(pos), west.addr);
        assert!(
            eventually(TEST_TIMEOUT, || ann
                .chunk(pos)
                .is_some_and(|(_, version, _)| version >= taken.version))
            .await
        );
        assert!(!ann.home().is_closed());
        ann.close().await;
        bob.close().await;
        carl.close().await;
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// A region another node wrote and let go is read from this node as
/// stored, not from the copy this node had before: a player at home here
/// with no route to the last writer (a plain client) streams it from
/// here, and it must not see the pristine or older chunk.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_region_another_node_wrote_and_let_go_is_served_as_stored() {
    let Some(db) = strata_tests::postgres::database("cluster_free_current") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_idle_east(&db, 1_000).await;
        // The west node reads region 1's chunk first (as generated).
        let pos = chunk_of(BORDER_X + 10);
        let early = standing(&west, "early", BORDER_X + 10).await;
        early.close().await;
        // Bob, on the east node, changes it and leaves; the region is let go.
        let bob = standing(&east, "bob", BORDER_X + 8).await;
        let (v, changes) = bob.edit_acked(mine_at(BORDER_X + 10)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        let edited = *changes.iter().find(|c| c.pos == pos).expect("changed");
        bob.close().await;
        let free = async {
            loop {
                let rows = sql(
                    &db,
                    "SELECT count(*) FROM regions WHERE region_x = 1 AND owner IS NULL",
                )
                .await;
                if rows == ["1"] {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        };
        tokio::time::timeout(Duration::from_secs(20), free)
            .await
            .expect("region 1 let go");
        // Dave, at home on the west node, reads it from there.
        let dave = connect(&west, "dave", Role::Player).await;
        dave.send_position(feet(BORDER_X + 10)).unwrap();
        assert!(
            eventually(TEST_TIMEOUT, || dave
                .replica()
                .get(pos)
                .is_some_and(|c| c.version >= edited.version))
            .await,
            "served {:?}, stored {edited:?}",
            dave.replica().get(pos).map(|c| c.version)
        );
        assert!(dave.replica().mesh_mismatches().is_empty());
        dave.close().await;
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// The admin protocol's answer to `req` on `node`, as root.
async fn admin_on(node: &Running, req: AdminRequest) -> AdminResponse {
    let token = token(node, "root", Role::Admin);
    let mut c = AdminClient::connect(node.addr, &node.cert_der, &token)
        .await
        .unwrap();
    let answer = c.request(&req).await.unwrap();
    c.close().await;
    answer
}

fn ban(player: &str) -> AdminRequest {
    AdminRequest::Ban {
        player: player.into(),
        until: None,
    }
}

/// Bans made on either node hold on both: a change starts from the stored
/// list, so neither erases the other's, and each node reads the list again
/// within ACCESS_RELOAD_PERIOD, refusing and ending the other's banned.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bans_made_on_either_node_hold_on_both() {
    let Some(db) = strata_tests::postgres::database("cluster_access") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let eve = connect(&east, "eve", Role::Player).await;
        let bans = |answer: AdminResponse| match answer {
            AdminResponse::Access(a) => a.bans.into_iter().map(|(p, _)| p).collect::<Vec<_>>(),
            other => panic!("unexpected {other:?}"),
        };

        // One ban on each node, the second before the east node reloads:
        // it starts from the stored list and keeps the first.
        assert_eq!(bans(admin_on(&west, ban("xav")).await), ["xav"]);
        assert_eq!(bans(admin_on(&east, ban("yul")).await), ["xav", "yul"]);
        assert_eq!(
            bans(admin_on(&west, AdminRequest::Access).await),
            ["xav", "yul"]
        );

        // Banned on the west node: once the east node has read the list
        // again, it refuses zed's Hello and ends eve's live session.
        admin_on(&west, ban("zed")).await;
        admin_on(&west, ban("eve")).await;
        let limit = ACCESS_RELOAD_PERIOD + Duration::from_secs(5);
        let started = std::time::Instant::now();
        let zed = token(&east, "zed", Role::Player);
        let refused = loop {
            match strata_client_sim::Client::connect(east.addr, &east.cert_der, &zed).await {
                // Past zed's logins ([validation.join_rate]): not the ban yet.
                Err(strata_client_sim::ClientError::Refused {
                    code: ErrorCode::TooManyConnections,
                    ..
                }) => {}
                Err(strata_client_sim::ClientError::Refused { code, message }) => {
                    break (code, message)
                }
                Ok(c) => c.close().await,
                Err(e) => panic!("unexpected {e}"),
            }
            assert!(started.elapsed() < limit, "zed still joins the east node");
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        assert_eq!(refused.0, ErrorCode::Forbidden, "{}", refused.1);
        assert!(refused.1.contains("banned"), "{}", refused.1);
        let ended = tokio::time::timeout(limit, eve.closed())
            .await
            .expect("eve's session on the east node ended");
        assert!(
            matches!(&ended, strata_client_sim::ClientError::Refused { code, message }
                if *code == ErrorCode::Kicked && message.contains("administrator")),
            "{ended:?}"
        );

        // Bans made on both nodes at once: each is written only over the
        // list it read (else read again), so none is lost.
        let racers = |parity: usize| (0..16).filter(move |i| i % 2 == parity);
        let on = |node: &'static str, parity: usize| {
            let node = if node == "west" { &west } else { &east };
            async move {
                for i in racers(parity) {
                    admin_on(node, ban(&format!("racer{i:02}"))).await;
                }
            }
        };
        tokio::join!(on("west", 0), on("east", 1));
        let all = bans(admin_on(&west, AdminRequest::Access).await);
        let raced: Vec<&String> = all.iter().filter(|p| p.starts_with("racer")).collect();
        assert_eq!(raced.len(), 16, "{all:?}");
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

fn zone_names(answer: AdminResponse) -> Vec<String> {
    match answer {
        AdminResponse::Zones(z) => z.into_iter().map(|z| z.name).collect(),
        other => panic!("unexpected {other:?}"),
    }
}

/// The names of `node`'s zones once it holds `n` (it reads the stored
/// zones again every ZONES_RELOAD_PERIOD).
async fn zones_held(node: &Running, n: usize) -> Vec<String> {
    let limit = strata_server::stored_zones::ZONES_RELOAD_PERIOD + Duration::from_secs(5);
    let started = std::time::Instant::now();
    loop {
        let names = zone_names(admin_on(node, AdminRequest::Zones).await);
        if names.len() == n {
            return names;
        }
        assert!(started.elapsed() < limit, "still {names:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Protected zones are shared like the access list: a zone added on either
/// node is refused on both (the other reads the stored zones again within
/// ZONES_RELOAD_PERIOD), and zones added on both nodes at once are all
/// kept (each change is written only over the zones it read).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn zones_added_on_either_node_hold_on_both() {
    use strata_protocol::admin::ZoneSpec;
    use strata_protocol::RejectReason;
    use strata_terrain::VoxelPos;
    let Some(db) = strata_tests::postgres::database("cluster_zones") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let around = |name: &str, x: i32| {
            let (_, v) = spot(x, Z);
            AdminRequest::ZoneAdd(ZoneSpec {
                name: name.into(),
                min: VoxelPos::new(v.x - 6, v.y - 6, v.z - 6),
                max: VoxelPos::new(v.x + 6, v.y + 6, v.z + 6),
            })
        };
        let bob = standing(&east, "bob", EAST_X).await;

        // Added on the west node, around bob's spot on the east node.
        assert_eq!(
            zone_names(admin_on(&west, around("keep", EAST_X + 2)).await),
            ["keep"]
        );
        assert_eq!(zones_held(&east, 1).await, ["keep"]);
        let (v, _) = bob.edit_acked(mine_at(EAST_X + 2)).await.unwrap();
        assert_eq!(
            v,
            Verdict::Rejected(RejectReason::ProtectedZone {
                zone: "keep".into()
            })
        );

        // Zones added on both nodes at once: none is lost.
        let on = |node: &'static str, parity: usize| {
            let node = if node == "west" { &west } else { &east };
            async move {
                for i in (0..12i32).filter(|i| *i as usize % 2 == parity) {
                    let answer = admin_on(node, around(&format!("z{i:02}"), 1000 + 40 * i)).await;
                    assert!(matches!(answer, AdminResponse::Zones(_)), "{answer:?}");
                }
            }
        };
        tokio::join!(on("west", 0), on("east", 1));
        // Each node holds all 13 once it has read the other's last change.
        for node in [&west, &east] {
            zones_held(node, 13).await;
        }
        bob.close().await;
        west.shutdown().await.unwrap();
        east.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// A node the cluster client joins after the player asked for a view
/// (`Subscribe`) streams that view, as the nodes connected then do.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_joined_later_streams_the_view_asked() {
    let Some(db) = strata_tests::postgres::database("cluster_view_asked") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let bob = bob_claims_region_one(&east).await;

        // Ann, at home on the west node, asks for a view in region 1,
        // beyond her own view radius of where she stands, before she
        // joins the east node.
        let ann_token = token(&west, "ann", Role::Player);
        let mut ann = ClusterClient::connect(
            west.addr,
            &west.cert_der,
            &ann_token,
            ClientOptions::default(),
        )
        .await
        .unwrap();
        let center = chunk_of(EAST_X);
        ann.subscribe(center, 1).await;
        assert!(
            eventually(TEST_TIMEOUT, || ann.home().replica().get(center).is_some()).await,
            "the west node streams the view asked"
        );
        follow_until_joined(&mut ann, east.addr).await;

        // The east node, asked the same, streams the same view.
        let there = || ann.node(east.addr).unwrap();
        assert!(
            eventually(TEST_TIMEOUT, || there().replica().get(center).is_some()).await,
            "the east node streams the view asked"
        );
        let neighbour = ChunkPos::new(center.x + 1, center.y, center.z);
        assert!(eventually(TEST_TIMEOUT, || there().replica().get(neighbour).is_some()).await);
        // Both running nodes hold the database against a forced restore.
        let serving = sql(
            &db,
            &format!("SELECT count(*) {}", crate::store_common::SERVING_LOCK_ROWS),
        )
        .await;
        assert_eq!(serving, ["2"]);
        ann.close().await;
        finish(bob, east).await;
        west.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// A node that never saw a player reads, as the player joins, where another
/// node last saved it: a ticket issued more than `STORED_TICKET_SLACK_MS`
/// before then cannot take the player back, a more recent one can (one
/// signed for another world cannot), and the player resumes where it was
/// saved.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ticket_older_than_another_nodes_stored_position_is_refused() {
    use strata_protocol::{Refusal, Start, TicketRefusal};
    use strata_server::cluster::ticket;
    use strata_server::engine::now_ms;
    let Some(db) = strata_tests::postgres::database("cluster_old_ticket") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let seen = now_ms();
        let ann = standing(&west, "ann", WEST_X).await;
        // A ticket held 20 s (a replay; tickets live 30 s), older than
        // any a node issues by more than the slack.
        let issued_before = seen - 20_000;
        // The west node saves where it saw ann (once a second).
        let saved =
            format!("SELECT count(*) FROM players WHERE name = 'ann' AND known_ms >= {seen}");
        let started = std::time::Instant::now();
        while sql(&db, &saved).await != ["1"] {
            assert!(started.elapsed() < Duration::from_secs(20), "never saved");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let on_east = connect(&east, "ann", Role::Player).await;
        assert!(
            matches!(on_east.welcome().start, Start::Resume { .. }),
            "{:?}",
            on_east.welcome().start
        );
        let old = ticket::mint(
            west.tickets.as_ref().unwrap(),
            "ann",
            feet(EAST_X),
            issued_before,
        );
        let arrived = on_east.arrive_within(old, Duration::from_secs(10)).await;
        assert_eq!(arrived.unwrap(), None, "an older ticket moved ann");
        assert_eq!(
            on_east.refusals(),
            [Refusal::BadTicket {
                reason: TicketRefusal::AlreadyPlaced
            }]
        );
        // One issued a few seconds before the save (the player's latest) is
        // taken, if signed for this world: the nodes share its id, and a
        // cluster of another world on the same secret signs for its own.
        let recent = seen - 5_000;
        let world = west.tickets.as_ref().unwrap().world().to_string();
        assert_eq!(east.tickets.as_ref().unwrap().world(), world);
        let other = ticket::TicketKey::new(west.data_dir.secret().clone(), format!("{world}x"));
        let elsewhere = ticket::mint(&other, "ann", feet(WEST_X), recent);
        on_east.arrive(elsewhere).await.unwrap();
        assert!(eventually(Duration::from_secs(10), || on_east.refusals().len() == 2).await);
        assert_eq!(on_east.arrived(), None, "another world's ticket moved ann");
        assert_eq!(
            on_east.refusals()[1..],
            [Refusal::BadTicket {
                reason: TicketRefusal::BadSignature
            }]
        );
        // For a spot ann walked on from since: it is placed where it was
        // saved, and told so.
        let new = ticket::mint(
            west.tickets.as_ref().unwrap(),
            "ann",
            feet(WEST_X + 3),
            recent,
        );
        on_east.arrive(new).await.unwrap();
        assert!(eventually(Duration::from_secs(10), || on_east.arrived().is_some()).await);
        assert_eq!(on_east.arrived(), Some(feet(WEST_X)));
        // Ann arrives where it was seen last: the saved spot, newer than
        // the ticket. The tickets east mints for it, a spot east never saw
        // reported, keep the time ann was known there: not fresher at each
        // refresh (one outdating reports ann makes elsewhere would take it
        // back there). Told once it has a view.
        // (West may save it again meanwhile: east read it at ann's join.)
        let known = sql(&db, "SELECT known_ms FROM players WHERE name = 'ann'").await;
        let known: u64 = known[0].parse().unwrap();
        on_east.subscribe(chunk_of(WEST_X), 1).await.unwrap();
        assert!(
            eventually(Duration::from_secs(10), || on_east
                .region_owners()
                .is_some_and(|o| o.ticket.is_some()))
            .await,
            "{:?}",
            on_east.region_owners()
        );
        assert_eq!(on_east.region_owners().unwrap().node, "east");
        let minted = on_east.region_owners().unwrap().ticket.unwrap();
        assert_eq!(minted.feet, feet(WEST_X));
        assert!(
            (seen..=known).contains(&minted.issued_ms),
            "{} not saved between {seen} and {known}",
            minted.issued_ms
        );
        finish(ann, west).await;
        finish(on_east, east).await;
    })
    .await
    .expect("test finished in time");
}

/// A node's ticket for a position reported to it is timed when it was
/// reported: a player that stops reporting to one node (walking on
/// through another) gets no fresher ticket for its old spot at the next
/// refresh, one that would outdate what it reports elsewhere.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ticket_is_timed_when_its_position_was_reported() {
    let Some(db) = strata_tests::postgres::database("cluster_ticket_time") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let (_dirs, west, east) = west_and_east(&db).await;
        let ann = standing(&west, "ann", WEST_X).await;
        let told = || ann.region_owners().filter(|o| o.ticket.is_some());
        assert!(eventually(Duration::from_secs(10), || told().is_some()).await);
        let first = told().unwrap();
        // The next refresh (every TICKET_REFRESH_MS) re-mints it.
        assert!(
            eventually(Duration::from_secs(20), || told()
                .is_some_and(|o| o.serial > first.serial))
            .await
        );
        let (a, b) = (first.ticket.unwrap(), told().unwrap().ticket.unwrap());
        assert_eq!((b.feet, b.issued_ms), (a.feet, a.issued_ms));
        finish(ann, west).await;
        east.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Takes the players table from every other session (a plain `SELECT` of
/// a stored position waits) until told; the holder thread comes second.
fn lock_players(
    db: &strata_tests::postgres::PgDb,
) -> (std::sync::mpsc::Sender<()>, std::thread::JoinHandle<()>) {
    let lock = "LOCK TABLE players IN ACCESS EXCLUSIVE MODE";
    crate::store_common::hold_until_told(db, lock)
}

/// Ends [`lock_players`]'s transaction and waits for its thread.
async fn unlock_players(held: (std::sync::mpsc::Sender<()>, std::thread::JoinHandle<()>)) {
    let (release, holder) = held;
    release.send(()).unwrap();
    tokio::task::spawn_blocking(move || holder.join().unwrap())
        .await
        .unwrap();
}

/// The test database's backends reading a stored position now (the
/// store's query; pg_stat_activity lists every database's, so this one's
/// only).
async fn position_readers(db: &strata_tests::postgres::PgDb) -> u32 {
    let n = sql(
        db,
        "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() \
         AND pid <> pg_backend_pid() AND state = 'active' \
         AND query LIKE 'SELECT x, y, z, known_ms FROM players WHERE name%'",
    )
    .await;
    n[0].parse().unwrap()
}

/// Waits until the store holds a position of `player` known at `seen` or
/// later (the node saves them once a second).
async fn saved_since(db: &strata_tests::postgres::PgDb, player: &str, seen: u64) {
    let saved =
        format!("SELECT count(*) FROM players WHERE name = '{player}' AND known_ms >= {seen}");
    let started = std::time::Instant::now();
    while sql(db, &saved).await != ["1"] {
        assert!(started.elapsed() < Duration::from_secs(20), "never saved");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// A login to `node` as `player`: how it ended and how long it took.
async fn timed_login(
    node: &Running,
    player: &str,
) -> (
    Result<strata_client_sim::Client, strata_client_sim::ClientError>,
    Duration,
) {
    let t = token(node, player, Role::Player);
    let started = std::time::Instant::now();
    let c = strata_client_sim::Client::connect(node.addr, &node.cert_der, &t).await;
    (c, started.elapsed())
}

/// The refusal's message, which must be a retryable `TooManyConnections`.
fn busy_refusal(
    login: &Result<strata_client_sim::Client, strata_client_sim::ClientError>,
) -> String {
    match login {
        Err(strata_client_sim::ClientError::Refused {
            code: ErrorCode::TooManyConnections,
            message,
        }) if message.contains("try again") => message.clone(),
        Err(e) => panic!("not refused busy: {e}"),
        Ok(_) => panic!("let in without its stored position"),
    }
}

/// How many logins the process's metrics count refused for `reason`.
fn refused_for(reason: &str) -> f64 {
    let text = strata_server::metrics::shared().unwrap().render();
    let line = format!("strata_connections_refused_total{{reason=\"{reason}\"}} ");
    text.lines()
        .find_map(|l| l.strip_prefix(&line))
        .map_or(0.0, |v| v.trim().parse().unwrap())
}

/// A login whose stored position stays unreadable (the players table is
/// locked) is refused `TooManyConnections` once `[cluster]
/// position_read_ms` has passed, never let in unplaced; meanwhile the
/// node renews its lease and commits a standing player's edit, and once
/// the table is free again the player logs in.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_login_whose_stored_position_is_not_read_in_time_is_refused_and_the_node_goes_on() {
    use strata_server::engine::now_ms;
    let Some(db) = strata_tests::postgres::database("cluster_position_read_slow") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        strata_server::metrics::shared().unwrap();
        let bound = Duration::from_millis(1_500);
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 5_000, 500);
        cfg.cluster.as_mut().unwrap().position_read_ms = bound.as_millis() as u64;
        // One login a player, never refilled: a login refused for the
        // unread position is not charged, so bob still logs in after it.
        cfg.validation.join_rate = strata_server::validate::ratelimit::BucketConfig {
            capacity: 1,
            per_second: 0,
        };
        let west = app::start(cfg).await.expect("node starts");
        let seen = now_ms();
        let ann = standing(&west, "ann", WEST_X).await;
        let (v, _) = ann.edit_acked(mine_at(WEST_X + 2)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
        // Saved: no save of hers waits on the lock (ahead of the commits).
        saved_since(&db, "ann", seen).await;
        let renewed = "SELECT renewed_at::text FROM regions WHERE owner = 'west'";
        let before = sql(&db, renewed).await;
        assert_eq!(before.len(), 1, "west holds region 0");
        let slow_before = refused_for("position_read_slow");

        let held = lock_players(&db);
        let (bob, took) = timed_login(&west, "bob").await;
        let why = busy_refusal(&bob);
        assert!(why.contains("in time"), "{why}");
        assert!(
            took >= bound - Duration::from_millis(100) && took < bound + Duration::from_secs(2),
            "refused after {took:?}"
        );
        assert!(refused_for("position_read_slow") > slow_before);
        // The node went on meanwhile: it renewed its lease and commits.
        assert_ne!(sql(&db, renewed).await, before, "no renewal while locked");
        let (v, _) = ann.edit_acked(mine_at(WEST_X)).await.unwrap();
        assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");

        unlock_players(held).await;
        let (bob, _) = timed_login(&west, "bob").await;
        let bob = bob.expect("bob logs in once the table is free");
        bob.close().await;
        finish(ann, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// However many players log in at once, at most `[cluster]
/// position_reads` stored positions are read at once, each on one pooled
/// connection: the others wait for a turn and are refused at
/// `position_read_ms`, and reads stuck in the store keep their turns
/// after their logins gave up, so the next logins find none either.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn logins_past_position_reads_hold_no_more_connections_and_are_refused_in_time() {
    let Some(db) = strata_tests::postgres::database("cluster_position_reads") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        strata_server::metrics::shared().unwrap();
        let (reads, bound) = (2, Duration::from_millis(2_000));
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 5_000, 500);
        let cluster = cfg.cluster.as_mut().unwrap();
        cluster.position_reads = reads;
        cluster.position_read_ms = bound.as_millis() as u64;
        let west = Arc::new(app::start(cfg).await.expect("node starts"));
        let busy_before = refused_for("position_reads");

        let held = lock_players(&db);
        for wave in [6, 3] {
            let logins: Vec<_> = (0..wave)
                .map(|i| {
                    let west = west.clone();
                    tokio::spawn(async move { timed_login(&west, &format!("p{wave}_{i}")).await })
                })
                .collect();
            let mut most = 0;
            while logins.iter().any(|l| !l.is_finished()) {
                most = most.max(position_readers(&db).await);
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            let mut busy = 0;
            for l in logins {
                let (login, took) = l.await.unwrap();
                let why = busy_refusal(&login);
                busy += usize::from(why.contains("busy"));
                assert!(
                    took < bound + Duration::from_secs(2),
                    "refused after {took:?}"
                );
            }
            assert!(most <= reads as u32, "{most} reads at once");
            if wave == 6 {
                // Two read, and wait on the lock past the bound.
                assert_eq!(most, reads as u32, "the reads never ran");
                assert_eq!(busy, wave - reads, "refused for want of a turn");
            } else {
                // The stuck reads still hold both turns.
                assert_eq!(busy, wave, "refused for want of a turn");
            }
        }
        assert_eq!(position_readers(&db).await, reads as u32);
        assert!(refused_for("position_reads") >= busy_before + 7.0);

        unlock_players(held).await;
        let (late, _) = timed_login(&west, "late").await;
        late.expect("a login once the table is free").close().await;
        let Ok(west) = Arc::try_unwrap(west) else {
            panic!("a login still holds the node");
        };
        west.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// A stored position whose read fails (the store's statement timeout,
/// here under a lock; a player flooding logins could cause it too) refuses
/// the login at once: counted as no position, it would let the player
/// onto a node that never saw it with an `Arrive` ticket older than
/// where another node last saved it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_login_whose_stored_position_read_fails_is_refused_not_let_in_unplaced() {
    use strata_server::engine::now_ms;
    let Some(db) = strata_tests::postgres::database("cluster_position_read_failed") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        strata_server::metrics::shared().unwrap();
        let dirs = tempfile::tempdir().unwrap();
        let (da, db_dir) = (dirs.path().join("a"), dirs.path().join("b"));
        let west = node(&da, &db, "west", WEST_X).await;
        share_keys(&da, &db_dir);
        let mut cfg = node_config(&db_dir, &db, ("east", EAST_X), 5_000, 500);
        cfg.store.postgres.statement_timeout_ms = 300;
        let east = app::start(cfg).await.expect("node starts");
        let seen = now_ms();
        let ann = standing(&west, "ann", WEST_X).await;
        saved_since(&db, "ann", seen).await;
        let failed_before = refused_for("position_read_failed");

        let held = lock_players(&db);
        let (on_east, took) = timed_login(&east, "ann").await;
        let why = busy_refusal(&on_east);
        assert!(!why.contains("in time") && !why.contains("busy"), "{why}");
        let wait = Duration::from_millis(strata_server::cluster::DEFAULT_POSITION_READ_MS);
        assert!(took < wait, "refused only after {took:?}");
        assert!(refused_for("position_read_failed") > failed_before);

        unlock_players(held).await;
        let (on_east, _) = timed_login(&east, "ann").await;
        let on_east = on_east.expect("ann logs in once the table is free");
        assert!(
            matches!(
                on_east.welcome().start,
                strata_protocol::Start::Resume { .. }
            ),
            "{:?}",
            on_east.welcome().start
        );
        finish(ann, west).await;
        finish(on_east, east).await;
    })
    .await
    .expect("within the test timeout");
}

/// A node numbers its edits from seq blocks of `[cluster] seq_block`
/// seqs: it reserves the next block while a quarter of one is left, so a
/// player's edits go on being acknowledged, in order, across many blocks.
/// While no block can be reserved, edits past the block's end wait,
/// numbered nowhere, and go on once one is. Every seq is inside one of
/// the node's blocks, and the log checks out.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_moves_on_to_its_next_seq_block_before_one_runs_out() {
    let Some(db) = strata_tests::postgres::database("cluster_seq_blocks") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Renewals (which reserve the next block) every 200 ms.
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 5_000, 200);
        let block = strata_server::cluster::MIN_SEQ_BLOCK;
        cfg.cluster.as_mut().unwrap().seq_block = block;
        let loose = strata_server::validate::ratelimit::BucketConfig {
            capacity: 1 << 20,
            per_second: 1 << 20,
        };
        cfg.validation.edit_rate = loose;
        cfg.validation.volume_rate = loose;
        let west = app::start(cfg).await.expect("node starts");
        let ann = Arc::new(standing(&west, "ann", WEST_X).await);
        let seqs = Arc::new(std::sync::Mutex::new(Vec::new()));
        edit_around(&ann, 4 * block as usize, &seqs).await;
        let blocks = seq_blocks(&db).await;
        assert!(blocks.len() >= 4, "{blocks:?}");
        assert!(blocks.iter().all(|(f, l)| l - f + 1 == block), "{blocks:?}");
        assert_within(&seqs.lock().unwrap(), &blocks);

        // No block can be reserved (a check no new row passes): of two
        // blocks' worth of edits, those past this block's end wait.
        sql(
            &db,
            "ALTER TABLE seq_blocks ADD CONSTRAINT no_new_block CHECK (first_seq < 0) NOT VALID",
        )
        .await;
        let blocks = seq_blocks(&db).await;
        let done = seqs.lock().unwrap().len();
        let editing = tokio::spawn({
            let (ann, seqs) = (ann.clone(), seqs.clone());
            async move { edit_around(&ann, 2 * block as usize, &seqs).await }
        });
        tokio::time::sleep(Duration::from_secs(2)).await;
        let taken = seqs.lock().unwrap().len() - done;
        assert!(
            taken <= block as usize,
            "{taken} of {} acknowledged",
            2 * block
        );
        assert_eq!(seq_blocks(&db).await, blocks, "no block reserved");
        let last: u64 = sql(&db, "SELECT max(seq) FROM edit_log").await[0]
            .parse()
            .unwrap();
        assert!(
            last <= blocks.last().unwrap().1,
            "seq {last} past {blocks:?}"
        );
        sql(&db, "ALTER TABLE seq_blocks DROP CONSTRAINT no_new_block").await;
        editing.await.unwrap();
        let seqs = seqs.lock().unwrap().clone();
        assert_eq!(seqs.len(), done + 2 * block as usize, "all acknowledged");
        let blocks = seq_blocks(&db).await;
        assert_within(&seqs, &blocks);

        checks_clean(&db).await;
        let ann = Arc::into_inner(ann).expect("the editing task is done");
        finish(ann, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// `check` of the world on `db` finds nothing wrong.
async fn checks_clean(db: &strata_tests::postgres::PgDb) {
    let url = db.url();
    let report = tokio::task::spawn_blocking(move || {
        use strata_server::store::ChunkStore;
        let pg = strata_server::store::pg::PgConfig {
            url,
            ..Default::default()
        };
        strata_server::store::PgStore::open(&pg, 8)
            .unwrap()
            .check()
            .unwrap()
    })
    .await
    .unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// `n` mining edits around the feet of `c` (standing at `WEST_X`; within
/// reach, none under them), 12 in flight at a time (a session may have
/// 16): each must be accepted, its seq pushed onto `seqs`.
async fn edit_around(c: &strata_client_sim::Client, n: usize, seqs: &std::sync::Mutex<Vec<u64>>) {
    let around = [(-4, -4), (-4, 0), (-4, 4), (0, -4), (0, 4), (4, -4), (4, 0)];
    let edits: Vec<Edit> = around
        .iter()
        .cycle()
        .take(n)
        .map(|(dx, dz)| mine_at_xz(WEST_X + dx, Z + dz))
        .collect();
    for burst in edits.chunks(12) {
        let mut sent = Vec::new();
        for e in burst {
            sent.push(c.submit(e.clone()).await.unwrap());
        }
        for s in sent {
            match c.verdict(s).await.unwrap().0 {
                Verdict::Accepted { seq } => seqs.lock().unwrap().push(seq),
                other => panic!("{other:?}"),
            }
        }
    }
}

/// The west node's seq blocks: (first, last) in order.
async fn seq_blocks(db: &strata_tests::postgres::PgDb) -> Vec<(u64, u64)> {
    let rows = sql(
        db,
        "SELECT first_seq || ' ' || last_seq FROM seq_blocks \
         WHERE node = 'west' ORDER BY first_seq",
    )
    .await;
    rows.iter()
        .map(|r| {
            let (a, b) = r.split_once(' ').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect()
}

/// `seqs` rise, each inside one of `blocks`.
fn assert_within(seqs: &[u64], blocks: &[(u64, u64)]) {
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "in order: {seqs:?}");
    for s in seqs {
        assert!(
            blocks.iter().any(|(f, l)| (f..=l).contains(&s)),
            "seq {s} outside the node's blocks {blocks:?}"
        );
    }
}

/// A held region whose reload keeps failing (adopted while its chunks
/// cannot be read) refuses its edits `Busy`, and those refusals do not
/// count as using it: it is let go once idle for `release_idle_ms`, not
/// kept by a player who keeps trying. Once readable, an edit claims it
/// again and is taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_region_whose_reload_keeps_failing_is_let_go_once_idle() {
    let Some(db) = strata_tests::postgres::database("cluster_reload_idle") else {
        return;
    };
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = node_config(dir.path(), &db, ("west", WEST_X), 1_000, 200);
        cfg.store.postgres.statement_timeout_ms = 300;
        cfg.cluster.as_mut().unwrap().release_idle_ms = 1_000;
        let west = app::start(cfg).await.expect("node starts");
        let ann = standing(&west, "ann", WEST_X).await;

        // The deltas table held by another session: region 0's chunks
        // cannot be read. A node that went away left region 0 leased;
        // west adopts it, and its reload fails.
        let lock = "LOCK TABLE chunk_deltas IN ACCESS EXCLUSIVE MODE";
        let (release, holder) = crate::store_common::hold_until_told(&db, lock);
        let thief = thief_takes_region_zero(&db).await;
        tokio::task::spawn_blocking(move || drop(thief))
            .await
            .unwrap();
        let owner = "SELECT owner FROM regions WHERE region_x = 0 AND region_z = 0";
        sql(
            &db,
            "UPDATE regions SET lease_expires = now() - interval '1 second' \
             WHERE region_x = 0 AND region_z = 0",
        )
        .await;
        let adopted = async {
            while sql(&db, owner).await != ["west"] {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        };
        tokio::time::timeout(Duration::from_secs(10), adopted)
            .await
            .expect("west adopts region 0");

        // Ann keeps trying: refused, and the region is let go all the same.
        let tried = std::time::Instant::now();
        let mut let_go = false;
        while tried.elapsed() < Duration::from_secs(8) {
            let (verdict, _) = ann.edit_acked(mine_at(WEST_X)).await.unwrap();
            assert_eq!(
                verdict,
                Verdict::Rejected(strata_protocol::RejectReason::Busy)
            );
            if sql(&db, owner).await.is_empty() {
                let_go = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        assert!(let_go, "region 0 kept by refused edits");

        readable_again(release, holder, &ann).await;
        assert_eq!(sql(&db, owner).await, ["west"]);
        finish(ann, west).await;
    })
    .await
    .expect("within the test timeout");
}

/// Ends the lock `hold_until_told` took, then has `ann` mine at `WEST_X`
/// until an edit is accepted (each refused one `Busy`), within 10 s.
async fn readable_again(
    release: std::sync::mpsc::Sender<()>,
    holder: std::thread::JoinHandle<()>,
    ann: &strata_client_sim::Client,
) {
    release.send(()).unwrap();
    tokio::task::spawn_blocking(move || holder.join().unwrap())
        .await
        .unwrap();
    for _ in 0..40 {
        tokio::time::sleep(RELOAD_RETRY / 4).await;
        let (verdict, _) = ann.edit_acked(mine_at(WEST_X)).await.unwrap();
        if matches!(verdict, Verdict::Accepted { .. }) {
            return;
        }
        assert_eq!(
            verdict,
            Verdict::Rejected(strata_protocol::RejectReason::Busy)
        );
    }
    panic!("the region was never reloaded");
}
