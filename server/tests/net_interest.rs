//! Interest: a prompt client at view radius 8 that re-centres its
//! subscription is told which chunks left in a few frames, not thousands,
//! and stays connected; a player cannot subscribe or ask for chunks far
//! from itself (map hack), even before its first position, and each
//! refusal is answered; its own view never reaches past radius plus
//! hysteresis from where it stands, walking away included. Each view ends
//! with `InterestComplete`, after a re-centre the whole queue is nearest
//! first from the new centre, and a forgotten chunk gets no updates until
//! it is asked for again.

use crate::common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::*;
use strata_client_sim::bots::raw_session::RawSession;
use strata_client_sim::{Client, Verdict};
use strata_protocol::limits::MAX_FORGET_CHUNKS;
use strata_protocol::{encode_frame, ClientMessage, Direction, Refusal, Role, WorldUpdate};
use strata_server::app;
use strata_server::interest::nearest_first;
use strata_terrain::{ChunkPos, Edit};

/// The chunks a view covers at the test world's default bounds (rows -4..=7).
fn view(c: ChunkPos, r: i32) -> Vec<ChunkPos> {
    let mut v = Vec::new();
    for z in -r..=r {
        for y in (c.y - r).max(-4)..=(c.y + r).min(7) {
            for x in -r..=r {
                v.push(ChunkPos::new(c.x + x, y, c.z + z));
            }
        }
    }
    v
}

/// Waits until the client's last `InterestComplete` names `center`, `radius`.
async fn loaded(c: &Client, center: ChunkPos, radius: u8) {
    assert!(
        eventually(Duration::from_secs(10), || c.view_loaded()
            == Some((center, radius)))
        .await,
        "no InterestComplete for {center:?}: {:?}",
        c.view_loaded()
    );
}

#[tokio::test]
async fn a_far_re_centre_at_view_radius_8_keeps_the_client() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.interest.view_radius = 8;
        let server = app::start(cfg).await.expect("server starts");
        let c = connect(&server, "walker", Role::Player).await;
        // 17³ = 4913 chunks a view; each jump of 10 chunks (allowed: with
        // no position yet the player may look anywhere near the default
        // spawn square, 128 chunks wide) drops 2312 of them, far more than
        // the session's writer queue holds frames.
        for (i, x) in [0, 10, 0, -10].into_iter().enumerate() {
            c.subscribe(ChunkPos::new(x, 0, 0), 8).await.unwrap();
            tokio::time::sleep(Duration::from_millis(300)).await;
            c.ping(i as u64).await.unwrap();
            assert!(!c.is_closed(), "disconnected after jump {i}");
        }
        // What the client holds is only the last view's.
        tokio::time::sleep(Duration::from_millis(300)).await;
        let stale = c.replica().chunks().filter(|(p, _)| p.x > 0).count();
        assert_eq!(stale, 0, "chunks of earlier views were dropped");
        assert!(!c.replica().is_empty(), "the last view is streaming");
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn far_subscriptions_and_snapshot_requests_are_refused() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // View radius 2, hysteresis 2: a view reaches at most 4 chunks
        // from the player, so a radius-2 centre is at most 2 away.
        let server = start(dir.path()).await;
        let c = connect(&server, "spy", Role::Player).await;
        c.subscribe(ChunkPos::new(0, 0, 0), 2).await.unwrap();
        let far = ChunkPos::new(175, 0, 0);
        c.subscribe(far, 2).await.unwrap();
        c.full_snapshot(far).await.unwrap();
        c.resync(ChunkPos::new(-60, 0, 3)).await.unwrap();
        // A near one is fine.
        c.subscribe(ChunkPos::new(4, 0, 0), 2).await.unwrap();
        assert!(
            eventually(Duration::from_secs(5), || c.refusals().len() >= 3).await,
            "{:?}",
            c.refusals()
        );
        assert_eq!(
            c.refusals(),
            vec![
                Refusal::SubscribeTooFar {
                    center: far,
                    max: 2
                },
                Refusal::NotInInterest { pos: far },
                Refusal::NotInInterest {
                    pos: ChunkPos::new(-60, 0, 3)
                },
            ]
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
        let outside = c.replica().chunks().filter(|(p, _)| p.x.abs() > 8).count();
        assert_eq!(outside, 0, "no chunk far from the player was sent");
        assert!(!c.replica().is_empty(), "the near view streams");
        // An admin may look anywhere.
        let admin = connect(&server, "ops", Role::Admin).await;
        admin.subscribe(ChunkPos::new(0, 0, 0), 1).await.unwrap();
        admin.subscribe(far, 1).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(admin.refusals().is_empty());
        c.close().await;
        admin.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_positionless_player_subscribes_only_near_its_start() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        // Spawn square x, z in -16..=16 voxels: chunk columns -1..=0.
        cfg.validation.spawn.radius = 16;
        let server = app::start(cfg).await.expect("server starts");
        let c = connect(&server, "early", Role::Player).await;
        // View radius 2 + hysteresis 2: a view reaches at most 4 chunks
        // from the square, so a radius-2 centre lies at most 2 away.
        let far = ChunkPos::new(175, 0, 0);
        let edge = ChunkPos::new(5, 0, -5);
        let wide = ChunkPos::new(4, 0, 0);
        c.subscribe(far, 2).await.unwrap();
        c.subscribe(edge, 2).await.unwrap();
        c.subscribe(wide, 2).await.unwrap();
        // A smaller view may lie farther. Accepted first subscriptions no
        // longer anchor later ones: the other side of the square is fine.
        c.subscribe(wide, 0).await.unwrap();
        c.subscribe(ChunkPos::new(-3, 3, 2), 2).await.unwrap();
        c.subscribe(ChunkPos::new(0, 0, 0), 2).await.unwrap();
        loaded(&c, ChunkPos::new(0, 0, 0), 2).await;
        let too_far = |center| Refusal::SubscribeTooFar { center, max: 2 };
        assert_eq!(
            c.refusals(),
            vec![too_far(far), too_far(edge), too_far(wide)]
        );
        let outside = c.replica().chunks().filter(|(p, _)| p.x.abs() > 9).count();
        assert_eq!(outside, 0, "nothing was sent from far away");
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn interest_complete_follows_the_last_chunk_of_each_view() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let c = connect(&server, "viewer", Role::Player).await;
        for center in [ChunkPos::new(0, 6, 0), ChunkPos::new(3, 6, 1)] {
            c.subscribe(center, 2).await.unwrap();
            loaded(&c, center, 2).await;
            // Updates apply in order: when the marker is seen, the view is
            // held, its rows clipped at the world's top (row 7).
            let r = c.replica();
            let missing: Vec<_> = view(center, 2)
                .into_iter()
                .filter(|p| r.get(*p).is_none())
                .collect();
            assert!(missing.is_empty(), "not held at the marker: {missing:?}");
            assert!(r.chunks().all(|(p, _)| p.y <= 7));
        }
        c.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn after_a_re_centre_the_whole_queue_is_nearest_first_from_the_new_centre() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // A view takes several ticks to stream (about 55 chunks a batch),
        // and ticks are long enough for the second subscription to arrive
        // before the second batch.
        let mut cfg = test_config(dir.path());
        cfg.net.send_budget_bytes_per_tick = 1024;
        cfg.engine.tick_ms = 50;
        let server = strata_server::app::start(cfg).await.unwrap();
        let seen: Arc<Mutex<Vec<WorldUpdate>>> = Arc::default();
        let on_update = {
            let seen = seen.clone();
            Arc::new(move |u: &WorldUpdate| seen.lock().unwrap().push(u.clone()))
        };
        let endpoint = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
        let tls = strata_client_sim::tls::client_config_pinned(&server.cert_der).unwrap();
        let token = token(&server, "mover", Role::Player);
        let mut s = RawSession::open(&endpoint, server.addr, tls, &token, None, Some(on_update))
            .await
            .unwrap();
        // Two subscriptions in one write: most of the first view is still
        // queued when the second arrives.
        let (a, b) = (ChunkPos::new(0, 0, 0), ChunkPos::new(2, 1, 0));
        let subscribe = |center| ClientMessage::Subscribe { center, radius: 2 };
        s.send_all(&[subscribe(a), subscribe(b)]).await.unwrap();
        let done = || {
            seen.lock()
                .unwrap()
                .iter()
                .any(|u| matches!(u, WorldUpdate::InterestComplete { center, .. } if *center == b))
        };
        assert!(eventually(Duration::from_secs(10), done).await);
        let chunks: Vec<ChunkPos> = seen
            .lock()
            .unwrap()
            .iter()
            .filter_map(|u| match u {
                WorldUpdate::Generated { pos } => Some(*pos),
                _ => None,
            })
            .collect();
        // A first batch of the first view may have left before the engine
        // took the second subscription: a prefix in the first view's order.
        // Everything after it is nearest first from the new centre.
        let mut from_a = view(a, 2);
        from_a.sort_by_key(|p| nearest_first(*p, a));
        let sorted_from_b = |s: &[ChunkPos]| {
            s.windows(2)
                .all(|w| nearest_first(w[0], b) <= nearest_first(w[1], b))
        };
        let split = (0..=chunks.len().min(from_a.len()))
            .find(|&k| chunks[..k] == from_a[..k] && sorted_from_b(&chunks[k..]));
        let Some(k) = split else {
            panic!(
                "not nearest first from {b:?} after a prefix from {a:?}; the first {} chunks: {:?}",
                chunks.len().min(12),
                &chunks[..chunks.len().min(12)]
            );
        };
        // And chunks of the old view only were among those re-sorted.
        assert!(
            chunks[k..].iter().any(|p| p.chebyshev(b) > 2),
            "{k} chunks went out before the re-centre: nothing of the old view was left queued"
        );
        // Every chunk of the new view, and the old view's chunks still
        // within hysteresis, each once.
        let mut want: Vec<ChunkPos> = view(b, 2);
        want.extend(view(a, 2).into_iter().filter(|p| p.chebyshev(b) <= 4));
        want.sort();
        want.dedup();
        let mut got = chunks.clone();
        got.sort();
        assert_eq!(got, want);
        drop(s);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_forgotten_chunk_gets_no_deltas_until_it_is_resynced() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (feet, surface) = spot(20, 20);
        let target = surface.chunk();
        let editor = connect(&server, "digger", Role::Player).await;
        editor.send_position(feet).unwrap();
        // Its view follows the accepted position and holds the target.
        assert!(eventually(Duration::from_secs(10), || editor.view_loaded().is_some()).await);
        let watcher = connect(&server, "watcher", Role::Player).await;
        // From now on its arrivals are recorded.
        assert!(watcher.take_arrivals().is_empty());
        watcher.subscribe(target, 1).await.unwrap();
        loaded(&watcher, target, 1).await;
        // Nothing more streams to it (its view is complete).
        assert!(eventually(Duration::from_secs(10), || watcher.view_loaded().is_some()).await);
        watcher.forget(&[target]).await.unwrap();
        assert!(watcher.replica().get(target).is_none(), "dropped at once");
        // The server confirms it at once (nothing else reaches the
        // watcher's updates stream): from then on nothing of it is on its
        // way, and the client takes it in again when sent.
        assert!(
            eventually(Duration::from_secs(5), || !watcher
                .replica()
                .is_dropped(target))
            .await,
            "the Forget was confirmed"
        );
        // Forgetting a chunk outside the view is ignored.
        watcher.forget(&[ChunkPos::new(90, 0, 0)]).await.unwrap();
        let mine = Edit::Mine {
            center: strata_terrain::FixedVec3::from_voxels(surface.x, surface.y, surface.z),
            radius: r(2.0),
            strength: 255,
        };
        let seq = match editor.edit(mine).await.unwrap() {
            Verdict::Accepted { seq } => seq,
            other => panic!("the edit was refused: {other:?}"),
        };
        // The same tick's fan-out brought the editor its delta.
        assert!(
            eventually(Duration::from_secs(5), || editor.replica().last_seq()
                >= seq)
            .await
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            watcher.take_arrivals().iter().all(|a| a.pos != target),
            "a delta of the forgotten chunk was sent"
        );
        assert!(watcher.replica().get(target).is_none());
        assert_eq!(watcher.replica().stats.gaps, 0, "nothing to resync");
        // Asking again brings it back at its new version.
        watcher.resync(target).await.unwrap();
        assert!(
            eventually(Duration::from_secs(5), || watcher
                .replica()
                .get(target)
                .is_some_and(|h| h.version >= 1))
            .await
        );
        // An oversized Forget is refused as a whole.
        let too_many = ClientMessage::Forget {
            chunks: vec![target; MAX_FORGET_CHUNKS + 1],
        };
        let frame = encode_frame(&too_many, Direction::ClientToServer).unwrap();
        watcher.send_raw(frame).await.unwrap();
        assert!(eventually(Duration::from_secs(5), || !watcher.refusals().is_empty()).await);
        assert_eq!(
            watcher.refusals(),
            vec![Refusal::ForgetTooLarge {
                chunks: MAX_FORGET_CHUNKS as u32 + 1,
                max: MAX_FORGET_CHUNKS as u32
            }]
        );
        assert!(
            watcher.replica().get(target).is_some(),
            "nothing was forgotten"
        );
        editor.close().await;
        watcher.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_forgotten_chunk_whose_snapshot_was_on_its_way_does_not_go_stale() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let (feet, surface) = spot(20, 20);
        let target = surface.chunk();
        let editor = connect(&server, "digger", Role::Player).await;
        editor.send_position(feet).unwrap();
        assert!(eventually(Duration::from_secs(10), || editor.view_loaded().is_some()).await);
        // The watcher lags: the target's snapshot is sent (and the server
        // records it held) but not applied before the client forgets it.
        let watcher = connect(&server, "watcher", Role::Player).await;
        watcher.pause_updates();
        watcher.subscribe(target, 1).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        watcher.forget(&[target]).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        // The server no longer sends the target's deltas to the watcher.
        let mine = Edit::Mine {
            center: strata_terrain::FixedVec3::from_voxels(surface.x, surface.y, surface.z),
            radius: r(2.0),
            strength: 255,
        };
        let seq = match editor.edit(mine).await.unwrap() {
            Verdict::Accepted { seq } => seq,
            other => panic!("the edit was refused: {other:?}"),
        };
        assert!(
            eventually(Duration::from_secs(5), || editor.replica().last_seq()
                >= seq)
            .await
        );
        let version = editor
            .replica()
            .get(target)
            .expect("editor holds it")
            .version;
        assert!(version >= 1);
        // The late snapshot arrives after the Forget: it must not be kept
        // at a version the server no longer takes forward.
        watcher.resume_updates();
        loaded(&watcher, target, 1).await;
        let held = watcher.replica().get(target).map(|h| h.version);
        assert!(
            held.is_none_or(|v| v == version),
            "the watcher holds the target at {held:?}, the server at {version}"
        );
        editor.close().await;
        watcher.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}

#[tokio::test]
async fn a_players_own_view_stays_within_reach_of_where_it_walks() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        // View radius 2, hysteresis 2: a view reaches at most 4 chunks
        // from the player. Fast walking, so one report crosses chunks (a
        // move of 252 voxels at most, within the 256 a path is swept).
        let mut cfg = test_config(dir.path());
        cfg.validation.max_speed = 1000.0;
        cfg.validation.max_move_ms = 200;
        // It flies high over the hills between (no gravity).
        cfg.validation.gravity.enabled = false;
        let server = app::start(cfg).await.expect("server starts");
        let (feet, _) = spot(16, 16);
        let walker = connect(&server, "walker", Role::Player).await;
        walker.send_position(feet).unwrap();
        assert!(eventually(Duration::from_secs(10), || walker.view_loaded().is_some()).await);
        let (home, _) = walker.view_loaded().unwrap();
        // A centre 4 chunks off passed the old rule (centre within radius
        // plus hysteresis) but its radius-2 view would reach 6.
        let wide = ChunkPos::new(home.x + 4, home.y, home.z);
        walker.subscribe(wide, 2).await.unwrap();
        // Two chunks ahead is within reach: the view stays there.
        let (dig_feet, surface) = spot(2 * 32 + 16, 16);
        let target = surface.chunk();
        assert!(target.chebyshev(home) <= 2, "{target:?} is near {home:?}");
        walker.subscribe(target, 2).await.unwrap();
        loaded(&walker, target, 2).await;
        assert_eq!(
            walker.refusals(),
            vec![Refusal::SubscribeTooFar {
                center: wide,
                max: 2
            }]
        );
        let digger = connect(&server, "digger", Role::Player).await;
        digger.send_position(dig_feet).unwrap();
        assert!(eventually(Duration::from_secs(10), || digger.view_loaded().is_some()).await);
        let dig = |strength| Edit::Mine {
            center: strata_terrain::FixedVec3::from_voxels(surface.x, surface.y, surface.z),
            radius: r(1.0),
            strength,
        };
        let accepted = |v| match v {
            Verdict::Accepted { seq } => seq,
            other => panic!("the edit was refused: {other:?}"),
        };
        // While the walker stands near, its own view brings the deltas.
        walker.take_arrivals();
        accepted(digger.edit(dig(100)).await.unwrap());
        let mut seen = Vec::new();
        assert!(
            eventually(Duration::from_secs(5), || {
                seen.extend(walker.take_arrivals());
                seen.iter().any(|a| a.pos == target)
            })
            .await,
            "the explicit view brought the delta"
        );
        // Walking 3 chunks the other way, the view would reach 7 chunks
        // from the feet: it moves to the feet's chunk (radius kept), which
        // no longer holds the target even with its hysteresis.
        tokio::time::sleep(Duration::from_millis(200)).await;
        // High above the ground: the way up, then across, is clear.
        let (mut away, _) = spot(-3 * 32 + 16, 16);
        away.y = strata_terrain::Fixed::from_voxels(away.y.floor_voxel() + 40);
        walker.send_position(away).unwrap();
        let there = strata_terrain::VoxelPos::new(-80, 0, 16).chunk().x;
        assert!(
            eventually(Duration::from_secs(10), || walker
                .view_loaded()
                .is_some_and(|(c, r)| c.x == there && r == 2))
            .await,
            "the view follows the walker again: {:?}",
            walker.view_loaded()
        );
        assert!(walker.replica().get(target).is_none(), "told to drop it");
        walker.take_arrivals();
        let seq = accepted(digger.edit(dig(200)).await.unwrap());
        assert!(
            eventually(Duration::from_secs(5), || digger.replica().last_seq()
                >= seq)
            .await
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
        assert!(
            walker.take_arrivals().iter().all(|a| a.pos != target),
            "a delta of the view walked away from was sent"
        );
        assert!(!walker.is_closed());
        walker.close().await;
        digger.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
