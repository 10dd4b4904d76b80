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

#[test]
fn a_late_join_of_an_older_session_ends_that_session_not_the_newer() {
    let dir = tempfile::tempdir().unwrap();
    let (engine, thread) = common::flat_engine(dir.path());
    let mut newer = join(&engine, 2, "ana");
    let mut older = join(&engine, 1, "ana");
    let ended = older.try_recv().expect("the older one ended");
    assert_eq!(ended.0, ErrorCode::Kicked);
    assert!(ended.1.contains("newer login"), "{}", ended.1);
    assert!(newer.try_recv().is_err(), "the newer one lives on");
    // In order, the older one goes as before.
    let mut third = join(&engine, 3, "ana");
    assert_eq!(newer.try_recv().expect("replaced").0, ErrorCode::Kicked);
    assert!(third.try_recv().is_err());
    engine.stop();
    thread.join().unwrap().unwrap();
}
