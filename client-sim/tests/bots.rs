//! The bots library against an in-process server over real QUIC: edits are
//! accepted and broadcast, replicas converge, and the ack log matches the
//! store once the server has stopped.

use std::time::Duration;

use strata_client_sim::bots::{self, BotsConfig, Profile, Tokens, VerifyMode};
use strata_server::admin::verify_acks::{read_ack_log, verify};
use strata_server::app;
use strata_server::config::{NetSection, ServerConfig};
use strata_server::store::SledStore;

async fn start_server(tmp: &tempfile::TempDir) -> app::Running {
    start_server_with(tmp, NetSection::default()).await
}

async fn start_server_with(tmp: &tempfile::TempDir, net: NetSection) -> app::Running {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = tmp.path().join("data");
    cfg.net = net;
    app::start(cfg).await.unwrap()
}

/// A short run against `server` with minted tokens; tests override fields.
fn config_for(server: &app::Running) -> BotsConfig {
    BotsConfig::new(
        server.addr,
        server.cert_der.clone(),
        Tokens::Minted(server.data_dir.secret().clone()),
    )
}

/// Runs the bots to the end and checks every replica converged.
async fn run_consistent(run: BotsConfig) -> bots::Summary {
    let s = tokio::time::timeout(Duration::from_secs(90), bots::run(run))
        .await
        .expect("the run ends")
        .unwrap();
    assert!(s.consistent(), "{}", s.human());
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn builders_converge_and_every_ack_is_stored() {
    let tmp = tempfile::tempdir().unwrap();
    let server = start_server(&tmp).await;
    let acks = tmp.path().join("acks.jsonl");
    let run = BotsConfig {
        bots: 4,
        duration: Duration::from_secs(3),
        profile: Profile::Builders,
        seed: 7,
        ack_log: Some(acks.clone()),
        ..config_for(&server)
    };
    let s = run_consistent(run).await;
    assert_eq!(s.connected_at_end, 4);
    // Every bot joined before the edits started.
    assert_eq!(s.ready_at_start, 4);
    assert!(s.ramp_s > 0.0);
    assert!(s.edits_accepted >= 10, "{}", s.human());
    assert!(
        s.chunks_verified > 0 && s.broadcast_latency_ms.count > 0,
        "{s:?}"
    );
    let db = server.data_dir.world_db_path();
    server.shutdown().await.unwrap();
    let records = read_ack_log(&acks).unwrap();
    assert_eq!(records.len() as u64, s.edits_accepted);
    let report = verify(&SledStore::open(&db).unwrap(), &records).unwrap();
    assert!(report.ok(), "{report:?}");
}

#[tokio::test]
async fn without_a_ramp_bots_edit_while_others_join() {
    let tmp = tempfile::tempdir().unwrap();
    let server = start_server(&tmp).await;
    let run = BotsConfig {
        bots: 3,
        duration: Duration::from_secs(2),
        profile: Profile::Miners,
        seed: 3,
        ramp: false,
        ..config_for(&server)
    };
    let s = run_consistent(run).await;
    assert_eq!((s.ready_at_start, s.ramp_s), (0, 0.0), "no ramp phase");
    assert!(s.edits_accepted > 0, "{}", s.human());
    server.shutdown().await.unwrap();
}

/// A stop during the ramp (the binary's first SIGTERM) ends it at once:
/// no edits, and the run still waits for quiet, checks and reports. A
/// ramp not told lasts at least QUIET_PERIOD (750 ms) of quiet.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stop_during_the_ramp_ends_it_with_a_summary() {
    let tmp = tempfile::tempdir().unwrap();
    let server = start_server(&tmp).await;
    let run = BotsConfig {
        bots: 2,
        duration: Duration::from_secs(60),
        profile: Profile::Miners,
        seed: 5,
        ..config_for(&server)
    };
    let s = tokio::time::timeout(
        Duration::from_secs(30),
        bots::run_until(run, None, std::future::ready(())),
    )
    .await
    .expect("the run ends before its duration")
    .unwrap();
    assert!(s.ramp_s < 0.5, "the ramp ended when told: {}", s.human());
    assert_eq!(s.edits_accepted, 0, "{}", s.human());
    server.shutdown().await.unwrap();
}

/// `--thin --op-replay`: bots load their views as snapshots (nothing
/// regenerated), take edits as ops, and still converge on the server.
#[tokio::test]
async fn thin_op_replay_bots_converge() {
    let tmp = tempfile::tempdir().unwrap();
    let server = start_server(&tmp).await;
    let run = BotsConfig {
        bots: 3,
        duration: Duration::from_secs(2),
        profile: Profile::Miners,
        seed: 11,
        capabilities: strata_protocol::CAP_SNAPSHOTS | strata_protocol::CAP_OP_REPLAY,
        ..config_for(&server)
    };
    let s = run_consistent(run).await;
    assert_eq!((s.generated, s.patched), (0, 0), "{}", s.human());
    assert!(s.edits_accepted > 0 && s.op_chunks > 0, "{}", s.human());
    assert_eq!(s.op_mismatches, 0, "{}", s.human());
    server.shutdown().await.unwrap();
}

#[tokio::test]
async fn bad_settings_are_refused_before_connecting() {
    let run = BotsConfig {
        server: "127.0.0.1:9".parse().unwrap(),
        cert_der: Vec::new(),
        tokens: Tokens::Shared("t".into()),
        bots: 2,
        duration: Duration::from_secs(1),
        profile: Profile::Mixed,
        edit_rate: 1.0,
        view_radius: 2,
        verify: VerifyMode::All,
        seed: 1,
        stalled: 3,
        stalled_window: None,
        ramp: true,
        ack_log: None,
        progress: false,
        area_origin: bots::DEFAULT_AREA_ORIGIN,
        region_chunks: 8,
        silence_limit: bots::DEFAULT_SILENCE_LIMIT,
        predict: false,
        capabilities: 0,
        follow_owners: false,
        player_prefix: "bot".into(),
        link_delay: Duration::ZERO,
        verify_timeout: bots::DEFAULT_VERIFY_TIMEOUT,
    };
    let e = bots::run(run.clone()).await.unwrap_err();
    assert!(e.to_string().contains("--stalled"), "{e}");
    let e = bots::run(BotsConfig {
        stalled: 0,
        ramp: true,
        view_radius: 0,
        ..run.clone()
    })
    .await
    .unwrap_err();
    assert!(e.to_string().contains("--view-radius"), "{e}");
    let e = bots::run(BotsConfig {
        stalled: 0,
        link_delay: bots::MAX_LINK_DELAY + Duration::from_millis(1),
        ..run.clone()
    })
    .await
    .unwrap_err();
    assert!(e.to_string().contains("--link-delay"), "{e}");
    for verify_timeout in [
        Duration::ZERO,
        bots::MAX_VERIFY_TIMEOUT + Duration::from_secs(1),
    ] {
        let e = bots::run(BotsConfig {
            stalled: 0,
            verify_timeout,
            ..run.clone()
        })
        .await
        .unwrap_err();
        assert!(e.to_string().contains("--verify-timeout"), "{e}");
    }
    for window in [bots::MIN_STALLED_WINDOW - 1, bots::MAX_STALLED_WINDOW + 1] {
        let e = bots::run(BotsConfig {
            stalled: 1,
            stalled_window: Some(window),
            ..run.clone()
        })
        .await
        .unwrap_err();
        assert!(e.to_string().contains("--stalled-window"), "{e}");
    }
}

/// `--verify-timeout`: a check that runs out of time leaves the chunks the
/// server has not sent yet unverified, and the run is not called
/// consistent; the default leaves time for all of them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_check_out_of_time_counts_what_it_did_not_verify() {
    let tmp = tempfile::tempdir().unwrap();
    let server = start_server(&tmp).await;
    let run = BotsConfig {
        bots: 2,
        duration: Duration::from_millis(500),
        edit_rate: 0.0,
        verify: VerifyMode::All,
        verify_timeout: Duration::from_millis(1),
        ..config_for(&server)
    };
    let s = tokio::time::timeout(Duration::from_secs(90), bots::run(run.clone()))
        .await
        .expect("the run ends")
        .unwrap();
    assert!(s.chunks_unverified > 0, "{}", s.human());
    assert!(!s.consistent(), "{}", s.human());
    let s = run_consistent(BotsConfig {
        verify_timeout: bots::DEFAULT_VERIFY_TIMEOUT,
        ..run
    })
    .await;
    assert_eq!(s.chunks_unverified, 0, "{}", s.human());
    assert!(s.chunks_verified > 0, "{}", s.human());
    server.shutdown().await.unwrap();
}

/// `--link-delay`: every bot's sends leave 150 ms late, so each verdict
/// takes at least that long. The server is set up for such players (a
/// send interval, ACK_FREQUENCY), and the replicas still converge. At 10
/// edits a second the next slot falls due while each edit awaits its
/// verdict: those slots are counted, not silently dropped.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bots_over_a_delayed_link_converge() {
    let tmp = tempfile::tempdir().unwrap();
    let net = NetSection {
        send_interval_ms: 50,
        ack_delay_max_ms: 100,
        ack_eliciting_threshold: 3,
        ..NetSection::default()
    };
    let server = start_server_with(&tmp, net).await;
    let delay = Duration::from_millis(110);
    let run = BotsConfig {
        bots: 3,
        duration: Duration::from_secs(2),
        seed: 5,
        link_delay: delay,
        edit_rate: 10.0,
        ..config_for(&server)
    };
    let s = run_consistent(run.clone()).await;
    assert!(s.edits_accepted > 0, "{}", s.human());
    // Every request waits 150 ms on the link (histogram rounding aside).
    let p50 = s.ack_latency_ms.p50;
    assert!(p50 >= 109.0, "verdicts came back in {p50} ms at p50");
    // Every slot is accounted for: sent, skipped for want of a target, or
    // skipped while the last edit awaited its verdict (most of them here).
    // Each bot starts within its first interval, hence the margin.
    assert!(s.edit_slots_skipped > 0, "{}", s.human());
    let due = run.bots as f64 * run.edit_rate * run.duration.as_secs_f64();
    let slots = (s.edits_sent + s.edits_skipped + s.edit_slots_skipped) as f64;
    assert!(
        slots >= 0.8 * due,
        "{slots} of {due} edit slots accounted for: {}",
        s.human()
    );
    server.shutdown().await.unwrap();
}

/// `strata-bots --predict` (the real binary, with its own server): the
/// JSON summary carries the bots' summed prediction counts.
#[test]
fn the_binary_reports_predictions() {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_strata-bots"))
        .args(["--spawn-server", "--bots", "3", "--duration", "2s"])
        .args([
            "--profile",
            "mixed",
            "--edit-rate",
            "4",
            "--verify",
            "modified",
        ])
        .args(["--predict", "--json"])
        .env("RUST_LOG", "error")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("strata-bots starts");
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(90) {
            child.kill().unwrap();
            panic!("strata-bots did not finish");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut out = String::new();
    std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut out).unwrap();
    assert!(status.success(), "{status}: {out}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let p = &v["prediction"];
    let n = |k: &str| p[k].as_u64().unwrap_or_else(|| panic!("{k} in {p}"));
    assert!(n("made") > 0, "{p}");
    assert!(n("exact") > 0, "{p}");
    assert!(
        n("exact") + n("mispredicted") + n("rolled_back") + n("unverified") + n("pending")
            == n("made"),
        "{p}"
    );
    assert_eq!(n("pending"), 0, "{p}");
    assert!(v["edits_accepted"].as_u64().unwrap() > 0, "{v}");
}
