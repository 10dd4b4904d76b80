//! An online snapshot still being read when the engine stops is aborted:
//! its reader ends at its next chunk with a reason, instead of holding the
//! process's exit (and a console job's `.partial` file) until it has read
//! the whole world.

use crate::common;

use strata_server::engine::admin::AdminCommand;
use strata_server::engine::snapshot::STOPPING;
use strata_server::engine::Command;

#[test]
fn a_snapshot_running_when_the_engine_stops_is_aborted() {
    let tmp = tempfile::tempdir().unwrap();
    let (handle, thread) = common::flat_engine(tmp.path());
    let (reply, answer) = tokio::sync::oneshot::channel();
    assert!(handle.try_send(Command::Admin(AdminCommand::SnapshotBegin {
        max_pending_chunks: 0,
        world_seed: 1,
        generator_version: 1,
        generator_params: String::new(),
        reply,
    })));
    let start = answer.blocking_recv().unwrap().unwrap();
    assert_eq!(start.preimages.aborted(), None, "running");
    handle.stop();
    thread.join().unwrap().unwrap();
    assert_eq!(start.preimages.aborted().as_deref(), Some(STOPPING));
}
