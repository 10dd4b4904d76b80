//! Bad input closes only the offending connection; a client that stops
//! reading loses deltas instead of slowing anyone down; refused positions
//! are answered, at a bounded rate however many come; a player's requests,
//! edits included, wait for its request tokens, across reconnects.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, ClientError, Verdict};
use strata_protocol::io::FramedReader;
use strata_protocol::limits::MAX_CLIENT_FRAME;
use strata_protocol::{
    encode_frame, ClientMessage, Direction, EditRequest, ErrorCode, FrameBuffer, Hello,
    PositionRefusal, PositionUpdate, RejectReason, Role, ServerMessage, PROTOCOL_VERSION,
};
use strata_server::app;
use strata_server::net::session::EDIT_COST;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{Edit, FixedVec3};

async fn expect_closed_with(c: strata_client_sim::Client, want: ErrorCode) {
    match tokio::time::timeout(Duration::from_secs(10), c.closed())
        .await
        .expect("server closes the connection")
    {
        ClientError::Refused { code, .. } => assert_eq!(code, want),
        e => panic!("expected {want:?}, got {e}"),
    }
}

#[tokio::test]
async fn malformed_oversized_and_garbage_frames_close_only_their_connection() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let good = connect(&server, "good", Role::Player).await;

        let garbage = connect(&server, "g1", Role::Player).await;
        garbage
            .send_raw(vec![5, 0, 0, 0, 0xff, 0xfe, 0xfd, 0xfc, 0xfb])
            .await
            .unwrap();
        expect_closed_with(garbage, ErrorCode::Malformed).await;

        let big = connect(&server, "g2", Role::Player).await;
        big.send_raw(((MAX_CLIENT_FRAME + 1) as u32).to_le_bytes().to_vec())
            .await
            .unwrap();
        expect_closed_with(big, ErrorCode::FrameTooLarge).await;

        let again = connect(&server, "g3", Role::Player).await;
        let hello = ClientMessage::Hello(Hello {
            protocol_version: PROTOCOL_VERSION,
            token: "x".into(),
            capabilities: 0,
        });
        again
            .send_raw(encode_frame(&hello, Direction::ClientToServer).unwrap())
            .await
            .unwrap();
        expect_closed_with(again, ErrorCode::Malformed).await;

        let empty = connect(&server, "g4", Role::Player).await;
        empty.send_raw(vec![0, 0, 0, 0]).await.unwrap();
        expect_closed_with(empty, ErrorCode::Malformed).await;

        // Garbage datagrams are dropped; the session lives on.
        let raw = raw_session(&server, "g5").await;
        for junk in [vec![0xffu8; 9], vec![0u8; 3], vec![7u8; 600]] {
            raw.conn.send_datagram(junk.into()).unwrap();
        }
        // The good client never noticed any of it: its edit gets the exact
        // verdict it should (it never sent a position).
        good.ping(7).await.unwrap();
        let edit = Edit::Mine {
            center: FixedVec3::from_voxels(70, 0, 40),
            radius: r(2.0),
            strength: 255,
        };
        assert_eq!(
            good.edit(edit).await.unwrap(),
            Verdict::Rejected(RejectReason::NoPosition)
        );
        assert!(!good.is_closed());
        assert!(
            raw.conn.close_reason().is_none(),
            "{:?}",
            raw.conn.close_reason()
        );
        drop(raw);
        good.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A raw session that has said Hello but reads nothing: its receive window
/// is 1 KiB per stream, so the server's writers soon block on it.
struct RawSession {
    _endpoint: quinn::Endpoint,
    conn: quinn::Connection,
    send: quinn::SendStream,
    _recv: quinn::RecvStream,
}

async fn raw_session(server: &app::Running, player: &str) -> RawSession {
    raw_session_window(server, player, 1024).await
}

/// [`raw_session`] with `window` bytes of credit per stream (0: the server
/// can send nothing, not even a refusal).
async fn raw_session_window(server: &app::Running, player: &str, window: u32) -> RawSession {
    let cfg = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
    let (endpoint, conn) = connect_small_window(server.addr, cfg, window).await;
    let (mut send, recv) = conn.open_bi().await.unwrap();
    let hello = ClientMessage::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        token: token(server, player, Role::Player),
        capabilities: 0,
    });
    send.write_all(&encode_frame(&hello, Direction::ClientToServer).unwrap())
        .await
        .unwrap();
    RawSession {
        _endpoint: endpoint,
        conn,
        send,
        _recv: recv,
    }
}

#[tokio::test]
async fn a_stalled_client_does_not_delay_the_others() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.net.writer_queue = 8;
        cfg.validation.edit_rate.per_second = 1000;
        cfg.validation.edit_rate.capacity = 1000;
        let server = app::start(cfg).await.unwrap();
        let g = Generator::fractal(GenParams::default()).unwrap();
        let (x, z) = (70, 40);
        let y = g.surface_height(x, z);
        let feet = at(x as f64, y + 1.0, z as f64);
        let stalled = raw_session(&server, "slow").await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        let pos = strata_protocol::encode(
            &PositionUpdate { seq: 1, pos: feet },
            Direction::ClientToServer,
        )
        .unwrap();
        stalled.conn.send_datagram(pos.into()).unwrap();
        let a = connect(&server, "ana", Role::Player).await;
        let b = connect(&server, "bo", Role::Player).await;
        a.send_position(feet).unwrap();
        b.send_position(feet).unwrap();
        let target = strata_terrain::VoxelPos::new(x, y.floor() as i32, z).chunk();
        assert!(
            eventually(Duration::from_secs(10), || b
                .replica()
                .get(target)
                .is_some())
            .await
        );
        let mut last = 0;
        for i in 0..40 {
            let edit = Edit::Build {
                center: FixedVec3::from_voxels(
                    x + (i % 5) - 2,
                    y.floor() as i32 + 2,
                    z + (i / 5) % 5 - 2,
                ),
                radius: r(1.5),
                material: 7,
                strength: 40,
            };
            match a.edit(edit).await.unwrap() {
                Verdict::Accepted { seq } => last = seq,
                v => panic!("edit {i} refused: {v:?}"),
            }
        }
        assert!(
            eventually(Duration::from_secs(10), || b.replica().last_seq() >= last).await,
            "b saw every tick"
        );
        // Had the stalled writer blocked the engine, no ack would arrive and
        // the test would hit its timeout instead.
        assert_eq!(b.replica().stats.gaps, 0);
        // And the stalled client was still connected throughout: it fell
        // behind, it was not dropped.
        assert!(
            stalled.conn.close_reason().is_none(),
            "{:?}",
            stalled.conn.close_reason()
        );
        assert_eq!(live_sessions(&server).await, 3);
        drop(stalled);
        a.close().await;
        b.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_client_that_never_reads_its_verdicts_is_disconnected() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Refusals without limit, so the control queue overflows first; a
        // queue of 16 (`[net] control_writer_queue`) overflows within 400
        // verdicts, which the default of 1024 would hold.
        let mut cfg = test_config(dir.path());
        cfg.validation.reject_rate.capacity = u64::MAX / 2000;
        cfg.net.control_writer_queue = 16;
        let server = app::start(cfg).await.expect("server starts");
        let good = connect(&server, "good", Role::Player).await;
        // No reading: verdicts pile up in the server's bounded control queue
        // until it overflows.
        // Its receive streams stay open: dropped, they would stop the
        // server's writers (a different way to fail).
        let RawSession {
            conn,
            mut send,
            _recv,
            _endpoint,
        } = raw_session(&server, "flood").await;
        let flood = async {
            // Refused at once (no position yet), each answered by a verdict.
            for id in 0..400u64 {
                let edit = Edit::Mine {
                    center: FixedVec3::from_voxels(0, 0, 0),
                    radius: r(1.0),
                    strength: 1,
                };
                let msg = ClientMessage::Edit(strata_protocol::EditRequest {
                    client_edit_id: id,
                    edit,
                });
                if send
                    .write_all(&encode_frame(&msg, Direction::ClientToServer).unwrap())
                    .await
                    .is_err()
                {
                    return;
                }
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(30), flood).await;
        let reason = tokio::time::timeout(Duration::from_secs(10), conn.closed())
            .await
            .expect("server closes the flooder");
        match reason {
            quinn::ConnectionError::ApplicationClosed(a) => {
                assert_eq!(
                    ErrorCode::from_close_code(a.error_code.into_inner()),
                    Some(ErrorCode::Internal),
                    "{a:?}"
                );
            }
            other => panic!("expected an application close, got {other}"),
        }
        // Everyone else is fine.
        good.ping(1).await.unwrap();
        assert!(!good.is_closed());
        good.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_player_whose_edits_keep_being_refused_is_disconnected() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.validation.reject_rate.capacity = 20;
        let server = app::start(cfg).await.expect("server starts");
        let good = connect(&server, "good", Role::Player).await;
        let bad = connect(&server, "bad", Role::Player).await;
        // Refused at once: no position yet.
        let edit = Edit::Mine {
            center: FixedVec3::from_voxels(0, 0, 0),
            radius: r(1.0),
            strength: 1,
        };
        let mut refused = 0;
        for _ in 0..40 {
            match bad.edit(edit.clone()).await {
                Ok(Verdict::Rejected(_)) => refused += 1,
                Ok(v) => panic!("unexpected verdict {v:?}"),
                Err(_) => break,
            }
        }
        assert!(
            (20..40).contains(&refused),
            "{refused} refusals before the kick"
        );
        expect_closed_with(bad, ErrorCode::Kicked).await;
        good.ping(1).await.unwrap();
        assert!(!good.is_closed());
        good.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_session_end_reaches_a_busy_engine_and_its_tasks_end() {
    tokio::time::timeout(TEST_TIMEOUT * 2, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        // One slot for players' commands: flooders keep it full.
        cfg.engine.command_queue = 1;
        let server = app::start(cfg).await.expect("server starts");
        let metrics = tokio::runtime::Handle::current().metrics();
        let idle_tasks = metrics.num_alive_tasks();
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut flooders = Vec::new();
        for f in 0..4 {
            let mut raw = raw_session(&server, &format!("flood{f}")).await;
            let stop = stop.clone();
            flooders.push(tokio::spawn(async move {
                for i in 0..200_000i32 {
                    if stop.load(std::sync::atomic::Ordering::Relaxed) {
                        break;
                    }
                    let center = strata_terrain::ChunkPos::new(i % 2 * 50, 0, f * 50);
                    let msg = ClientMessage::Subscribe { center, radius: 2 };
                    let frame = encode_frame(&msg, Direction::ClientToServer).unwrap();
                    if raw.send.write_all(&frame).await.is_err() {
                        break;
                    }
                }
                raw.conn.close(0u32.into(), b"done");
            }));
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        let mut joined = 0;
        for round in 0..10 {
            let mut batch = tokio::task::JoinSet::new();
            for i in 0..20 {
                let (addr, cert) = (server.addr, server.cert_der.clone());
                let token = token(&server, &format!("p{round}-{i}"), Role::Player);
                batch.spawn(async move {
                    match Client::connect(addr, &cert, &token).await {
                        Ok(c) => {
                            c.close().await;
                            1
                        }
                        Err(_) => 0,
                    }
                });
            }
            while let Some(r) = batch.join_next().await {
                joined += r.unwrap();
            }
        }
        assert!(joined >= 150, "{joined} of 200 sessions joined");
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for f in flooders {
            f.await.unwrap();
        }
        // Every leave arrives; the engine forgets every peer.
        let mut sessions = u32::MAX;
        for _ in 0..100 {
            sessions = live_sessions(&server).await;
            if sessions == 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert_eq!(sessions, 0, "sessions left behind");
        // And every task of those sessions ended.
        let mut tasks = usize::MAX;
        for _ in 0..100 {
            tasks = metrics.num_alive_tasks();
            if tasks <= idle_tasks {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert!(
            tasks <= idle_tasks,
            "{tasks} tasks alive, {idle_tasks} before any session"
        );
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Refused-position notices taken from `c`: the report, why, and where
/// the server holds the player.
fn refused(c: &Client) -> Vec<(u32, PositionRefusal, Option<FixedVec3>)> {
    std::iter::from_fn(|| c.pop_notice())
        .filter_map(|n| match n {
            strata_client_sim::Notice::PositionRefused { seq, reason, at } => {
                Some((seq, reason, at))
            }
            _ => None,
        })
        .collect()
}

#[tokio::test]
async fn refused_positions_are_answered_at_a_bounded_rate() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.validation.position_refusal_ms = 400;
        let server = app::start(cfg).await.expect("server starts");
        let c = connect(&server, "lost", Role::Player).await;
        let outside = at(100_000.0, 40.0, 0.0);
        c.send_position(outside).unwrap();
        let mut got = Vec::new();
        assert!(
            eventually(Duration::from_secs(5), || {
                got.extend(refused(&c));
                !got.is_empty()
            })
            .await
        );
        let spawn = PositionRefusal::OutsideSpawn {
            x: 0,
            z: 0,
            radius: 2048,
        };
        assert_eq!(got, vec![(1, spawn, None)], "no position held yet");
        // A flood of 3000 bad reports over about 0.6 s.
        let started = std::time::Instant::now();
        for _ in 0..60 {
            for _ in 0..50 {
                let _ = c.send_position(outside);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        let flood = refused(&c);
        let most = started.elapsed().as_millis() as usize / 400 + 2;
        assert!(
            !flood.is_empty() && flood.len() <= most,
            "{} answers to 3000 refused reports (at most {most})",
            flood.len()
        );
        assert!(flood.iter().all(|(_, r, _)| *r == spawn));
        c.ping(1).await.unwrap();
        assert!(!c.is_closed(), "the flood cost the session nothing");
        // A legal position, then a jump far too fast for the time since.
        let (feet, _) = spot(10, 10);
        c.send_position(feet).unwrap();
        assert!(eventually(Duration::from_secs(10), || c.view_loaded().is_some()).await);
        tokio::time::sleep(Duration::from_millis(450)).await;
        let mut jump = feet;
        jump.x = strata_terrain::Fixed::from_voxels(10 + 500);
        c.send_position(jump).unwrap();
        let mut late = Vec::new();
        assert!(
            eventually(Duration::from_secs(5), || {
                late.extend(refused(&c));
                !late.is_empty()
            })
            .await
        );
        assert!(
            matches!(late[..], [(_, PositionRefusal::TooFast { distance, allowed }, Some(at))]
                if distance > allowed && at == feet),
            "{late:?}: told where it stands"
        );
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_sessions_requests_wait_for_its_request_tokens() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // 100 chunks of requests a second and no more at once: a
        // subscription to the whole view (radius 2 here, 125 chunks, capped
        // at the burst) takes the whole bucket.
        let mut cfg = test_config(dir.path());
        cfg.interest.view_radius = 2;
        cfg.validation.request_rate.capacity = 100;
        cfg.validation.request_rate.per_second = 100;
        let server = app::start(cfg).await.expect("server starts");
        let calm = connect(&server, "calm", Role::Player).await;
        let RawSession {
            conn,
            mut send,
            _recv,
            _endpoint,
        } = raw_session(&server, "flood").await;
        let mut reader = FramedReader::new(_recv, FrameBuffer::new(Direction::ServerToClient));
        match reader.next::<ServerMessage>().await {
            Ok(Some(ServerMessage::Welcome(_))) => {}
            other => panic!("expected Welcome, got {other:?}"),
        }
        // A view that flips between two radii unsubscribes nothing and
        // so costs the server a full walk of the view each time: the
        // cheapest way to keep an engine busy, without limits.
        let mut frames = Vec::new();
        for i in 0..5u8 {
            let sub = ClientMessage::Subscribe {
                center: strata_terrain::ChunkPos::new(0, 0, 0),
                radius: 2 - i % 2,
            };
            frames.extend(encode_frame(&sub, Direction::ClientToServer).unwrap());
        }
        frames.extend(
            encode_frame(&ClientMessage::Ping { nonce: 7 }, Direction::ClientToServer).unwrap(),
        );
        let sent = std::time::Instant::now();
        send.write_all(&frames).await.unwrap();
        // Meanwhile the others are served as usual.
        calm.ping(1).await.unwrap();
        loop {
            match reader.next::<ServerMessage>().await {
                Ok(Some(ServerMessage::Pong { nonce: 7, .. })) => break,
                Ok(Some(_)) => continue,
                other => panic!("expected the Pong, got {other:?}"),
            }
        }
        // The ping waited behind the subscriptions: radius 2 takes the
        // bucket (100), radius 1 needs 27 (0.27 s), radius 2 again 100 (1 s):
        // 2.54 s for the five.
        let waited = sent.elapsed();
        assert!(waited >= Duration::from_millis(2_500), "{waited:?}");
        // Slowed down, not disconnected.
        assert!(conn.close_reason().is_none(), "{:?}", conn.close_reason());
        assert!(!calm.is_closed());
        calm.close().await;
        drop(send);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// `strata_requests_throttled_total` in this process's registry (shared
/// by every test here: compare before and after, never absolutely).
fn requests_throttled() -> f64 {
    let text = strata_server::metrics::shared().unwrap().render();
    metric(&text, strata_server::metrics::REQUESTS_THROTTLED).unwrap_or(0.0)
}

/// A raw session of `player` past its `Welcome`: its connection, control
/// stream and a reader of the server's control frames.
async fn welcomed(
    server: &app::Running,
    player: &str,
) -> (
    quinn::Endpoint,
    quinn::Connection,
    quinn::SendStream,
    FramedReader<quinn::RecvStream>,
) {
    let RawSession {
        _endpoint,
        conn,
        send,
        _recv,
    } = raw_session(server, player).await;
    let mut reader = FramedReader::new(_recv, FrameBuffer::new(Direction::ServerToClient));
    match reader.next::<ServerMessage>().await {
        Ok(Some(ServerMessage::Welcome(_))) => {}
        other => panic!("expected Welcome, got {other:?}"),
    }
    (_endpoint, conn, send, reader)
}

fn pings(n: u64) -> Vec<u8> {
    (0..n)
        .flat_map(|nonce| {
            encode_frame(&ClientMessage::Ping { nonce }, Direction::ClientToServer).unwrap()
        })
        .collect()
}

#[tokio::test]
async fn edits_wait_for_request_tokens_too() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let before = requests_throttled();
        let dir = tempfile::tempdir().unwrap();
        // Ten edits at once (8 tokens each), ten a second.
        let mut cfg = test_config(dir.path());
        cfg.validation.request_rate.capacity = 10 * EDIT_COST;
        cfg.validation.request_rate.per_second = 10 * EDIT_COST;
        let server = app::start(cfg).await.expect("server starts");
        let (_endpoint, conn, mut send, mut reader) = welcomed(&server, "flood").await;
        // Forty edits, refused for want of a position or past the edit rate
        // (within the default 100 refusals before a kick), then a ping.
        const EDITS: u64 = 40;
        let mut frames = Vec::new();
        for id in 0..EDITS {
            let edit = ClientMessage::Edit(EditRequest {
                client_edit_id: id,
                edit: Edit::Mine {
                    center: FixedVec3::from_voxels(70, 0, 40),
                    radius: r(1.0),
                    strength: 1,
                },
            });
            frames.extend(encode_frame(&edit, Direction::ClientToServer).unwrap());
        }
        frames.extend(
            encode_frame(
                &ClientMessage::Ping { nonce: 77 },
                Direction::ClientToServer,
            )
            .unwrap(),
        );
        let sent = std::time::Instant::now();
        send.write_all(&frames).await.unwrap();
        let (mut answered, mut ponged) = (0, false);
        while answered < EDITS || !ponged {
            match reader.next::<ServerMessage>().await {
                Ok(Some(ServerMessage::EditRejected { reason, .. })) => {
                    assert!(
                        matches!(reason, RejectReason::NoPosition | RejectReason::RateLimited),
                        "{reason:?}"
                    );
                    answered += 1;
                }
                Ok(Some(ServerMessage::Pong { nonce: 77, .. })) => ponged = true,
                Ok(Some(_)) => continue,
                other => panic!("expected verdicts and the Pong, got {other:?}"),
            }
        }
        // 40 edits and a ping, ten edits' tokens at once and ten edits' a
        // second: 3.0 s at the least.
        let waited = sent.elapsed();
        assert!(waited >= Duration::from_millis(2_500), "{waited:?}");
        assert!(requests_throttled() > before, "the waits were counted");
        // Slowed down, not disconnected.
        assert!(conn.close_reason().is_none(), "{:?}", conn.close_reason());
        drop(send);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn reconnecting_does_not_refill_the_request_bucket() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // Twenty requests at once, one a second.
        const BURST: u64 = 20;
        let mut cfg = test_config(dir.path());
        cfg.validation.request_rate.capacity = BURST;
        cfg.validation.request_rate.per_second = 1;
        let server = app::start(cfg).await.expect("server starts");
        // The first connection spends the whole burst.
        let (_first_endpoint, first, mut send, mut reader) = welcomed(&server, "again").await;
        send.write_all(&pings(BURST)).await.unwrap();
        for _ in 0..BURST {
            match reader.next::<ServerMessage>().await {
                Ok(Some(ServerMessage::Pong { .. })) => {}
                other => panic!("expected a Pong, got {other:?}"),
            }
        }
        first.close(0u32.into(), b"bye");
        drop((send, reader));
        // The same player again: as many pings find the bucket as the first
        // connection left it, refilling at one a second.
        let before = requests_throttled();
        let (_endpoint, conn, mut send, mut reader) = welcomed(&server, "again").await;
        send.write_all(&pings(BURST)).await.unwrap();
        let window = tokio::time::Instant::now() + Duration::from_secs(2);
        let mut pongs = 0;
        while let Ok(msg) = tokio::time::timeout_at(window, reader.next::<ServerMessage>()).await {
            match msg {
                Ok(Some(ServerMessage::Pong { .. })) => pongs += 1,
                Ok(Some(_)) => continue,
                other => panic!("expected Pongs, got {other:?}"),
            }
        }
        assert!(pongs < BURST, "{pongs} of {BURST} pings answered at once");
        assert!(requests_throttled() > before, "the waits were counted");
        assert!(conn.close_reason().is_none(), "{:?}", conn.close_reason());
        drop(send);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A server with one player slot, where a player logs in once.
async fn one_slot_one_login(dir: &std::path::Path) -> app::Running {
    let mut cfg = test_config(dir);
    cfg.server.max_connections = 1;
    cfg.validation.join_rate.capacity = 1;
    cfg.validation.join_rate.per_second = 0;
    app::start(cfg).await.unwrap()
}

/// Waits until no session is live.
async fn no_sessions(server: &app::Running) {
    while live_sessions(server).await > 0 {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// A player past its logins is refused before it takes a session slot: a
/// client that gives no credit for the refusal holds its connection for
/// the drain, and another player still gets the only slot meanwhile.
#[tokio::test]
async fn a_login_refused_for_its_rate_holds_no_session_slot() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = one_slot_one_login(dir.path()).await;
        let first = connect(&server, "ana", Role::Player).await;
        first.close().await;
        no_sessions(&server).await;
        // Ana's second login: refused for its rate, the refusal undelivered.
        let stalled = raw_session_window(&server, "ana", 0).await;
        tokio::time::sleep(Duration::from_millis(200)).await;
        let bo = Client::connect(
            server.addr,
            &server.cert_der,
            &token(&server, "bo", Role::Player),
        )
        .await;
        assert!(bo.is_ok(), "the only slot was held: {:?}", bo.err());
        drop(stalled);
        bo.unwrap().close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// The protocol has no client-opened unidirectional streams, and the
/// server grants none: such a stream never opens, so it holds no unread
/// data on the server.
#[tokio::test]
async fn a_client_gets_no_unidirectional_streams() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = app::start(test_config(dir.path())).await.unwrap();
        let raw = raw_session(&server, "ana").await;
        let opened = tokio::time::timeout(Duration::from_millis(500), raw.conn.open_uni()).await;
        assert!(opened.is_err(), "a uni stream opened");
        drop(raw);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// Connections that finish TLS and never say Hello, from four addresses,
/// hold every handshake slot: a player from a fifth address still gets in,
/// taking the oldest one's slot, and that connection is closed.
#[tokio::test]
async fn a_player_gets_in_while_silent_connections_hold_every_handshake_slot() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.server.max_handshakes = 4;
        cfg.server.max_handshakes_per_address = 1;
        cfg.server.retry_above_handshakes = 4;
        // Evictable after half of it: 2 s.
        cfg.server.handshake_timeout_ms = 4_000;
        let server = app::start(cfg).await.unwrap();
        let tls = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
        let mut silent = Vec::new();
        for n in 2..=5u8 {
            let from = std::net::SocketAddr::from(([127, 0, 0, n], 0));
            let mut endpoint = quinn::Endpoint::client(from).unwrap();
            endpoint.set_default_client_config(tls.clone());
            let conn = endpoint
                .connect(server.addr, "localhost")
                .unwrap()
                .await
                .unwrap();
            silent.push((endpoint, conn));
        }
        // Slots held this long may be taken.
        tokio::time::sleep(Duration::from_millis(2_300)).await;
        let ana = connect(&server, "ana", Role::Player).await;
        let oldest = &silent[0].1;
        let closed = tokio::time::timeout(Duration::from_secs(5), oldest.closed()).await;
        let code = strata_protocol::ErrorCode::TooManyConnections.close_code();
        assert!(
            matches!(&closed, Ok(quinn::ConnectionError::ApplicationClosed(c)) if c.error_code == quinn::VarInt::from_u32(code)),
            "{closed:?}"
        );
        assert!(
            silent[3].1.close_reason().is_none(),
            "the newest kept its slot"
        );
        ana.close().await;
        drop(silent);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

/// A login refused because the server is full costs the player none of
/// its logins: once a slot frees, it gets in.
#[tokio::test]
async fn a_login_refused_for_a_full_server_spends_no_login() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = one_slot_one_login(dir.path()).await;
        let bo = connect(&server, "bo", Role::Player).await;
        let ana = || async {
            Client::connect(
                server.addr,
                &server.cert_der,
                &token(&server, "ana", Role::Player),
            )
            .await
        };
        for _ in 0..3 {
            assert!(ana().await.is_err(), "the server is full");
        }
        bo.close().await;
        no_sessions(&server).await;
        let ana = ana().await;
        assert!(ana.is_ok(), "{:?}", ana.err());
        ana.unwrap().close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
