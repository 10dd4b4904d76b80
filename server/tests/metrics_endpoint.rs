//! The Prometheus endpoint of a real server process reports connections,
//! sessions, edits by outcome and reason, edit and flush latency, bytes
//! sent, background meshing and QUIC's own traffic.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{Edit, FixedVec3};

#[tokio::test]
async fn metrics_count_what_happened() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        // A free port for the exporter (it takes a fixed address).
        let metrics = free_metrics_addr();
        // Room for 4 background meshes: the other 23 around the player wait
        // in the backlog and are meshed as room frees up.
        let config = format!(
            "{FAST_EDITS}[metrics]\nlisten = \"{metrics}\"\n[engine]\npremesh_inflight = 4\npremesh_threads = 2\n[store]\ncheckpoint_ms = 200\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let health = http_get(metrics, "/healthz");
        assert!(health.starts_with("HTTP/1.1 200"), "{health}");
        assert!(health.ends_with("ready\n"), "{health}");
        let c = process_client(&data, addr, "ana").await;
        let g = Generator::fractal(GenParams::default()).unwrap();
        let (x, z) = (70, 40);
        let y = g.surface_height(x, z);
        c.send_position(at(x as f64, y + 1.0, z as f64)).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let near = Edit::Mine {
            center: FixedVec3::from_voxels(x, y.floor() as i32, z),
            radius: r(2.0),
            strength: 255,
        };
        assert!(matches!(
            c.edit(near).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        let far = Edit::Mine {
            center: FixedVec3::from_voxels(x + 50, y.floor() as i32, z),
            radius: r(2.0),
            strength: 255,
        };
        assert!(matches!(c.edit(far).await.unwrap(), Verdict::Rejected(_)));
        let text = scrape(metrics);
        for needle in [
            "strata_connections 1",
            "strata_sessions_total 1",
            "strata_edit_latency_seconds_count 1",
            // Both edits, the refused one too, went through the engine's inbox.
            "strata_edit_inbox_seconds_count 2",
            "strata_edits_accepted_total 1",
            "strata_edits_rejected_total{reason=\"reach\"} 1",
            "strata_flush_seconds",
            "strata_bytes_sent_total",
            "strata_sequencer_queue_depth",
            // One session: its batch is queued by the engine thread.
            "strata_fanout_batches_total{how=\"queued\"} 1",
        ] {
            assert!(text.contains(needle), "{needle:?} missing from:\n{text}");
        }
        // The accepted edit's group commit: its log page and the chunk.
        let commit = metric(&text, "strata_store_bytes_total{kind=\"commit\"}");
        assert!(
            matches!(commit, Some(n) if (16.0..65_536.0).contains(&n)),
            "{commit:?} commit bytes:\n{text}"
        );
        // The chunks around the player were meshed in the background.
        let deadline = std::time::Instant::now() + Duration::from_secs(20);
        let premeshed = loop {
            let text = scrape(metrics);
            match metric(&text, "strata_premesh_meshes_total") {
                Some(n) if n >= 20.0 => break n,
                _ if std::time::Instant::now() > deadline => panic!("no premeshing:\n{text}"),
                _ => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        };
        assert!(premeshed <= 27.0 + 2.0, "{premeshed} meshes for one player");
        // The first edit of a chunk stores its whole record; a second one
        // stores a delta, which a checkpoint folds into that record.
        let again = Edit::Mine {
            center: FixedVec3::from_voxels(x + 2, y.floor() as i32, z),
            radius: r(2.0),
            strength: 255,
        };
        assert!(matches!(
            c.edit(again).await.unwrap(),
            Verdict::Accepted { .. }
        ));
        let checkpoint = "strata_store_bytes_total{kind=\"checkpoint\"}";
        let folded = wait_for_metric(metrics, checkpoint, 1.0).await;
        // One or two chunks, compressed.
        assert!(folded < 2.0 * 65_536.0, "{folded} checkpoint bytes");
        // Those meshes read the 5x5x5 chunks around the player, each generated
        // once at most (the two mesher threads share a cache that holds
        // thousands); the rest of their reads hit.
        let text = scrape(metrics);
        let generated = "strata_generated_chunks_total{cache=\"premesh\",outcome=\"generated\"}";
        let hits = "strata_generated_chunks_total{cache=\"premesh\",outcome=\"hit\"}";
        let (generated, hits) = (metric(&text, generated), metric(&text, hits));
        assert!(
            matches!(generated, Some(n) if (1.0..=125.0).contains(&n)),
            "{generated:?} generated:\n{text}"
        );
        assert!(
            matches!((generated, hits), (Some(g), Some(h)) if h >= 4.0 * g),
            "{hits:?} hits for {generated:?} generated"
        );
        // Transport counters: read while the connection is open (every
        // 5 s), and once more when it closes.
        let sent = "strata_udp_datagrams_total{direction=\"sent\"}";
        let received = "strata_udp_datagrams_total{direction=\"received\"}";
        let open = wait_for_metric(metrics, received, 1.0).await;
        c.close().await;
        let closed = wait_for_metric(metrics, received, open + 1.0).await;
        let text = scrape(metrics);
        let datagrams = metric(&text, sent).expect("datagrams sent");
        let bytes = metric(&text, "strata_udp_bytes_total{direction=\"sent\"}").unwrap();
        let app_bytes = metric(&text, "strata_bytes_sent_total").unwrap();
        // The welcome, the snapshots around the player, two verdicts.
        assert!(datagrams >= 10.0, "{datagrams} datagrams sent");
        // QUIC's headers and ACKs come on top of what the writers sent.
        assert!(
            bytes > app_bytes,
            "{bytes} UDP bytes for {app_bytes} written"
        );
        assert!(
            bytes <= datagrams * 1500.0,
            "{bytes} bytes in {datagrams} datagrams"
        );
        let in_bytes = metric(&text, "strata_udp_bytes_total{direction=\"received\"}").unwrap();
        assert!(
            in_bytes >= closed * 20.0,
            "{in_bytes} bytes in {closed} datagrams"
        );
        assert_eq!(metric(&text, "strata_quic_lost_packets_total"), Some(0.0));
        let rtts = metric(&text, "strata_quic_rtt_seconds_count").unwrap_or(0.0);
        assert!(rtts >= 1.0, "{rtts} RTT readings:\n{text}");
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A client sending position datagrams as fast as it can gets no more of
/// them to the engine than its `[validation.position_rate]`: its session
/// task drops the rest, counts them, and the session goes on.
#[tokio::test]
async fn a_position_flood_stops_at_the_sessions_bucket() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        let config = format!(
            "{FAST_EDITS}[validation.position_rate]\ncapacity = 5\nper_second = 10\n[metrics]\nlisten = \"{metrics}\"\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let c = process_client(&data, addr, "ana").await;
        let g = Generator::fractal(GenParams::default()).unwrap();
        let (x, z) = (70, 40);
        let feet = at(x as f64, g.surface_height(x, z) + 1.0, z as f64);
        // A report a millisecond, so that most find the engine done with
        // the one before (one arriving while another waits replaces it).
        const FLOOD: usize = 400;
        for _ in 0..FLOOD {
            c.send_position(feet).unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        // The burst and about a second's refill reach the engine; every
        // other report that would queue a command is dropped.
        let dropped = "strata_positions_dropped_total{reason=\"rate\"}";
        let n = wait_for_metric(metrics, dropped, (FLOOD / 4) as f64).await;
        assert!(n <= FLOOD as f64, "{n} dropped of {FLOOD}");
        let text = scrape(metrics);
        assert_eq!(
            metric(&text, "strata_positions_dropped_total{reason=\"queue_full\"}"),
            None
        );
        c.ping(1).await.unwrap();
        assert!(!c.is_closed(), "the flood cost the session nothing else");
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A player with no position yet claiming spot after spot in the bedrock
/// floor of the spawn square (each claim loads or generates the chunks
/// around it, then is refused as inside solid) is held to its
/// `[validation.placement_rate]`: the rest are dropped before anything is
/// loaded, and counted; the session goes on and can still place itself.
#[tokio::test]
async fn placements_past_the_players_bucket_are_dropped_before_loading() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let metrics = free_metrics_addr();
        let config = format!(
            "{FAST_EDITS}[validation.placement_rate]\ncapacity = 4\nper_second = 1\n[metrics]\nlisten = \"{metrics}\"\n"
        );
        let (mut child, addr) = spawn_server(&data, &config);
        let c = process_client(&data, addr, "mole").await;
        let g = Generator::fractal(GenParams::default()).unwrap();
        const CLAIMS: i32 = 40;
        // In the bedrock floor (the lowest three layers), which no cave
        // reaches: every claim that loads is refused as inside solid.
        let floor = strata_terrain::gen::GenParams::default().min_y as f64 + 0.5;
        for i in 0..CLAIMS {
            let (x, z) = (100 + 37 * i, -300 + 53 * i);
            c.send_position(at(x as f64, floor, z as f64)).unwrap();
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let dropped = "strata_positions_dropped_total{reason=\"placement\"}";
        let n = wait_for_metric(metrics, dropped, (CLAIMS / 2) as f64).await;
        assert!(n < CLAIMS as f64, "{n} dropped of {CLAIMS}");
        // Placing itself at the surface works once a token is back.
        let (x, z) = (70, 40);
        let feet = at(x as f64, g.surface_height(x, z) + 1.0, z as f64);
        tokio::time::sleep(Duration::from_millis(1100)).await;
        c.send_position(feet).unwrap();
        let chunk = strata_terrain::VoxelPos::new(x, g.surface_height(x, z) as i32, z).chunk();
        let started = std::time::Instant::now();
        while c.replica().get(chunk).is_none() {
            assert!(started.elapsed() < Duration::from_secs(10), "never placed");
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(!c.is_closed());
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Polls the metrics at `addr` until `name` is at least `at_least`
/// (20 s at most); returns its value.
async fn wait_for_metric(addr: std::net::SocketAddr, name: &str, at_least: f64) -> f64 {
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    loop {
        let text = scrape(addr);
        match metric(&text, name) {
            Some(n) if n >= at_least => return n,
            _ if std::time::Instant::now() > deadline => {
                panic!("{name} never reached {at_least}:\n{text}")
            }
            _ => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

/// The engine reports each tick it finishes to the server's health, which
/// says not ready once none finished for `ENGINE_STALL` (the rule: unit
/// test in `health.rs`); a refused login is counted by reason.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_engine_reports_its_ticks_and_refusals_are_counted() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let health = server.health();
        let fresh = || {
            health
                .since_tick()
                .is_some_and(|d| d < Duration::from_secs(1))
        };
        let started = std::time::Instant::now();
        while !fresh() {
            assert!(
                started.elapsed() < Duration::from_secs(5),
                "no tick reported"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert_eq!(health.check(), Ok(()));

        let refused = |reason: &str| {
            let text = strata_server::metrics::shared().unwrap().render();
            let line = format!("strata_connections_refused_total{{reason=\"{reason}\"}} ");
            text.lines()
                .find_map(|l| l.strip_prefix(&line))
                .map_or(0.0, |v| v.trim().parse::<f64>().unwrap())
        };
        let before = refused("bad_token");
        let bad = strata_client_sim::Client::connect(server.addr, &server.cert_der, "not a token");
        assert!(bad.await.is_err());
        assert!(refused("bad_token") >= before + 1.0);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}
