//! An engine behind its tick rate applies the next batch while the last
//! one commits, then commits it at once: a real server process whose
//! commits outlast its 1 ms tick, under bots editing as fast as they may.
//! Every replica still converges, every mesh matches, and every
//! acknowledged edit is in the store once the server has stopped.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::bots::{self, BotsConfig, Tokens};
use strata_server::admin::verify_acks::{read_ack_log, verify};
use strata_server::datadir::DataDir;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn batches_applied_during_a_commit_are_acknowledged_only_once_durable() {
    let root = tempfile::tempdir().unwrap();
    let data = root.path().join("data");
    let metrics = free_metrics_addr();
    let config = format!("{FAST_EDITS}[metrics]\nlisten = \"{metrics}\"\n[engine]\ntick_ms = 1\n");
    let (mut child, addr) = spawn_server(&data, &config);
    let dd = DataDir::open_existing(&data).unwrap();
    let acks = root.path().join("acks.jsonl");
    let run = BotsConfig {
        bots: 16,
        // About 145 accepted a second alone on the 2-core box; 6 s leaves
        // room for a box busy with other tests (it once fell below 200 in 4 s).
        duration: Duration::from_secs(6),
        edit_rate: 200.0,
        seed: 11,
        ack_log: Some(acks.clone()),
        ..BotsConfig::new(
            addr,
            dd.cert().cert_der().to_vec(),
            Tokens::Minted(dd.secret().clone()),
        )
    };
    let s = tokio::time::timeout(Duration::from_secs(90), bots::run(run))
        .await
        .expect("the run ends")
        .unwrap();
    assert!(s.consistent(), "{}", s.human());
    assert!(s.edits_accepted >= 200, "{}", s.human());
    let text = scrape(metrics);
    let ahead = metric(&text, "strata_ticks_applied_ahead_total").unwrap_or(0.0);
    assert!(
        ahead > 0.0,
        "no batch was applied during a commit: {}",
        s.human()
    );
    child.kill().unwrap();
    child.wait().unwrap();
    // SIGKILLed: whatever was acknowledged was durable.
    let records = read_ack_log(&acks).unwrap();
    assert_eq!(records.len() as u64, s.edits_accepted);
    // Opened as `strata-admin verify-acks` does, with the world's generator.
    let store = strata_server::admin::remote::open_offline_store(dd.root()).unwrap();
    let report = verify(&*store, &records).unwrap();
    assert!(report.ok(), "{report:?}");
}
