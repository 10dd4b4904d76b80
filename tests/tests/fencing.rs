//! The fencing-token scenario with real processes: a `strata-server` node
//! on PostgreSQL is SIGSTOPped past its lease while bots edit, another
//! node takes its regions, and the node is SIGCONTed. Nothing it commits
//! after the takeover reaches the store and nothing is acknowledged past
//! what the store held then. A batch in flight is refused by the fence and
//! abandoned; the node goes on and refuses its players' edits in the lost
//! regions, naming the new owner, until that owner lets them go: then it
//! takes them back and acknowledges again.
//!
//! Three nodes writing one world at once, each its own regions with seqs
//! from its own block; one is killed with SIGKILL and the others adopt its
//! regions within the lease.
//!
//! Its players are told and moved: bots (`--follow-owners`) on a node
//! paused past its lease, whose regions another node adopted, are refused
//! there naming the new owner, move to it with their tickets and keep
//! editing, every replica converged and every ack stored.
//!
//! And the graceful side: a node stopped with SIGTERM releases its leases,
//! `strata-admin cluster status` reports a running node's regions, and
//! the offline tools (check, render-map, snapshot create and restore)
//! work on the PostgreSQL store.

use std::io::{BufRead, BufReader, Read};
use std::process::Command;
use std::time::{Duration, Instant};

use strata_server::cluster::ClusterConfig;
use strata_server::sequencer::regions::DEFAULT_REGION_CHUNKS;
use strata_server::store::pg::PgConfig;
use strata_server::store::{ChunkStore, PgStore};
use strata_tests::postgres::database;
use strata_tests::{count, num, spawn_bots, verify_acks, Server, SERVER_CONFIG};

/// The paused node's lease and renewal period.
const LEASE_MS: u64 = 1_000;
const RENEW_MS: u64 = 200;
/// How long the node stays stopped past its lease.
const PAST_LEASE: Duration = Duration::from_millis(700);

fn signal(server: &Server, sig: &str) {
    let pid = server.proc.0.id().to_string();
    let ok = Command::new("kill")
        .args([sig, &pid])
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "kill {sig} {pid}");
}

/// Every acknowledged seq in a bots ack log.
/// One secret and one certificate for the cluster: `from`'s (a node
/// started once) copied into `to` before its node starts. A node with
/// identity files of its own beside the cluster's world is refused.
fn share_identity(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for f in ["auth.secret", "cert.der", "key.der"] {
        std::fs::copy(from.join(f), to.join(f)).unwrap();
    }
}

fn acked_seqs(path: &std::path::Path) -> Vec<u64> {
    let file = std::fs::File::open(path).unwrap();
    BufReader::new(file)
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(&l.unwrap()).unwrap();
            num(&v, "seq")
        })
        .collect()
}

/// `n` bots editing 5 times a second, logging acks to `acks`, once they
/// have 10 acknowledged.
fn editing_bots(server: &Server, acks: &std::path::Path, n: u32) -> strata_tests::Guard {
    bots_at(server, acks, n, ("bot", "512,512"), "60s")
}

/// Waits until `acks` holds `n` lines.
fn await_acks(acks: &std::path::Path, n: usize) {
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::fs::read_to_string(acks).map_or(0, |s| s.lines().count()) < n {
        assert!(Instant::now() < deadline, "no edits acknowledged");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// [`editing_bots`] named `prefix-N` living in the square whose corner is
/// `origin` (X,Z), for `duration`. Fleets on one cluster need their own
/// prefix: a player is one body, which a node resumes where another left it.
fn bots_at(
    server: &Server,
    acks: &std::path::Path,
    n: u32,
    (prefix, origin): (&str, &str),
    duration: &str,
) -> strata_tests::Guard {
    let bots = spawn_bots(
        server,
        &[
            "--player-prefix",
            prefix,
            "--bots",
            &n.to_string(),
            "--duration",
            duration,
            "--edit-rate",
            "5",
            "--area-origin",
            origin,
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    await_acks(acks, 10);
    bots
}

/// A log file's text so far.
fn read(path: &std::path::Path) -> String {
    let mut text = String::new();
    if let Ok(mut f) = std::fs::File::open(path) {
        let _ = f.read_to_string(&mut text);
    }
    text
}

/// What the store holds: last seq, the log's seqs, each chunk's version.
fn state(store: &PgStore) -> (u64, Vec<u64>, Vec<String>) {
    let log = store
        .edit_log(1..=u64::MAX)
        .map(|e| e.unwrap().seq)
        .collect();
    let chunks = store
        .modified_chunks()
        .map(|c| format!("{:?}", c.unwrap()))
        .collect();
    (store.last_seq().unwrap(), log, chunks)
}

#[test]
fn a_node_paused_past_its_lease_stores_and_acknowledges_nothing_after_a_takeover() {
    let Some(db) = database("fencing") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (data, acks, log) = (
        tmp.path().join("data"),
        tmp.path().join("acks.jsonl"),
        tmp.path().join("node-a.log"),
    );
    let store_config = format!("{SERVER_CONFIG}{}", db.store_toml());
    let config = format!(
        "{store_config}[cluster]\nnode_id = \"node-a\"\nlease_ms = {LEASE_MS}\nrenew_ms = {RENEW_MS}\n"
    );
    let stderr = std::fs::File::create(&log).unwrap();
    let mut server = Server::start_logging(&data, "127.0.0.1:0", &config, stderr.into());
    // For the offline verify-acks: the store, not the node.
    std::fs::write(data.join("strata.toml"), &store_config).unwrap();
    let bots = editing_bots(&server, &acks, 4);

    // The other node: a store handle of its own, with its own name.
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let other = ClusterConfig {
        node_id: "node-b".into(),
        lease_ms: 60_000,
        renew_ms: 10_000,
        // It takes node-a's regions when the test says.
        adopt: false,
        ..ClusterConfig::default()
    };
    let b = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &other).unwrap();
    let held_by_a: Vec<_> = b
        .region_leases()
        .unwrap()
        .into_iter()
        .filter(|l| l.owner.as_deref() == Some("node-a"))
        .collect();
    assert!(!held_by_a.is_empty(), "node-a leased the regions it wrote");

    signal(&server, "-STOP");
    std::thread::sleep(Duration::from_millis(LEASE_MS) + PAST_LEASE);
    let regions: Vec<_> = held_by_a.iter().map(|l| l.region).collect();
    let claimed = b.claim_regions(&regions).unwrap();
    assert_eq!(claimed.len(), regions.len(), "node-b took every region");
    let at_takeover = state(&b);

    signal(&server, "-CONT");
    // It wakes up. Its renewal (or the fence, refusing a batch it had in
    // flight) finds the leases lost, and from then on it refuses its
    // players' edits there, naming node-b. It keeps running.
    let deadline = Instant::now() + Duration::from_secs(20);
    while !read(&log).contains("region lease lost") && server.proc.0.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "node-a never saw its loss");
        std::thread::sleep(Duration::from_millis(50));
    }
    // Long enough for the bots to try a few more edits.
    std::thread::sleep(Duration::from_millis(1_500));
    assert_eq!(
        state(&b),
        at_takeover,
        "nothing of node-a's after the takeover"
    );
    // SIGTERM ends the bots' edits early; their summary says they tried
    // after the takeover and node-a refused them, naming node-b (else
    // "nothing acknowledged" below would hold of bots that never tried).
    bots.terminate();
    let (_, summary) = strata_tests::bots_summary(bots);
    assert!(
        num(&summary["edits_rejected"], "region_elsewhere") > 0,
        "node-a refused its bots' edits after the takeover: {summary}"
    );
    assert_eq!(count(&summary, "bots_failed"), 0, "{summary}");
    assert!(
        server.proc.0.try_wait().unwrap().is_none(),
        "node-a stopped: {}",
        read(&log)
    );
    let seqs = acked_seqs(&acks);
    assert!(
        seqs.iter().all(|&s| s <= at_takeover.0),
        "acknowledged past the takeover's seq {}: {:?}",
        at_takeover.0,
        seqs.iter()
            .filter(|&&s| s > at_takeover.0)
            .collect::<Vec<_>>()
    );

    // node-b lets go: node-a takes the regions back when its players edit
    // there (reloading them from the store) and acknowledges again.
    assert_eq!(b.release_leases().unwrap(), regions.len() as u64);
    let acks_after = tmp.path().join("acks-after.jsonl");
    drop(editing_bots(&server, &acks_after, 2));
    assert!(
        acked_seqs(&acks_after).iter().all(|&s| s > at_takeover.0),
        "edits after the takeover are numbered after it"
    );
    signal(&server, "-TERM");
    let status = server.proc.wait_timeout(Duration::from_secs(30));
    assert!(
        status.success(),
        "node-a exited with {status}: {}",
        read(&log)
    );
    for acks in [&acks, &acks_after] {
        let (status, report) = verify_acks(&data, acks);
        assert!(status.success(), "verify-acks: {report}");
        assert_eq!(num(&report, "records") as usize, acked_seqs(acks).len());
        assert_eq!(count(&report, "failure_count"), 0);
    }
    let (status, out) = admin(&["check", "--data-dir", data.to_str().unwrap()]);
    assert!(status.success() && out.contains("OK"), "check: {out}");
    // node-a released what it took back at its shutdown; node-b the rest.
    let mut taken_back = 0;
    for l in b.region_leases().unwrap() {
        if let Some(&epoch) = claimed.get(&l.region) {
            assert_eq!(l.owner, None, "{l:?}");
            taken_back += usize::from(l.epoch > epoch);
        }
    }
    assert!(taken_back > 0, "node-a took none of node-b's regions back");
}

#[test]
fn a_paused_nodes_players_are_told_the_new_owner_and_move_there() {
    let Some(db) = database("fencing_moved") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (da, dbb, acks) = (
        tmp.path().join("a"),
        tmp.path().join("b"),
        tmp.path().join("acks.jsonl"),
    );
    let store_config = format!("{SERVER_CONFIG}{}", db.store_toml());
    let config = |id: &str| {
        format!(
            "{store_config}[cluster]\nnode_id = \"{id}\"\nlease_ms = {LEASE_MS}\nrenew_ms = {RENEW_MS}\n"
        )
    };
    let a = Server::start_with(&da, "127.0.0.1:0", &config("node-a"));
    std::fs::write(da.join("strata.toml"), &store_config).unwrap();
    share_identity(&da, &dbb);
    let b = Server::start_with(&dbb, "127.0.0.1:0", &config("node-b"));
    // Bots on node-a, in the middle of region (2, 2): each edit touches
    // that region only.
    let bots = spawn_bots(
        &a,
        &[
            "--bots",
            "4",
            "--duration",
            "12s",
            "--edit-rate",
            "5",
            "--area-origin",
            "600,600",
            "--follow-owners",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    await_acks(&acks, 10);

    // Paused past its lease: node-b adopts its region.
    signal(&a, "-STOP");
    std::thread::sleep(Duration::from_millis(LEASE_MS) + PAST_LEASE);
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let reader = PgStore::open(&pg, DEFAULT_REGION_CHUNKS).unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let leases = reader.region_leases().unwrap();
        let r22 = leases
            .iter()
            .find(|l| l.region == strata_server::sequencer::regions::RegionId { x: 2, z: 2 });
        if r22.is_some_and(|l| l.owner.as_deref() == Some("node-b")) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "node-b adopted region (2, 2): {leases:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    signal(&a, "-CONT");

    let (status, summary) = strata_tests::bots_summary(bots);
    assert!(status.success(), "bots: {summary}");
    strata_tests::assert_converged(&summary);
    assert!(num(&summary, "handoffs") >= 1, "moved to node-b: {summary}");
    assert!(
        num(&summary["edits_rejected"], "region_elsewhere") >= 1,
        "told: {summary}"
    );
    // Every ack, from either node, is in the store.
    let (status, report) = verify_acks(&da, &acks);
    assert!(status.success(), "verify-acks: {report}");
    assert_eq!(count(&report, "failure_count"), 0);
    a.stop();
    b.stop();
}

/// Runs `strata-admin` with `args`; returns its status and stdout.
fn admin(args: &[&str]) -> (std::process::ExitStatus, String) {
    let child = Command::new(strata_tests::binary("strata-admin"))
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::inherit())
        .spawn()
        .expect("strata-admin starts");
    strata_tests::wait_with_output(strata_tests::Guard(child), Duration::from_secs(60))
}

#[test]
fn a_node_stopped_gracefully_hands_its_regions_over_and_the_admin_tools_read_postgres() {
    let Some(db) = database("graceful_handover") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (data, acks) = (tmp.path().join("data"), tmp.path().join("acks.jsonl"));
    let store_config = format!("{SERVER_CONFIG}{}", db.store_toml());
    // A long lease: only the release at shutdown can free the regions soon.
    let metrics = strata_tests::free_local_addr();
    let config = format!(
        "{store_config}[metrics]\nlisten = \"{metrics}\"\n\
         [cluster]\nnode_id = \"node-a\"\nlease_ms = 60000\nrenew_ms = 10000\n"
    );
    let server = Server::start_with(&data, "127.0.0.1:0", &config);
    std::fs::write(data.join("strata.toml"), &store_config).unwrap();
    let data_arg = data.to_str().unwrap();
    let bots = editing_bots(&server, &acks, 3);

    // While it runs: the node's regions, live, with edits and a rate.
    let (status, out) = admin(&[
        "cluster",
        "status",
        "--data-dir",
        data_arg,
        "--sample-ms",
        "1000",
        "--json",
    ]);
    assert!(status.success(), "cluster status: {out}");
    let rows: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let mine: Vec<_> = rows
        .iter()
        .filter(|r| r["owner"] == "node-a" && r["state"] == "live")
        .collect();
    assert!(!mine.is_empty(), "node-a's regions listed: {out}");
    assert!(mine.iter().all(|r| r["epoch"].as_u64() >= Some(1)));
    assert!(mine
        .iter()
        .all(|r| matches!(r["lease_age_ms"].as_i64(), Some(0..60_000))));
    assert!(
        mine.iter().any(|r| num(r, "edits") > 0),
        "edits counted: {out}"
    );
    assert!(
        mine.iter()
            .any(|r| r["edits_per_s"].as_f64().is_some_and(|v| v > 0.0)),
        "edits/s over the sample: {out}"
    );
    let (status, table) = admin(&[
        "cluster",
        "status",
        "--data-dir",
        data_arg,
        "--sample-ms",
        "0",
    ]);
    assert!(
        status.success() && table.contains("node node-a:"),
        "{table}"
    );
    // The node counts the regions it holds: at least those listed live
    // above (its bots may have claimed more since).
    let text = strata_tests::http_get(&metrics, "/metrics");
    let gauge = text
        .lines()
        .find_map(|l| l.strip_prefix("strata_cluster_regions_held "))
        .and_then(|v| v.trim().parse::<f64>().ok());
    assert!(
        gauge.is_some_and(|g| g >= mine.len() as f64),
        "regions held: {gauge:?}, {} listed",
        mine.len()
    );

    drop(bots);
    server.stop();

    // Released at shutdown: another node claims them at once, well
    // inside the 60 s lease.
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    // Named as the admin tools are: the forced restore below refuses a
    // database a running server's sessions use.
    let b = PgStore::open(&pg.for_admin(), DEFAULT_REGION_CHUNKS).unwrap();
    let leases = b.region_leases().unwrap();
    assert!(!leases.is_empty());
    assert!(
        leases.iter().all(|l| l.owner.is_none()),
        "every lease released: {leases:?}"
    );
    let before = state(&b);
    let acked = acked_seqs(&acks);
    assert!(acked.iter().all(|&s| s <= before.0));

    // The offline tools read the PostgreSQL store through the data dir's
    // strata.toml: check, a map, a snapshot, and a restore over it.
    let (status, out) = admin(&["check", "--data-dir", data_arg]);
    assert!(status.success() && out.contains("OK"), "check: {out}");
    let map = tmp.path().join("map.png");
    let (status, out) = admin(&[
        "render-map",
        "--data-dir",
        data_arg,
        "--region",
        "-2",
        "-2",
        "2",
        "2",
        "--top-down",
        "--out",
        map.to_str().unwrap(),
    ]);
    assert!(status.success(), "render-map: {out}");
    assert!(std::fs::metadata(&map).unwrap().len() > 100);
    let snap = tmp.path().join("world.snap");
    let (status, out) = admin(&[
        "snapshot",
        "create",
        "--data-dir",
        data_arg,
        "--out",
        snap.to_str().unwrap(),
    ]);
    assert!(status.success(), "snapshot create: {out}");
    let cfg = data.join("strata.toml");
    let restore = |force: bool| {
        let mut args = vec![
            "snapshot",
            "restore",
            snap.to_str().unwrap(),
            "--data-dir",
            data_arg,
            "--config",
            cfg.to_str().unwrap(),
        ];
        if force {
            args.push("--force");
        }
        admin(&args)
    };
    let (status, _) = restore(false);
    assert!(
        !status.success(),
        "a store with a world is not replaced without --force"
    );
    assert_eq!(state(&b), before, "the refused restore changed nothing");
    let (status, out) = restore(true);
    assert!(status.success(), "restore --force: {out}");
    let after = state(&b);
    assert_eq!(after.0, before.0, "last_seq is the snapshot's seq");
    assert!(after.1.is_empty(), "the restored world starts past its log");
    assert_eq!(after.2, before.2, "every chunk at its version");
    let (status, out) = admin(&["check", "--data-dir", data_arg]);
    assert!(
        status.success() && out.contains("OK"),
        "check after restore: {out}"
    );
}

/// The cluster test's lease and renewal period.
const CLUSTER_LEASE_MS: u64 = 2_000;
const CLUSTER_RENEW_MS: u64 = 400;

#[test]
fn three_nodes_write_one_world_and_a_killed_nodes_regions_are_adopted_within_the_lease() {
    let Some(db) = database("three_nodes") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let store_config = format!("{SERVER_CONFIG}{}", db.store_toml());
    // Each fleet's 48-voxel square straddles a region corner (regions are
    // 256 voxels): (512, 512), (1280, 512) and (-1280, 512), far apart.
    let origins = ["488,488", "1256,488", "-1304,488"];
    let mut nodes = Vec::new();
    for (i, origin) in origins.iter().enumerate() {
        let name = format!("node-{i}");
        let data = tmp.path().join(&name);
        let config = format!(
            "{store_config}[cluster]\nnode_id = \"{name}\"\nlease_ms = {CLUSTER_LEASE_MS}\n\
             renew_ms = {CLUSTER_RENEW_MS}\n"
        );
        if i > 0 {
            share_identity(&tmp.path().join("node-0"), &data);
        }
        let server = Server::start_with(&data, "127.0.0.1:0", &config);
        std::fs::write(data.join("strata.toml"), &store_config).unwrap();
        nodes.push((name, data, server, *origin));
    }
    let acks: Vec<_> = (0..3)
        .map(|i| tmp.path().join(format!("acks-{i}.jsonl")))
        .collect();
    // node-0's fleet runs until the node dies; the others' run out.
    let fleet = |i: usize| (["fleet0", "fleet1", "fleet2"][i], nodes[i].3);
    let doomed = bots_at(&nodes[0].2, &acks[0], 3, fleet(0), "60s");
    let fleets: Vec<_> = (1..3)
        .map(|i| bots_at(&nodes[i].2, &acks[i], 3, fleet(i), "8s"))
        .collect();

    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let store = PgStore::open(&pg, DEFAULT_REGION_CHUNKS).unwrap();
    let owners = |store: &PgStore| -> Vec<(String, (i32, i32))> {
        store
            .region_leases()
            .unwrap()
            .into_iter()
            .filter_map(|l| Some((l.owner?, (l.region.x, l.region.z))))
            .collect()
    };
    let held = owners(&store);
    for (name, ..) in &nodes {
        assert!(
            held.iter().any(|(o, _)| o == name),
            "{name} holds a region: {held:?}"
        );
    }
    let dead: Vec<(i32, i32)> = held
        .iter()
        .filter(|(o, _)| o == "node-0")
        .map(|(_, r)| *r)
        .collect();
    assert!(
        dead.len() >= 2,
        "edits at its corner span regions, all node-0's: {held:?}"
    );

    // SIGKILL node-0; the others' renewals adopt its regions once its
    // lease runs out: at most a lease and a renewal period later.
    let (_, data0, server0, _) = nodes.remove(0);
    server0.kill();
    let killed = Instant::now();
    drop(doomed);
    let takeover = loop {
        let now = owners(&store);
        let moved = dead.iter().all(|r| {
            now.iter()
                .any(|(o, h)| h == r && (o == "node-1" || o == "node-2"))
        });
        if moved {
            break killed.elapsed();
        }
        assert!(
            killed.elapsed() < Duration::from_secs(20),
            "node-0's regions {dead:?} not adopted: {now:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    println!("takeover after SIGKILL: {} ms", takeover.as_millis());
    assert!(
        takeover < Duration::from_millis(CLUSTER_LEASE_MS + CLUSTER_RENEW_MS + 1_500),
        "taken over in {takeover:?}"
    );

    // The survivors' bots converged on their node's world.
    for (fleet, (name, ..)) in fleets.into_iter().zip(&nodes) {
        let (status, summary) = strata_tests::bots_summary(fleet);
        assert!(status.success(), "{name}'s bots: {summary}");
        strata_tests::assert_converged(&summary);
        assert!(num(&summary, "edits_accepted") > 0, "{summary}");
        assert_eq!(num(&summary, "edits_unanswered"), 0, "{summary}");
    }
    // Every edit any node acknowledged is in PostgreSQL, node-0's too.
    for (i, data) in [&data0, &nodes[0].1, &nodes[1].1].into_iter().enumerate() {
        let seqs = acked_seqs(&acks[i]);
        assert!(!seqs.is_empty(), "node-{i} acknowledged edits");
        let (status, report) = verify_acks(data, &acks[i]);
        assert!(status.success(), "verify-acks node-{i}: {report}");
        assert_eq!(num(&report, "records") as usize, seqs.len());
        assert_eq!(count(&report, "failure_count"), 0, "{report}");
    }
    // Three seq blocks, and the log checks out with its jumps between them.
    let blocks: std::collections::BTreeSet<u64> = (0..3)
        .map(|i| acked_seqs(&acks[i])[0] / strata_server::cluster::DEFAULT_SEQ_BLOCK)
        .collect();
    assert_eq!(blocks.len(), 3, "one block per node: {blocks:?}");
    let (status, out) = admin(&["check", "--data-dir", nodes[0].1.to_str().unwrap()]);
    assert!(status.success() && out.contains("OK"), "check: {out}");
    for (_, _, server, _) in nodes {
        server.stop();
    }
}

/// Two processes started with one `node_id`: the later one takes the id
/// over once its ports are bound, and the earlier one stops with exit
/// status 3 (`EXIT_SUPERSEDED`, which the systemd units do not restart
/// on) instead of the two taking regions from each other.
#[test]
fn a_second_process_with_the_same_node_id_stops_the_first_with_status_3() {
    let Some(db) = database("same_node_id") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let store_config = format!("{SERVER_CONFIG}{}", db.store_toml());
    let config = format!(
        "{store_config}[cluster]\nnode_id = \"node-a\"\nlease_ms = {LEASE_MS}\nrenew_ms = {RENEW_MS}\n"
    );
    let mut first = Server::start_with(&tmp.path().join("a"), "127.0.0.1:0", &config);
    share_identity(&tmp.path().join("a"), &tmp.path().join("b"));
    let _second = Server::start_with(&tmp.path().join("b"), "127.0.0.1:0", &config);
    let status = first.proc.wait_timeout(Duration::from_secs(30));
    assert_eq!(
        status.code(),
        Some(strata_server::app::EXIT_SUPERSEDED),
        "{status:?}"
    );
}
