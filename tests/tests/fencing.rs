//! The fencing-token scenario with real processes: a `strata-server` node
//! on PostgreSQL is SIGSTOPped past its lease while bots edit, another
//! node takes its regions, and the node is SIGCONTed. Nothing it commits
//! after the takeover reaches the store and nothing is acknowledged past
//! what the store held then; the node stops, closing its sessions.

use std::io::{BufRead, BufReader, Read};
use std::process::Command;
use std::time::{Duration, Instant};

use strata_server::cluster::ClusterConfig;
use strata_server::sequencer::regions::DEFAULT_REGION_CHUNKS;
use strata_server::store::pg::PgConfig;
use strata_server::store::{ChunkStore, PgStore};
use strata_tests::postgres::database;
use strata_tests::{num, spawn_bots, verify_acks, Server, SERVER_CONFIG};

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
    let bots = spawn_bots(
        &server,
        &[
            "--bots",
            "4",
            "--duration",
            "60s",
            "--edit-rate",
            "5",
            "--ack-log",
            acks.to_str().unwrap(),
        ],
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    while std::fs::read_to_string(&acks).map_or(0, |s| s.lines().count()) < 10 {
        assert!(Instant::now() < deadline, "no edits acknowledged");
        std::thread::sleep(Duration::from_millis(100));
    }

    // The other node: a store handle of its own, with its own name.
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let other = ClusterConfig {
        node_id: "node-b".into(),
        lease_ms: 60_000,
        renew_ms: 10_000,
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
    // It wakes with edits queued and commits them: refused, it stops.
    let status = server.proc.wait_timeout(Duration::from_secs(30));
    assert!(!status.success(), "node-a stopped: {status}");
    drop(bots);

    assert_eq!(
        state(&b),
        at_takeover,
        "nothing of node-a's after the takeover"
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
    let (status, report) = verify_acks(&data, &acks);
    assert!(status.success(), "verify-acks: {report}");
    assert_eq!(num(&report, "records") as usize, seqs.len());
    assert_eq!(num(&report, "failure_count"), 0);
    let mut text = String::new();
    std::fs::File::open(&log)
        .unwrap()
        .read_to_string(&mut text)
        .unwrap();
    assert!(text.contains("is fenced"), "node-a's log says why: {text}");
    for l in b.region_leases().unwrap() {
        if regions.contains(&l.region) {
            assert_eq!(l.owner.as_deref(), Some("node-b"));
        }
    }
}
