//! Hostile players beside honest bots, against an in-process server over
//! real QUIC: 4 honest bots and 1 hostile per attack, 3 seconds each.
//!
//! Each test asserts that the honest bots converged and that the cheat
//! failed (the counters are printed too). Honest latency under attack is
//! measured by `scripts/bots_bench.sh ... --hostile 1 --attack KIND`
//! (BENCHMARKS.md), not here.

use std::time::Duration;

use strata_client_sim::bots::{
    self, Attack, BotsConfig, HostileConfig, HostileSummary, Profile, Summary, Tokens, VerifyMode,
};
use strata_server::app;
use strata_server::config::ServerConfig;

/// How long the bots edit and the hostile attacks.
const RUN: Duration = Duration::from_secs(3);

/// Runs 4 honest builders and one `attack` hostile against a fresh server;
/// prints the hostile counters.
async fn run_attack(attack: Attack, ramp: bool) -> (Summary, HostileSummary) {
    let tmp = tempfile::tempdir().unwrap();
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = tmp.path().join("data");
    let server = app::start(cfg).await.unwrap();
    let run = BotsConfig {
        server: server.addr,
        cert_der: server.cert_der.clone(),
        tokens: Tokens::Minted(server.data_dir.secret().clone()),
        bots: 4,
        duration: RUN,
        profile: Profile::Builders,
        edit_rate: 2.0,
        view_radius: 2,
        verify: VerifyMode::Modified,
        seed: 5,
        stalled: 0,
        stalled_window: None,
        ramp,
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
    let hostile = HostileConfig::new(attack, 1, server.addr);
    assert_eq!(hostile.bind.to_string(), "127.0.0.2");
    let s = tokio::time::timeout(Duration::from_secs(60), bots::run_with(run, Some(hostile)))
        .await
        .expect("the run ends")
        .unwrap();
    server.shutdown().await.unwrap();
    let h = s.hostile.clone().expect("a hostile summary");
    println!("{attack}: {}", serde_json::to_string(&h).unwrap());
    assert_eq!((h.attack.as_str(), h.players), (attack.name(), 1));
    for key in attack.counters() {
        assert!(h.counters.contains_key(*key), "{key} missing: {h:?}");
    }
    (s, h)
}

fn n(h: &HostileSummary, key: &str) -> u64 {
    h.counters[key]
}

/// The honest bots converged and kept editing.
fn assert_honest(s: &Summary) {
    assert!(s.consistent(), "{}", s.human());
    assert_eq!((s.replica_mismatches, s.mesh_mismatches), (0, 0));
    assert_eq!(s.connected_at_end, 4, "{}", s.human());
    assert!(s.edits_accepted > 0, "{}", s.human());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn position_flood_leaves_honest_bots_converging() {
    let (s, h) = run_attack(Attack::PositionFlood, true).await;
    assert_honest(&s);
    assert!(n(&h, "datagrams_sent") >= 10_000, "{h:?}");
}

/// Reports flipping over a chunk border at line rate: the server hands the
/// engine a bounded number of them and re-centres the view only past its
/// margin (BENCHMARKS.md measures the engine's time).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn border_flip_leaves_honest_bots_converging() {
    let (s, h) = run_attack(Attack::BorderFlip, true).await;
    assert_honest(&s);
    assert!(n(&h, "datagrams_sent") >= 10_000, "{h:?}");
    assert!(h.closed_by_server.is_empty(), "not disconnected: {h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rejected_edits_get_the_hostile_kicked() {
    let (s, h) = run_attack(Attack::RejectedEdits, true).await;
    assert_honest(&s);
    assert!(n(&h, "kicks") >= 1, "{h:?}");
    assert!(h.closed_by_server.get("Kicked").is_some_and(|k| *k >= 1));
    assert!(
        n(&h, "edits_rejected") > 0 && !h.rejected.is_empty(),
        "{h:?}"
    );
    assert_eq!(n(&h, "edits_accepted"), 0, "{h:?}");
}

/// Without a ramp the honest bots join while the flood runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn handshake_flood_leaves_honest_bots_connecting() {
    let (s, h) = run_attack(Attack::HandshakeFlood, false).await;
    assert_honest(&s);
    assert!(
        n(&h, "connections_opened") + n(&h, "connections_refused") > 0,
        "{h:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn far_subscribe_gets_nothing_outside_the_view() {
    let (s, h) = run_attack(Attack::FarSubscribe, true).await;
    assert_honest(&s);
    assert!(n(&h, "subscribes_sent") > 0, "{h:?}");
    assert!(n(&h, "snapshot_requests_sent") > 0, "{h:?}");
    // The map hack fails: nothing beyond the player's own view arrives,
    // and every far request is answered with a refusal.
    assert_eq!(n(&h, "chunks_outside_interest"), 0, "{h:?}");
    assert!(n(&h, "refusals") > 0, "{h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn teleport_by_reconnect_is_refused() {
    let (s, h) = run_attack(Attack::Teleport, true).await;
    assert_honest(&s);
    assert!(n(&h, "jumps") > 0 && n(&h, "edits_accepted") > 0, "{h:?}");
    // The teleport fails: a reconnect resumes from the last validated
    // position, so the far report is refused as too fast and the far edit
    // as out of reach.
    assert_eq!(n(&h, "edits_accepted_beyond_reach"), 0, "{h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_walk_through_a_built_wall_is_refused() {
    let (s, h) = run_attack(Attack::WallWalk, true).await;
    assert_honest(&s);
    assert!(n(&h, "walls_built") > 0 && n(&h, "walks") > 0, "{h:?}");
    // The far side is refused for its path, and the edit only it reaches
    // is out of reach of where the server holds the player.
    assert!(n(&h, "path_blocked") > 0, "{h:?}");
    assert_eq!(n(&h, "edits_accepted_beyond_wall"), 0, "{h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flight_over_a_built_wall_is_refused() {
    let (s, h) = run_attack(Attack::FlyOver, true).await;
    assert_honest(&s);
    assert!(n(&h, "walls_built") > 0 && n(&h, "flights") > 0, "{h:?}");
    // Gravity refuses the way up: the server holds the player at home, so
    // the far side and the edit only it reaches are refused too.
    assert!(n(&h, "too_high") > 0, "{h:?}");
    assert_eq!(n(&h, "edits_accepted_beyond_wall"), 0, "{h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shared_token_holds_one_session() {
    let (s, h) = run_attack(Attack::TokenShare, true).await;
    assert_honest(&s);
    assert!(n(&h, "sessions_opened") >= 2, "{h:?}");
    assert!(n(&h, "sessions_welcomed") >= 1, "{h:?}");
    // One token, one session at a time: each new login replaced the last.
    assert!(n(&h, "max_concurrent_welcomed") <= 1, "{h:?}");
    assert_eq!(n(&h, "edits_accepted_far_apart"), 0, "{h:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_flood_is_slowed_down_not_served() {
    let (s, h) = run_attack(Attack::SubscribeFlood, true).await;
    assert_honest(&s);
    assert!(n(&h, "subscribes_sent") > 100, "{h:?}");
    // Its own subscriptions are legal: it is neither refused nor
    // disconnected, only read as fast as its request tokens allow
    // (`server/tests/net_robustness.rs` times that).
    assert_eq!(n(&h, "refusals"), 0, "{h:?}");
    assert!(h.closed_by_server.is_empty(), "{h:?}");
}
