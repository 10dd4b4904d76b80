//! The engine ends a player's sessions past `[engine] sessions_per_player`
//! by session id (the order their connections came), whichever Join
//! reaches it first: the same order the session slots take at a full
//! server (`net/player_slots.rs`).

use crate::common;

use std::sync::Arc;

use strata_protocol::{ErrorCode, Role};
use strata_server::engine::{Command, EngineHandle, Kick, LatestPosition};
use strata_server::net::writer::FrameSender;
use tokio::sync::oneshot;

/// Joins session `id` of `player`; its kick, once the engine answered.
fn join(engine: &EngineHandle, id: u64, player: &str) -> oneshot::Receiver<Kick> {
    let (control, _) = FrameSender::channel(64);
    let (updates, _) = FrameSender::channel(64);
    let (reply, reply_rx) = oneshot::channel();
    let (kick, kick_rx) = oneshot::channel();
    assert!(engine.try_send(Command::Join {
        session: id,
        player: player.into(),
        role: Role::Player,
        control,
        updates,
        reply,
        kick,
        position: Arc::new(LatestPosition::default()),
        capabilities: 0,
        stored: None,
    }));
    reply_rx.blocking_recv().expect("joined");
    kick_rx
}

/// The kick `rx` gets, waited for up to 10 s: a Join is answered before
/// the session it replaced, its own when a newer one came first, is ended.
fn kicked(rx: &mut oneshot::Receiver<Kick>) -> Kick {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    loop {
        match rx.try_recv() {
            Ok(kick) => return kick,
            Err(oneshot::error::TryRecvError::Empty) if std::time::Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            Err(e) => panic!("no kick: {e:?}"),
        }
    }
}

#[test]
fn a_late_join_of_an_older_session_ends_that_session_not_the_newer() {
    let dir = tempfile::tempdir().unwrap();
    let (engine, thread) = common::flat_engine(dir.path());
    let mut newer = join(&engine, 2, "ana");
    let mut older = join(&engine, 1, "ana");
    let ended = kicked(&mut older);
    assert_eq!(ended.0, ErrorCode::Kicked);
    assert!(ended.1.contains("newer login"), "{}", ended.1);
    // Ending the newer one would have come before, in the same Join.
    assert!(newer.try_recv().is_err(), "the newer one lives on");
    // In order, the older one goes as before.
    let mut third = join(&engine, 3, "ana");
    assert_eq!(kicked(&mut newer).0, ErrorCode::Kicked);
    assert!(third.try_recv().is_err());
    engine.stop();
    thread.join().unwrap().unwrap();
}
