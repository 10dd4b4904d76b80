//! An online snapshot still being read when the engine stops is aborted:
//! its reader ends at its next chunk with a reason, instead of holding the
//! process's exit (and a console job's `.partial` file) until it has read
//! the whole world.

use std::sync::Arc;

use strata_server::engine::admin::AdminCommand;
use strata_server::engine::snapshot::STOPPING;
use strata_server::engine::{Command, Engine, EngineConfig, StreamPolicy};
use strata_server::interest::InterestConfig;
use strata_server::sequencer::{Sequencer, SequencerConfig};
use strata_server::store::{ChunkStore, SledStore, WorldMeta};
use strata_server::validate::bounds::WorldBounds;
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{MaterialTable, Voxel, World};

#[test]
fn a_snapshot_running_when_the_engine_stops_is_aborted() {
    let tmp = tempfile::tempdir().unwrap();
    let store = Arc::new(SledStore::open(tmp.path()).unwrap());
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    let world = World::new(Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    }));
    let seq = Sequencer::new(
        world,
        SequencerConfig::default(),
        ValidationConfig::default(),
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        Vec::new(),
    );
    let engine = Engine::new(
        seq,
        store,
        EngineConfig {
            workers: 1,
            ..Default::default()
        },
        StreamPolicy {
            send_budget: 1 << 20,
            regenerable: true,
        },
        InterestConfig::default(),
        WorldBounds::default(),
        Default::default(),
    )
    .unwrap();
    let (handle, thread) = engine.spawn(|| {}).unwrap();
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
