//! Acknowledged edits survive SIGKILL and graceful shutdown: the server runs
//! as a real child process, and the store is checked offline afterwards.

use crate::common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::*;
use strata_client_sim::Verdict;
use strata_protocol::Role;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{Edit, FixedVec3};

fn feet() -> (FixedVec3, i32, i32, i32) {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let (x, z) = (70, 40);
    let y = g.surface_height(x, z);
    (at(x as f64, y + 1.0, z as f64), x, y.floor() as i32, z)
}

type Acked = Arc<Mutex<Vec<u64>>>;

/// Sends edits one after another until one is refused or the connection
/// ends, recording the sequence number of every acknowledged one.
fn keep_editing(
    c: Arc<strata_client_sim::Client>,
    edit: impl Fn(i32) -> Edit + Send + 'static,
) -> (Acked, tokio::task::JoinHandle<()>) {
    let acked: Acked = Arc::default();
    let log = acked.clone();
    let worker = tokio::spawn(async move {
        for i in 0..10_000 {
            match c.edit(edit(i)).await {
                Ok(Verdict::Accepted { seq }) => log.lock().unwrap().push(seq),
                Ok(_) | Err(_) => return,
            }
        }
    });
    (acked, worker)
}

on_both_backends!(
    acknowledged_edits_survive_sigkill,
    acknowledged_edits_survive_sigkill_on_postgres,
    acknowledged_edits_survive_sigkill_on
);

async fn acknowledged_edits_survive_sigkill_on(backend: Backend) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let config = format!("{FAST_EDITS}{}", backend.toml());
        let (mut child, addr) = spawn_server(&data, &config);
        let c = Arc::new(process_client(&data, addr, "ana").await);
        let (pos, x, y, z) = feet();
        c.send_position(pos).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (acked, worker) = keep_editing(c.clone(), move |i| Edit::Build {
            center: FixedVec3::from_voxels(x + i % 5 - 2, y + 2, z + (i / 5) % 5 - 2),
            radius: r(1.5),
            material: 7,
            strength: 20,
        });
        assert!(
            eventually(Duration::from_secs(20), || acked.lock().unwrap().len()
                >= 20)
            .await
        );
        child.kill().unwrap();
        child.wait().unwrap();
        // The client would only notice the dead peer at its idle timeout.
        worker.abort();
        let _ = worker.await;
        let acked = acked.lock().unwrap().clone();
        if let Backend::Postgres(db) = &backend {
            // The killed server's sessions may still be ending: a COMMIT it
            // sent before the kill may land yet. Read once they are gone.
            let others = format!(
                "SELECT count(*) FROM pg_stat_activity WHERE datname = '{}' \
                 AND pid <> pg_backend_pid()",
                db.name()
            );
            let started = std::time::Instant::now();
            let count = |db: &strata_tests::postgres::PgDb| {
                let (db_url, others) = (db.url(), others.clone());
                std::thread::scope(|s| {
                    s.spawn(|| crate::store_common::sql_url(&db_url, &others))
                        .join()
                        .unwrap()
                })
            };
            while count(db) != ["0"] {
                assert!(started.elapsed() < Duration::from_secs(30));
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
        let store = backend.open_store(&data);
        let last = store.last_seq().unwrap();
        for seq in &acked {
            let entry = store
                .log_entry(*seq)
                .unwrap()
                .unwrap_or_else(|| panic!("acknowledged seq {seq} was lost"));
            for (pos, version) in entry.changes {
                assert!(store.load_chunk(pos).unwrap().unwrap().version >= version);
            }
        }
        assert!(last >= *acked.iter().max().unwrap());
        let report = store.check().unwrap();
        assert!(report.is_ok(), "{report:?}");
        drop(store);
        // A restarted server continues after the last durable edit.
        let (mut child, addr) = spawn_server(&data, &config);
        let c = process_client(&data, addr, "bo").await;
        assert_eq!(c.welcome().last_seq, last);
        c.close().await;
        child.kill().unwrap();
        child.wait().unwrap();
    })
    .await
    .expect("test finished in time");
}

on_both_backends!(
    graceful_shutdown_loses_nothing,
    graceful_shutdown_loses_nothing_on_postgres,
    graceful_shutdown_loses_nothing_on
);

async fn graceful_shutdown_loses_nothing_on(backend: Backend) {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        backend.apply(&mut cfg);
        cfg.validation.edit_rate.per_second = 1000;
        cfg.validation.edit_rate.capacity = 1000;
        let server = strata_server::app::start(cfg).await.unwrap();
        let c = Arc::new(connect(&server, "ana", Role::Player).await);
        let (pos, x, y, z) = feet();
        c.send_position(pos).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (acked, worker) = keep_editing(c.clone(), move |i| Edit::Mine {
            center: FixedVec3::from_voxels(x + i % 7 - 3, y, z),
            radius: r(1.5),
            strength: 10,
        });
        assert!(
            eventually(Duration::from_secs(20), || acked.lock().unwrap().len()
                >= 10)
            .await
        );
        server.shutdown().await.unwrap();
        let _ = worker.await;
        let err = c.server_error();
        assert!(
            matches!(err, Some((strata_protocol::ErrorCode::ShuttingDown, _))),
            "{err:?}"
        );
        let store = backend.open_store(dir.path());
        for seq in acked.lock().unwrap().iter() {
            assert!(
                store.log_entry(*seq).unwrap().is_some(),
                "acknowledged seq {seq} was lost"
            );
        }
    })
    .await
    .expect("test finished in time");
}

/// A chunk's first change reaches sled as a delta from its generated state
/// (no whole chunk on the commit's path): killed before any checkpoint, the
/// store cannot read the chunk without the world's generator, and reads it
/// at the acknowledged version with it, as the restarted server does.
#[tokio::test]
async fn a_first_change_is_stored_as_a_delta_from_generated_terrain() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        // No checkpoint folds the delta before the kill.
        let config = format!("{FAST_EDITS}[store]\ncheckpoint_ms = 3600000\n");
        let (mut child, addr) = spawn_server(&data, &config);
        let c = process_client(&data, addr, "ana").await;
        let (pos, x, y, z) = feet();
        c.send_position(pos).unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (verdict, changes) = c
            .edit_acked(Edit::Build {
                center: FixedVec3::from_voxels(x, y + 2, z),
                radius: r(1.5),
                material: 7,
                strength: 20,
            })
            .await
            .unwrap();
        assert!(matches!(verdict, Verdict::Accepted { .. }), "{verdict:?}");
        assert!(!changes.is_empty());
        child.kill().unwrap();
        child.wait().unwrap();
        c.close().await;
        {
            let bare =
                strata_server::store::SledStore::open(&data.join("world.sled")).unwrap();
            for ch in &changes {
                assert_eq!(ch.version, 1, "a first change: {ch:?}");
                let read = strata_server::store::ChunkStore::load_chunk(&bare, ch.pos);
                assert!(
                    matches!(
                        read,
                        Err(strata_server::store::StoreError::NeedsGenerator { pos }) if pos == ch.pos
                    ),
                    "{read:?}"
                );
            }
        }
        let store = Backend::Sled.open_store(&data);
        // The replay checks the generated base's hash and the target's.
        for ch in &changes {
            assert_eq!(store.load_chunk(ch.pos).unwrap().unwrap().version, 1);
        }
        assert!(store.check().unwrap().is_ok());
    })
    .await
    .expect("test finished in time");
}
