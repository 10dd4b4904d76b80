//! `strata_client::Session`, the Rust API under the C ABI, against a real
//! server: predicted edits show at once, verdicts carry tickets, chunk
//! changes are reported, meshes match the server's hashes, and the end of
//! the connection comes last.

use crate::common;

use std::time::{Duration, Instant};

use common::{ffi, wait_for, Server};
use strata_client::glam::{DVec3, IVec3};
use strata_client::protocol::RejectReason;
use strata_client::terrain::ChunkPos;
use strata_client::{edits, Event, Session, SessionOptions};

const WAIT: Duration = Duration::from_secs(10);

/// The highest solid voxel of column (`x`, `z`), read from held chunks.
fn ground(s: &Session, x: i32, z: i32) -> Option<i32> {
    let (lx, lz) = ((x & 31) as usize, (z & 31) as usize);
    for cy in (-1..=3).rev() {
        let c = s.chunk(ChunkPos::new(x >> 5, cy, z >> 5))?;
        if let Some(ly) = (0..32)
            .rev()
            .find(|&ly| c.density[lx + 32 * (ly + 32 * lz)] >= 128)
        {
            return Some(cy * 32 + ly as i32);
        }
    }
    None
}

#[test]
fn a_session_edits_sees_its_changes_and_ends_with_disconnected() {
    let server = Server::start();
    let opts = SessionOptions {
        predict: true,
        ..SessionOptions::default()
    };
    let token = server.token("rust-session");
    let s = Session::connect(server.running.addr, &server.running.cert_der, &token, opts).unwrap();
    let radius = s.welcome().view_radius;
    s.subscribe(IVec3::new(0, 1, 0), radius).unwrap();
    let mut seen = Vec::new();
    let start = Instant::now();
    let y = loop {
        while let Some(e) = s.poll() {
            seen.push(e);
        }
        if let Some(y) = ground(&s, 3, 3) {
            break y;
        }
        assert!(start.elapsed() < WAIT, "the column never arrived");
        std::thread::sleep(Duration::from_millis(10));
    };
    assert!(seen.iter().any(|e| matches!(e, Event::ChunkChanged { .. })));
    // A second player who predicts nothing watches the same view; once it
    // is loaded and every load reported, only later changes are reported.
    let watcher = Session::connect(
        server.running.addr,
        &server.running.cert_der,
        &server.token("rust-watcher"),
        SessionOptions::default(),
    )
    .unwrap();
    watcher.subscribe(IVec3::new(0, 1, 0), radius).unwrap();
    let mut watched = Vec::new();
    wait_for(&watcher, &mut watched, |e| {
        matches!(e, Event::ViewLoaded { .. }).then_some(())
    });
    while let Some(e) = watcher.poll() {
        watched.push(e);
    }
    let loaded = watched.len();

    // A far edit is refused with its own ticket.
    let feet = DVec3::new(3.5, f64::from(y) + 1.0, 3.5);
    let target = DVec3::new(3.5, f64::from(y) + 0.5, 3.5);
    let (accepted, changes, sent_at, settled_by_verdict) = loop {
        s.set_position(feet).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        let sent_at = seen.len();
        let ticket = s.edit(edits::mine(target, 2.0, 255).unwrap()).unwrap();
        let verdict = wait_for(&s, &mut seen, |e| match e {
            Event::EditAccepted {
                ticket: t, changes, ..
            } if *t == ticket => Some(Ok(changes.clone())),
            Event::EditRejected { ticket: t, reason } if *t == ticket => Some(Err(reason.clone())),
            _ => None,
        });
        match verdict {
            Ok(changes) => {
                // The delta and the verdict travel apart: either may come
                // first.
                let settled = changes
                    .first()
                    .is_some_and(|c| s.chunk(c.pos).map(|d| d.version) == Some(c.version));
                break (ticket, changes, sent_at, settled);
            }
            Err(RejectReason::NoPosition) => continue,
            Err(other) => panic!("dig refused: {other:?}"),
        }
    };
    assert!(accepted > 0 && !changes.is_empty());
    let far = s
        .edit(edits::mine(DVec3::new(3000.5, 10.0, 3.5), 2.0, 255).unwrap())
        .unwrap();
    let reason = wait_for(&s, &mut seen, |e| match e {
        Event::EditRejected { ticket, reason } if *ticket == far => Some(reason.clone()),
        _ => None,
    });
    assert!(
        matches!(reason, RejectReason::OutOfReach { .. }),
        "{reason:?}"
    );

    // Our own delta: the chunk reaches the version the server gave, is
    // reported changed, and its mesh is checked against the server's hash.
    let changed = changes[0];
    let start = Instant::now();
    while s.chunk(changed.pos).map(|c| c.version) != Some(changed.version) {
        while let Some(e) = s.poll() {
            seen.push(e);
        }
        assert!(start.elapsed() < WAIT, "our delta never came");
        std::thread::sleep(Duration::from_millis(5));
    }
    // The change was queued before the replica showed the new version.
    while let Some(e) = s.poll() {
        seen.push(e);
    }
    // When the delta came after the verdict, its change is reported after
    // the verdict too; else at least after the dig was sent.
    let verdict_at = seen
        .iter()
        .position(|e| matches!(e, Event::EditAccepted { ticket, .. } if *ticket == accepted))
        .unwrap();
    let since = if settled_by_verdict {
        sent_at
    } else {
        verdict_at
    };
    assert!(
        seen[since..].contains(&Event::ChunkChanged { pos: changed.pos }),
        "{seen:?}"
    );
    let data = s.chunk(changed.pos).unwrap();
    assert!(!data.predicted, "settled: the view is the server's");
    // The watcher is told of the dig's delta and reaches its version.
    wait_for(&watcher, &mut watched, |e| {
        (*e == Event::ChunkChanged { pos: changed.pos }).then_some(())
    });
    let start = Instant::now();
    while watcher.chunk(changed.pos).map(|c| c.version) != Some(changed.version) {
        assert!(start.elapsed() < WAIT, "the watcher never saw the dig");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        watched[loaded..]
            .iter()
            .all(|e| matches!(e, Event::ChunkChanged { .. })),
        "{watched:?}"
    );
    let mesh = s.mesh(changed.pos, 0, 0).unwrap().unwrap();
    assert!(mesh.triangle_count() > 0 && mesh.complete);
    let start = Instant::now();
    while s.stats().meshes_checked == 0 {
        assert!(start.elapsed() < WAIT, "no mesh was checked");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(s.stats().mesh_mismatches, 0);
    let p = s.prediction_stats().unwrap();
    assert_eq!(
        p.made,
        p.exact + p.rolled_back + p.mispredicted + p.unverified + p.pending
    );
    assert!(p.made >= 1);

    // The server goes away: edits taken meanwhile fail, then Disconnected
    // comes once, last.
    let _stopped = server.stop();
    let start = Instant::now();
    while !s.is_closed() {
        assert!(
            start.elapsed() < WAIT,
            "the session did not see the server go"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    let late = s.edit(edits::mine(target, 2.0, 255).unwrap()).unwrap();
    let mut tail = Vec::new();
    wait_for(&s, &mut tail, |e| {
        matches!(e, Event::Disconnected { .. }).then_some(())
    });
    assert!(
        tail.iter()
            .any(|e| matches!(e, Event::EditFailed { ticket, .. } if *ticket == late)),
        "{tail:?}"
    );
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(s.poll(), None, "nothing after Disconnected");
    s.close();
}

/// A refused position through the C ABI: the event names the rule and
/// where the server holds the player, to move back to.
#[test]
fn a_refused_position_through_the_c_abi_says_where_the_player_is_held() {
    use strata::*;

    let server = Server::start();
    let c = ffi::connect(&server, "c-walker");
    let report = |x: f64, y: f64, z: f64| {
        // SAFETY: `c` is the live session made above.
        let st = unsafe { strata_set_position(c, x, y, z) };
        assert_eq!(st, StrataStatus::Ok);
    };
    // High in the air above the spawn square: accepted.
    report(3.5, 200.0, 3.5);
    std::thread::sleep(Duration::from_millis(300));
    // 600 voxels on in 0.3 s: too fast.
    report(3.5, 200.0, 603.5);
    let start = Instant::now();
    let ev = loop {
        let ev = ffi::poll(c);
        if ev.kind == StrataEventKind::PositionRefused {
            break ev;
        }
        assert!(start.elapsed() < WAIT, "no refusal came");
        if ev.kind == StrataEventKind::None {
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    assert_eq!(ev.seq, 2, "the second report");
    assert_eq!(ev.position_refusal, StrataPositionRefusal::TooFast);
    assert_eq!(ev.held_known, 1);
    assert_eq!(ev.held, [3.5, 200.0, 3.5]);
    // SAFETY: `c` is live and nothing else uses it.
    unsafe { strata_session_free(c) };
}

/// `strata_connect_with` through the C ABI: a thin, op-replaying session
/// loads its view as whole chunks (no generator) and takes another
/// player's edit as an op, replayed and hash-checked.
#[test]
fn a_thin_op_replay_session_through_the_c_abi() {
    use strata::*;

    let server = Server::start();
    let cert = &server.running.cert_der;
    let options = StrataConnectOptions {
        size: std::mem::size_of::<StrataConnectOptions>() as u32,
        predict: 0,
        capabilities: STRATA_CAP_SNAPSHOTS | STRATA_CAP_OP_REPLAY,
    };
    let c = ffi::connect_with(&server.address(), cert, &server.token("c-thin"), &options);
    // SAFETY: `c` is the live session made above.
    assert_eq!(unsafe { strata_subscribe(c, 0, 1, 0, 2) }, StrataStatus::Ok);
    let stats = || ffi::stats(c);
    let start = Instant::now();
    while stats().chunks_held < 125 {
        assert!(
            start.elapsed() < WAIT,
            "the view never arrived: {:?}",
            stats()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let loaded = stats();
    assert_eq!(loaded.generated, 0, "{loaded:?}");
    assert_eq!(loaded.snapshots, loaded.chunks_held, "{loaded:?}");

    // Another player digs in the view; the C session replays the edit.
    let t = server.token("rust-digger");
    let opts = SessionOptions::default();
    let s = Session::connect(server.running.addr, cert, &t, opts).unwrap();
    s.subscribe(IVec3::new(0, 1, 0), 2).unwrap();
    let start = Instant::now();
    let y = loop {
        while s.poll().is_some() {}
        if let Some(y) = ground(&s, 3, 3) {
            break y;
        }
        assert!(start.elapsed() < WAIT, "the column never arrived");
        std::thread::sleep(Duration::from_millis(10));
    };
    let feet = DVec3::new(3.5, f64::from(y) + 1.0, 3.5);
    let target = DVec3::new(3.5, f64::from(y) + 0.5, 3.5);
    let start = Instant::now();
    while stats().op_chunks == 0 {
        assert!(start.elapsed() < WAIT, "no op was replayed: {:?}", stats());
        s.set_position(feet).unwrap();
        s.edit(edits::mine(target, 2.0, 255).unwrap()).unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    let end = stats();
    assert_eq!((end.op_fallbacks, end.hash_mismatches), (0, 0), "{end:?}");
    assert_eq!(end.mesh_mismatches, 0, "{end:?}");
    // SAFETY: `c` is live and nothing else uses it.
    unsafe { strata_session_free(c) };
}

#[test]
fn a_session_hears_its_view_loaded_its_refused_positions_and_forgets_chunks() {
    let server = Server::start();
    let token = server.token("rust-viewer");
    let opts = SessionOptions::default();
    let s = Session::connect(server.running.addr, &server.running.cert_der, &token, opts).unwrap();
    let mut seen = Vec::new();
    let center = ChunkPos::new(0, 1, 0);
    s.subscribe(IVec3::new(0, 1, 0), 1).unwrap();
    wait_for(&s, &mut seen, |e| {
        (*e == Event::ViewLoaded { center, radius: 1 }).then_some(())
    });
    assert!(
        s.chunk(center).is_some(),
        "the view is held when it is loaded"
    );

    // Far outside the spawn square: refused, and told why.
    s.set_position(DVec3::new(90_000.5, 40.0, 0.5)).unwrap();
    let reason = wait_for(&s, &mut seen, |e| match e {
        Event::PositionRefused { seq: 1, reason, at } => {
            assert_eq!(*at, None, "no position held before the first");
            Some(*reason)
        }
        _ => None,
    });
    assert!(
        matches!(
            reason,
            strata_client::protocol::PositionRefusal::OutsideSpawn { .. }
        ),
        "{reason:?}"
    );

    // A forgotten chunk is dropped at once, and a resync brings it back.
    s.forget(&[IVec3::new(0, 1, 0)]).unwrap();
    let start = Instant::now();
    while s.chunk(center).is_some() {
        assert!(start.elapsed() < WAIT, "the chunk was never dropped");
        std::thread::sleep(Duration::from_millis(5));
    }
    // Reported as changed: it left the view.
    wait_for(&s, &mut seen, |e| {
        (*e == Event::ChunkChanged { pos: center }).then_some(())
    });
    let too_many = vec![IVec3::ZERO; strata_client::protocol::limits::MAX_FORGET_CHUNKS + 1];
    assert!(s.forget(&too_many).is_err(), "refused before sending");
    s.resync(IVec3::new(0, 1, 0)).unwrap();
    let start = Instant::now();
    while s.chunk(center).is_none() {
        while let Some(e) = s.poll() {
            seen.push(e);
        }
        assert!(start.elapsed() < WAIT, "the resync never came");
        std::thread::sleep(Duration::from_millis(5));
    }
    s.close();
}

/// Through the C ABI: once DISCONNECTED was polled, the calls that would
/// queue work say CLOSED, and polls return nothing more (no EDIT_FAILED
/// for an edit taken after it, no CHUNK_CHANGED for a forget).
#[test]
fn nothing_is_taken_or_polled_after_disconnected() {
    use strata::*;

    let server = Server::start();
    let c = ffi::connect(&server, "c-after");
    let poll = || ffi::poll(c).kind;
    let _stopped = server.stop();
    let start = Instant::now();
    while poll() != StrataEventKind::Disconnected {
        assert!(start.elapsed() < WAIT, "no DISCONNECTED");
        std::thread::sleep(Duration::from_millis(5));
    }
    let dig = ffi::dig();
    let mut ticket = 0;
    let chunk = [0i32, 1, 0];
    // SAFETY: `c` is live; the edit and the chunk are readable, `ticket`
    // writable.
    let statuses = unsafe {
        [
            strata_edit(c, &dig, &mut ticket),
            strata_forget(c, &chunk, 1),
            strata_resync(c, 0, 1, 0),
            strata_subscribe(c, 0, 1, 0, 1),
        ]
    };
    assert_eq!(statuses, [StrataStatus::Closed; 4]);
    assert_eq!(ticket, 0, "no ticket was taken");
    let start = Instant::now();
    while start.elapsed() < Duration::from_millis(500) {
        assert_eq!(poll(), StrataEventKind::None, "an event after DISCONNECTED");
        std::thread::sleep(Duration::from_millis(10));
    }
    // SAFETY: `c` is live and nothing else uses it.
    unsafe { strata_session_free(c) };
}

/// A client records delta arrivals only when asked (a load test's
/// latencies): an SDK session, which never takes them, keeps none.
#[test]
fn delta_arrivals_are_recorded_only_for_a_caller_that_takes_them() {
    use strata_client::terrain::{Edit, FixedVec3, VoxelPos};
    use strata_client::{Client, Verdict};

    let server = Server::start();
    let cert = server.running.cert_der.clone();
    let token = server.token("arrivals");
    let client = server
        .runtime
        .block_on(Client::connect(server.running.addr, &cert, &token))
        .unwrap();
    server
        .runtime
        .block_on(client.subscribe(ChunkPos::new(0, 1, 0), 2))
        .unwrap();
    let start = Instant::now();
    let y = loop {
        let r = client.replica();
        if let Some(y) = (-64..=127).rev().find_map(|y| {
            r.voxel(VoxelPos::new(3, y, 3))
                .filter(|v| v.is_solid())
                .map(|_| y)
        }) {
            break y;
        }
        drop(r);
        assert!(start.elapsed() < WAIT, "the column never arrived");
        std::thread::sleep(Duration::from_millis(10));
    };
    let feet = FixedVec3::from_f64([3.5, f64::from(y) + 1.0, 3.5]).unwrap();
    let dig = || Edit::Mine {
        center: FixedVec3::from_f64([3.5, f64::from(y) + 0.5, 3.5]).unwrap(),
        radius: strata_client::terrain::Fixed::from_f64(2.0).unwrap(),
        strength: 255,
    };
    // Digs until accepted; waits until its own delta was applied.
    let dig_and_wait = || {
        let start = Instant::now();
        let changes = loop {
            assert!(start.elapsed() < WAIT, "no dig was accepted");
            client.send_position(feet).unwrap();
            std::thread::sleep(Duration::from_millis(20));
            let (verdict, changes) = server.runtime.block_on(client.edit_acked(dig())).unwrap();
            if matches!(verdict, Verdict::Accepted { .. }) && !changes.is_empty() {
                break changes;
            }
        };
        let c = changes[0];
        let start = Instant::now();
        while client.replica().get(c.pos).map(|h| h.version) < Some(c.version) {
            assert!(start.elapsed() < WAIT, "our delta never came");
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    dig_and_wait();
    assert!(
        client.take_arrivals().is_empty(),
        "arrivals were recorded for a client that never asked"
    );
    // Taking them starts recording.
    dig_and_wait();
    assert!(!client.take_arrivals().is_empty(), "taken, so recorded");
    server.runtime.block_on(client.close());
}
