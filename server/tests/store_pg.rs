//! What only the PostgreSQL store has: migrations applied once and
//! tracked, a region layout fixed per database, region columns on chunk
//! rows, calls from inside a tokio runtime, and `check` naming tables this
//! layout does not have.

use crate::store_common;

use std::sync::Arc;
use store_common::{pg_store, sql, terrain_chunk, Seq};
use strata_server::store::pg::{PgConfig, MIGRATIONS};
use strata_server::store::{
    ChunkStore, PgStore, StoreError, StoredPosition, WorldMeta, STORE_FORMAT_VERSION,
};

use strata_terrain::edit::{Fixed, FixedVec3};
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{ChunkPos, Voxel};
use strata_tests::postgres::{database, PgDb};

#[test]
fn migrations_are_applied_once_and_recorded() {
    let Some(db) = database("migrations_once") else {
        return;
    };
    drop(pg_store(&db));
    drop(pg_store(&db));
    let applied = sql(&db, "SELECT version || ' ' || name FROM schema_migrations");
    let known: Vec<String> = MIGRATIONS
        .iter()
        .map(|(v, name, _)| format!("{v} {name}"))
        .collect();
    assert_eq!(applied, known);
    // A database a newer build migrated further is refused, not written.
    sql(
        &db,
        "INSERT INTO schema_migrations (version, name) VALUES (999, 'future')",
    );
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let err = PgStore::open(&cfg, 8).unwrap_err();
    assert!(
        matches!(err, StoreError::UnsupportedFormat { found: 999, .. }),
        "{err}"
    );
}

#[test]
fn worlds_of_store_formats_2_and_3_are_upgraded_by_their_migrations() {
    let Some(db) = database("format_2_upgrade") else {
        return;
    };
    // As a format-2 build left it (before migrations 5 and 6), then as a
    // format-3 build did (before 6).
    for (old, missing) in [(2, "5, 6"), (3, "6")] {
        let store = pg_store(&db);
        store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
        drop(store);
        sql(&db, &format!("UPDATE world SET format_version = {old}"));
        sql(
            &db,
            &format!("DELETE FROM schema_migrations WHERE version IN ({missing})"),
        );
        let store = pg_store(&db);
        let meta = store.load_meta().unwrap().unwrap();
        assert_eq!(meta.format_version, STORE_FORMAT_VERSION);
    }
    assert_eq!(STORE_FORMAT_VERSION, 4);
}

#[test]
fn an_admin_tool_migrates_a_database_only_while_no_server_uses_it() {
    let Some(db) = database("admin_migrates_alone") else {
        return;
    };
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let server = pg_store(&db);
    server.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    server.serve().unwrap();
    // As a build with migrations 1-7 left it, and a server of that build
    // running on it.
    sql(
        &db,
        "ALTER TABLE players DROP COLUMN known_ms; \
         DELETE FROM schema_migrations WHERE version = 8",
    );
    let err = PgStore::open_admin(&cfg, 8).unwrap_err();
    assert!(
        matches!(
            err,
            StoreError::SchemaBehind { found: 7, needed }
                if needed as usize == MIGRATIONS.len()
        ),
        "{err}"
    );
    let versions = || {
        sql(
            &db,
            "SELECT version FROM schema_migrations ORDER BY version",
        )
    };
    assert!(!versions().contains(&"8".to_string()), "not migrated");
    // Up to date, it opens beside a running server.
    sql(
        &db,
        "ALTER TABLE players ADD COLUMN known_ms bigint NOT NULL DEFAULT 0; \
         INSERT INTO schema_migrations (version, name) VALUES (8, '0008_position_times')",
    );
    drop(PgStore::open_admin(&cfg, 8).unwrap());
    sql(
        &db,
        "ALTER TABLE players DROP COLUMN known_ms; \
         DELETE FROM schema_migrations WHERE version = 8",
    );
    // With the server gone, the tool migrates it.
    drop(server);
    let admin = PgStore::open_admin(&cfg, 8).unwrap();
    assert!(versions().contains(&"8".to_string()));
    assert_eq!(admin.player_positions().count(), 0);
}

/// A database `name` whose world was made by this build, then taken back
/// by `statements` to what an older build left.
fn as_an_older_build_left_it(name: &str, statements: &str) -> Option<PgDb> {
    let db = database(name)?;
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    drop(store);
    sql(&db, statements);
    Some(db)
}

#[test]
fn a_database_migrated_before_generated_rows_takes_them_after_migration_7() {
    // As a build with migrations 1-6 left it: the first checks on versions.
    let Some(db) = as_an_older_build_left_it(
        "generated_rows_migration",
        "ALTER TABLE chunks DROP CONSTRAINT chunks_version_check; \
         ALTER TABLE chunks ADD CONSTRAINT chunks_version_check CHECK (version > 0); \
         ALTER TABLE chunk_deltas DROP CONSTRAINT chunk_deltas_to_version_check; \
         ALTER TABLE chunk_deltas ADD CONSTRAINT chunk_deltas_to_version_check \
             CHECK (to_version > 1); \
         DELETE FROM schema_migrations WHERE version = 7",
    ) else {
        return;
    };
    let store = pg_store(&db);
    let g = FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    };
    store.attach_generator(Arc::new(g));
    let pos = ChunkPos::new(3, -1, 2);
    let state = terrain_chunk(4);
    let mut seq = Seq::default();
    store
        .commit_batch(&seq.generated_batch(&[vec![(pos, state.clone())]], &g))
        .unwrap();
    assert_eq!(store.delta_count().unwrap(), 1, "stored from generated");
    let loaded = store.load_chunk(pos).unwrap().unwrap();
    assert_eq!((loaded.version, loaded.chunk), (1, state));
}

#[test]
fn positions_stored_before_migration_8_read_with_no_time() {
    // As a build with migrations 1-7 left it, with a player stored.
    let Some(db) = as_an_older_build_left_it(
        "position_times_migration",
        "ALTER TABLE players DROP COLUMN known_ms; \
         DELETE FROM schema_migrations WHERE version = 8; \
         INSERT INTO players (name, x, y, z) VALUES ('old', 1, 2, 3)",
    ) else {
        return;
    };
    let store = pg_store(&db);
    let feet = |v: i32| FixedVec3::new(Fixed(v), Fixed(v + 1), Fixed(v + 2));
    let new = StoredPosition {
        feet: feet(7),
        known_ms: 1_790_000_000_000,
    };
    store.save_positions(&[("new".into(), new)]).unwrap();
    let got: Vec<_> = store.player_positions().map(|r| r.unwrap()).collect();
    let old = StoredPosition {
        feet: feet(1),
        known_ms: 0,
    };
    assert_eq!(got, [("new".to_string(), new), ("old".to_string(), old)]);
}

#[test]
fn a_stored_position_is_never_replaced_by_an_older_one() {
    let Some(db) = database("positions_newest_wins") else {
        return;
    };
    let store = pg_store(&db);
    let at = |v: i32, known_ms| StoredPosition {
        feet: FixedVec3::new(Fixed(v), Fixed(0), Fixed(0)),
        known_ms,
    };
    // Another node saved a newer one; a stale save after it changes nothing.
    store
        .save_positions(&[("ann".into(), at(5, 2_000))])
        .unwrap();
    store
        .save_positions(&[("ann".into(), at(1, 1_000))])
        .unwrap();
    assert_eq!(store.player_position("ann").unwrap(), Some(at(5, 2_000)));
    store
        .save_positions(&[("ann".into(), at(9, 3_000))])
        .unwrap();
    assert_eq!(store.player_position("ann").unwrap(), Some(at(9, 3_000)));
    assert_eq!(store.player_position("bob").unwrap(), None);
    // A row dated an hour ahead (a node's clock ran ahead) pins nothing.
    let now = strata_server::engine::now_ms();
    store
        .save_positions(&[("cy".into(), at(1, now + 3_600_000))])
        .unwrap();
    store.save_positions(&[("cy".into(), at(2, now))]).unwrap();
    assert_eq!(store.player_position("cy").unwrap(), Some(at(2, now)));
}

#[test]
fn the_region_layout_is_fixed_and_rows_carry_their_region() {
    let Some(db) = database("region_layout") else {
        return;
    };
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    let mut seq = Seq::default();
    let a = ChunkPos::new(-1, 0, 17);
    store
        .commit_batch(&seq.delta_batch(&[vec![(a, terrain_chunk(1))]]))
        .unwrap();
    store
        .commit_batch(&seq.delta_batch(&[vec![(a, terrain_chunk(2))]]))
        .unwrap();
    // Side 8: chunk x -1 is in region -1, z 17 in region 2.
    assert_eq!(
        sql(&db, "SELECT region_x || ',' || region_z FROM chunks"),
        ["-1,2"]
    );
    assert_eq!(
        sql(&db, "SELECT region_x || ',' || region_z FROM chunk_deltas"),
        ["-1,2"]
    );
    drop(store);
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let err = PgStore::open(&cfg, 16).unwrap_err();
    assert!(
        matches!(&err, StoreError::MetaMismatch { field: "region_chunks", stored, given }
            if stored == "8" && given == "16"),
        "{err}"
    );
}

#[tokio::test]
async fn calls_from_a_tokio_task_wait_without_a_nested_runtime() {
    let Some(db) = database("inside_tokio") else {
        return;
    };
    // The server's start and its admin sessions call the store from tasks.
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(3, 1, "")).unwrap();
    let p = |v: i32| StoredPosition {
        feet: FixedVec3::new(Fixed(v), Fixed(-v), Fixed(2 * v)),
        known_ms: 1_790_000_000_000 + v as u64,
    };
    store
        .save_positions(&[
            ("ana".into(), p(1)),
            ("bo".into(), p(2)),
            ("ana".into(), p(3)),
        ])
        .unwrap();
    let got: Vec<_> = store.player_positions().map(|r| r.unwrap()).collect();
    assert_eq!(got, [("ana".to_string(), p(3)), ("bo".to_string(), p(2))]);
    // Dropped in the task as well.
    drop(store);
}

#[test]
fn check_names_tables_this_layout_does_not_have() {
    let Some(db) = database("check_tables") else {
        return;
    };
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(3, 1, "")).unwrap();
    assert!(store.check().unwrap().is_ok());
    sql(
        &db,
        "CREATE TABLE leftovers (v int); INSERT INTO leftovers VALUES (1), (2)",
    );
    let report = store.check().unwrap();
    let text: Vec<String> = report.issues.iter().map(|i| i.to_string()).collect();
    assert_eq!(
        text,
        ["tree \"leftovers\": 2 orphaned records in a tree this version does not use"]
    );
}

/// A commit that times out waiting for a row lock (another node paused
/// inside its own commit holds the world row) wrote nothing: it is
/// `Uncommitted`, which a cluster node abandons, not an unknown outcome
/// that stops it. The same batch commits once the lock is free.
#[test]
fn a_commit_timed_out_before_commit_was_sent_wrote_nothing() {
    let Some(db) = database("commit_timeout") else {
        return;
    };
    let cfg = PgConfig {
        url: db.url(),
        statement_timeout_ms: 500,
        ..PgConfig::default()
    };
    let store = PgStore::open(&cfg, 8).unwrap();
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    let (release, released) = std::sync::mpsc::channel::<()>();
    let holder = store_common::hold_world_row(&db, "ROLLBACK", move || {
        let _ = released.recv();
    });
    let pos = ChunkPos::new(1, 0, 1);
    let batch = Seq::default().delta_batch(&[vec![(pos, terrain_chunk(1))]]);
    let err = store.commit_batch(&batch).unwrap_err();
    assert!(matches!(err, StoreError::Uncommitted { .. }), "{err}");
    release.send(()).unwrap();
    holder.join().unwrap();
    assert_eq!(store.last_seq().unwrap(), 0);
    assert!(store.load_chunk(pos).unwrap().is_none());
    store.commit_batch(&batch).unwrap();
    assert_eq!(store.last_seq().unwrap(), 1);
}

/// A commit whose `COMMIT` is not answered in time (here a deferred
/// trigger makes `COMMIT` itself outlast the statement timeout) is
/// resolved by PostgreSQL's record of its transaction: the session is
/// ended, the transaction rolled back, and the commit is `Uncommitted`
/// (nothing written), not an unknown outcome that stops the engine.
#[test]
fn a_commit_whose_commit_went_unanswered_is_resolved() {
    let Some(db) = database("commit_unanswered") else {
        return;
    };
    let cfg = PgConfig {
        url: db.url(),
        statement_timeout_ms: 1_000,
        ..PgConfig::default()
    };
    let store = PgStore::open(&cfg, 8).unwrap();
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    sql(
        &db,
        "CREATE FUNCTION slow_commit() RETURNS trigger LANGUAGE plpgsql AS \
         $$ BEGIN PERFORM pg_sleep(30); RETURN NULL; END $$; \
         CREATE CONSTRAINT TRIGGER slow AFTER INSERT ON edit_log \
         DEFERRABLE INITIALLY DEFERRED FOR EACH ROW EXECUTE FUNCTION slow_commit()",
    );
    let pos = ChunkPos::new(1, 0, 1);
    let batch = Seq::default().delta_batch(&[vec![(pos, terrain_chunk(1))]]);
    let err = store.commit_batch(&batch).unwrap_err();
    assert!(matches!(err, StoreError::Uncommitted { .. }), "{err}");
    assert_eq!(sql(&db, "SELECT count(*) FROM edit_log"), ["0"]);
    assert!(store.load_chunk(pos).unwrap().is_none());
    sql(&db, "DROP TRIGGER slow ON edit_log");
    store.commit_batch(&batch).unwrap();
    assert_eq!(store.last_seq().unwrap(), 1);
}

/// On a store never clustered (no seq blocks) the world row's last seq
/// stays exact: a log beyond it is damage that `check` names and that
/// refuses the next commit, changing nothing (a cluster's fenced commits
/// leave the row behind the log, and there the log's last counts).
#[test]
fn a_log_beyond_a_single_nodes_last_seq_is_damage() {
    let Some(db) = database("log_beyond_last_seq") else {
        return;
    };
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(3, 1, "")).unwrap();
    let mut world = Seq::default();
    let pos = ChunkPos::new(1, 0, 1);
    for salt in 1..=2 {
        store
            .commit_batch(&world.delta_batch(&[vec![(pos, terrain_chunk(salt))]]))
            .unwrap();
    }
    assert!(store.check().unwrap().is_ok());
    sql(&db, "UPDATE world SET last_seq = 1");
    let report = store.check().unwrap();
    assert!(
        report
            .issues
            .contains(&strata_server::store::CheckIssue::LastSeqMismatch { meta: 1, log: 2 }),
        "{report:?}"
    );
    let err = store
        .commit_batch(&world.delta_batch(&[vec![(pos, terrain_chunk(3))]]))
        .unwrap_err();
    assert!(
        err.to_string().contains("log record beyond last_seq"),
        "{err}"
    );
    assert_eq!(sql(&db, "SELECT max(seq) FROM edit_log"), ["2"]);
}

/// Commits have a connection of their own: a pool taken up by slow reads
/// (a login storm's position reads, console renders) does not make a
/// commit wait for a connection and time out, which stops the engine.
#[test]
fn a_commit_does_not_wait_for_the_pool() {
    let Some(db) = database("commit_beside_full_pool") else {
        return;
    };
    let cfg = PgConfig {
        url: db.url(),
        max_connections: 1,
        pool_wait_ms: 200,
        ..PgConfig::default()
    };
    let store = Arc::new(PgStore::open(&cfg, 8).unwrap());
    store.init_meta(&WorldMeta::new(1, 1, "")).unwrap();
    let mut seq = Seq::default();
    let pos = ChunkPos::new(0, 0, 0);
    store
        .commit_batch(&seq.batch(&[vec![(pos, terrain_chunk(1))]]))
        .unwrap();
    // The pool's one connection waits on a locked table.
    let (release, holder) =
        store_common::hold_until_told(&db, "LOCK TABLE players IN ACCESS EXCLUSIVE MODE");
    let reader = {
        let store = store.clone();
        std::thread::spawn(move || store.player_positions().count())
    };
    std::thread::sleep(std::time::Duration::from_millis(300));
    let committed = store.commit_batch(&seq.batch(&[vec![(pos, terrain_chunk(2))]]));
    release.send(()).unwrap();
    holder.join().unwrap();
    assert_eq!(reader.join().unwrap(), 0);
    committed.unwrap();
    assert_eq!(store.load_chunk(pos).unwrap().unwrap().version, 2);
}

/// Migrations are not held to the statement timeout meant for a tick's
/// statements (one may rewrite a whole table, once): a fresh database
/// opens under a timeout shorter than applying them all takes.
#[test]
fn migrations_run_past_the_statement_timeout() {
    let Some(db) = database("migrations_past_timeout") else {
        return;
    };
    let cfg = PgConfig {
        url: db.url(),
        statement_timeout_ms: 40,
        ..PgConfig::default()
    };
    let started = std::time::Instant::now();
    let store = PgStore::open(&cfg, 8).unwrap();
    eprintln!("opened and migrated in {:?}", started.elapsed());
    let applied = sql(&db, "SELECT count(*) FROM schema_migrations");
    assert_eq!(applied, [MIGRATIONS.len().to_string()]);
    drop(store);
}

/// A newer build's admin tool may migrate the database between a starting
/// server's migrations and its serving lock (the tool migrates only while
/// no server holds it): the server then refuses to serve, as it refuses to
/// open a database migrated further than it knows.
#[test]
fn a_server_migrated_past_before_it_took_the_lock_refuses_to_serve() {
    let Some(db) = database("migrated_before_serving") else {
        return;
    };
    let store = pg_store(&db);
    sql(
        &db,
        "INSERT INTO schema_migrations (version, name) VALUES (999, 'future')",
    );
    let err = store.serve().unwrap_err();
    assert!(
        matches!(err, StoreError::UnsupportedFormat { found: 999, .. }),
        "{err}"
    );
}
