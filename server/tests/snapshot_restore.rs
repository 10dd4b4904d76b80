//! Restoring snapshots: a restore cut short leaves the old world as it
//! was, and a store holding records without metadata is not taken for a
//! new world; headers this build cannot serve, zones `ZoneAdd` would
//! refuse and chunks in a seq-0 snapshot fail verification, and restore
//! refuses them before touching the data dir; a PostgreSQL restore is one
//! transaction (cut short, it leaves the old world), a forced one leaves
//! no stale seq blocks and is refused while a node runs.

use crate::snapshot_common;
use crate::store_common;

use std::path::{Path, PathBuf};

use snapshot_common::{header, write_noise_snapshot, write_snapshot};
use store_common::{pg_store, sql, terrain_chunk};
use strata_protocol::admin::ZoneSpec;
use strata_server::admin::snapshot_cmd::{self, replace_world, RestoreArgs};
use strata_server::app::ZONES_BLOB;
use strata_server::auth::ACCESS_BLOB;
use strata_server::cluster::ClusterConfig;
use strata_server::datadir::WORLD_DB_NAME;
use strata_server::sequencer::regions::{RegionId, DEFAULT_REGION_CHUNKS};
use strata_server::snapshot::restore::import;
use strata_server::snapshot::{verify, SnapshotHeader};
use strata_server::store::pg::{PgConfig, SERVING_LOCK};
use strata_server::store::{
    open_store, persisted_segment_size, with_suffix, ChunkStore, ImportTarget, PgStore, RawChunk,
    RegionAccess, SledStore, StoreConfig, StoreError, WorldMeta, MAX_GENERATOR_PARAMS_BYTES,
    REPLACED_SUFFIX, RESTORING_SUFFIX,
};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::gen::GenParams;
use strata_terrain::{ChunkPos, VoxelPos};
use strata_tests::postgres::database;

/// The offline target: the stopped server's data dir `data`.
fn offline(data: &Path) -> strata_server::admin::remote::TargetArgs {
    strata_server::admin::remote::TargetArgs {
        data_dir: Some(data.to_path_buf()),
        server: None,
        cert: None,
        token: None,
        token_file: None,
    }
}

/// `n` chunks in a row, at versions 1..=n.
fn chunks(n: i32) -> Vec<(ChunkPos, u64)> {
    (0..n)
        .map(|i| (ChunkPos::new(i, 1, 0), 1 + i as u64))
        .collect()
}

fn snapshot(dir: &Path, name: &str, h: &SnapshotHeader, n: i32) -> PathBuf {
    let path = dir.join(name);
    write_snapshot(&path, h, &chunks(n));
    path
}

fn restore(file: &Path, data: &Path, force: bool) -> anyhow::Result<u64> {
    snapshot_cmd::restore(&RestoreArgs {
        drop_access: false,
        file: file.into(),
        data_dir: data.into(),
        force,
        config: None,
    })
}

/// The data dir's world as (last_seq, chunks); its store checks clean.
fn world_of(data: &Path) -> (u64, u64) {
    let store = SledStore::open(&data.join(WORLD_DB_NAME)).unwrap();
    let report = store.check().unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
    let seq = store.load_meta().unwrap().expect("a world").last_seq;
    (seq, store.chunk_count().unwrap())
}

/// Names in `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Every issue `verify` reports, joined.
fn issues(file: &Path) -> String {
    let report = verify(file, |_| {}).unwrap();
    assert!(!report.is_ok(), "verify passed");
    report.issues.join("\n")
}

/// Passes the chunks through, then fails where the metadata would be
/// written: an import cut short (disk full, Ctrl-C) after its chunks.
struct CutBeforeMeta<'a>(&'a dyn ImportTarget);

impl ImportTarget for CutBeforeMeta<'_> {
    fn begin_import(&self) -> Result<(), StoreError> {
        self.0.begin_import()
    }

    fn import_chunks(&self, chunks: &[RawChunk]) -> Result<(), StoreError> {
        self.0.import_chunks(chunks)
    }

    fn finish_import(&self, _: &WorldMeta, _: &str, _: &[u8]) -> Result<(), StoreError> {
        Err(StoreError::Io(std::io::Error::other(
            "no space left on device",
        )))
    }
}

/// The restore's swap with an import that fails part-way.
fn restore_cut_short(db: &Path, file: &Path) -> String {
    let err = replace_world(db, &StoreConfig::default(), false, |store| {
        Ok(import(file, &CutBeforeMeta(store), ZONES_BLOB, |_| {})?)
    })
    .unwrap_err();
    format!("{err:#}")
}

/// A data dir in `dir` restored from a snapshot at seq 9 (3 chunks), a
/// snapshot at seq 20 (5 chunks) beside it, and the data dir's world.
fn old_sled_world(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let old = snapshot(dir, "old.snap", &header(9), 3);
    let new = snapshot(dir, "new.snap", &header(20), 5);
    let data = dir.join("data");
    assert_eq!(restore(&old, &data, false).unwrap(), 3);
    let db = data.join(WORLD_DB_NAME);
    (new, data, db)
}

#[test]
fn a_restore_cut_short_leaves_the_old_world() {
    let tmp = tempfile::tempdir().unwrap();
    let (new, data, db) = old_sled_world(tmp.path());

    let err = restore_cut_short(&db, &new);
    assert!(
        err.contains("no space left") && err.contains("is unchanged"),
        "{err}"
    );
    assert_eq!(world_of(&data), (9, 3));
    assert!(
        !with_suffix(&db, RESTORING_SUFFIX).exists(),
        "staging removed"
    );

    // A crash between the swap's renames left the old world aside, no
    // restored one beside it: the next open puts the old world back (it
    // never makes an empty one in its place)...
    std::fs::rename(&db, with_suffix(&db, REPLACED_SUFFIX)).unwrap();
    drop(open_store(&StoreConfig::default(), &db, DEFAULT_REGION_CHUNKS, None).unwrap());
    assert_eq!(world_of(&data), (9, 3));
    assert!(!with_suffix(&db, REPLACED_SUFFIX).exists());
    // ...and with the restored world synced beside it, moves that into
    // place and removes the old one, as the restore would have.
    let other = tmp.path().join("other");
    assert_eq!(restore(&new, &other, false).unwrap(), 5);
    std::fs::rename(
        other.join(WORLD_DB_NAME),
        with_suffix(&db, RESTORING_SUFFIX),
    )
    .unwrap();
    std::fs::rename(&db, with_suffix(&db, REPLACED_SUFFIX)).unwrap();
    drop(open_store(&StoreConfig::default(), &db, DEFAULT_REGION_CHUNKS, None).unwrap());
    assert_eq!(world_of(&data), (20, 5));
    assert!(!with_suffix(&db, REPLACED_SUFFIX).exists());
    assert!(!with_suffix(&db, RESTORING_SUFFIX).exists());
    // The next restore (of the old world's snapshot) goes ahead as usual.
    restore_cut_short(&db, &new);
    assert_eq!(world_of(&data), (20, 5));

    // A whole restore replaces the world and leaves nothing beside it.
    let before = listing(&data);
    assert_eq!(restore(&new, &data, true).unwrap(), 5);
    assert_eq!(world_of(&data), (20, 5));
    assert_eq!(listing(&data), before);
}

#[test]
fn a_restore_refuses_a_world_a_server_or_tool_has_open() {
    let tmp = tempfile::tempdir().unwrap();
    let (new, data, db) = old_sled_world(tmp.path());
    // Open as a server opens it.
    let open = open_store(&StoreConfig::default(), &db, DEFAULT_REGION_CHUNKS, None).unwrap();
    let err = format!("{:#}", restore(&new, &data, true).unwrap_err());
    assert!(
        err.contains("in use by another process") && err.contains("is unchanged"),
        "{err}"
    );
    assert_eq!(open.load_meta().unwrap().unwrap().last_seq, 9);
    // Nor may a second holder open it meanwhile.
    let err = open_store(&StoreConfig::default(), &db, DEFAULT_REGION_CHUNKS, None)
        .map(|_| ())
        .unwrap_err();
    assert!(matches!(err, StoreError::WorldInUse { .. }), "{err}");
    drop(open);
    assert_eq!(world_of(&data), (9, 3));
    // Closed, the restore goes through.
    assert_eq!(restore(&new, &data, true).unwrap(), 5);
    assert_eq!(world_of(&data), (20, 5));
}

#[test]
fn a_restore_keeps_bans_and_answers_to_the_data_dirs_config() {
    let tmp = tempfile::tempdir().unwrap();
    let (new, data, db) = old_sled_world(tmp.path());
    let store = SledStore::open(&db).unwrap();
    store.put_blob(ACCESS_BLOB, b"bans").unwrap();
    store.put_blob("other", b"x").unwrap();
    drop(store);
    // A config of another seed in the data dir: its server would refuse
    // the world, so nothing is restored.
    let other_seed = GenParams {
        seed: GenParams::default().seed + 1,
        ..GenParams::default()
    };
    let config = format!(
        "[world.generator]\n{}",
        toml::to_string(&other_seed).unwrap()
    );
    std::fs::write(data.join("strata.toml"), &config).unwrap();
    let before = listing(&data);
    let err = format!("{:#}", restore(&new, &data, true).unwrap_err());
    assert!(
        err.contains("would refuse this snapshot's world") && err.contains("seed"),
        "{err}"
    );
    assert_eq!(listing(&data), before);
    assert_eq!(world_of(&data), (9, 3));
    // With the world's own config, the restore goes through and keeps
    // the bans and revocations (the snapshot holds none).
    std::fs::remove_file(data.join("strata.toml")).unwrap();
    assert_eq!(restore(&new, &data, true).unwrap(), 5);
    assert_eq!(world_of(&data), (20, 5));
    let store = SledStore::open(&db).unwrap();
    assert_eq!(store.get_blob(ACCESS_BLOB).unwrap().unwrap(), b"bans");
    assert_eq!(store.get_blob("other").unwrap(), None);
    assert!(store.get_blob(ZONES_BLOB).unwrap().is_some());
}

/// A replaced world that does not read (a damaged store) cannot give its
/// bans and revocations to the restored one: the restore refuses it, and
/// `--drop-access` restores without them.
#[test]
fn a_restore_over_a_world_that_does_not_read_keeps_it_unless_told() {
    let tmp = tempfile::tempdir().unwrap();
    let (new, data, db) = old_sled_world(tmp.path());
    // sled's config file, damaged: the store no longer opens.
    std::fs::write(db.join("conf"), b"\x00 not a sled config \xff").unwrap();
    assert!(SledStore::open(&db).is_err(), "the damaged store opens");
    let args = |drop_access| RestoreArgs {
        file: new.clone(),
        data_dir: data.clone(),
        force: true,
        drop_access,
        config: None,
    };
    let err = format!("{:#}", snapshot_cmd::restore(&args(false)).unwrap_err());
    assert!(err.contains("--drop-access"), "{err}");
    assert!(
        SledStore::open(&db).is_err(),
        "the old world stays as it was"
    );
    assert_eq!(snapshot_cmd::restore(&args(true)).unwrap(), 5);
    assert_eq!(world_of(&data), (20, 5));
    let store = SledStore::open(&db).unwrap();
    assert_eq!(store.get_blob(ACCESS_BLOB).unwrap(), None);
}

/// A store holding a chunk with no metadata: `init_meta` must refuse.
fn refuses_records_without_meta(store: &dyn ChunkStore) {
    match store.init_meta(&WorldMeta::new(7, 1, "")) {
        Err(StoreError::InvalidMeta { reason }) => {
            assert!(reason.contains("interrupted restore"), "{reason}")
        }
        other => panic!("expected InvalidMeta, got {other:?}"),
    }
    assert!(store.load_meta().unwrap().is_none(), "no world written");
}

#[test]
fn init_meta_refuses_a_store_with_chunks_but_no_metadata() {
    let tmp = tempfile::tempdir().unwrap();
    let sled = SledStore::open(tmp.path()).unwrap();
    let raw = RawChunk {
        pos: ChunkPos::new(1, 0, 2),
        version: 4,
        encoded: encode_chunk(&terrain_chunk(3)),
    };
    sled.begin_import().unwrap();
    sled.import_chunks(&[raw]).unwrap();
    refuses_records_without_meta(&sled);
    if let Some(db) = database("init_meta_refuses_a_store_with_chunks_but_no_metadata") {
        // A restore commits its chunks with the world row, so only an
        // older build's restore cut short could leave this.
        let pg = pg_store(&db);
        sql(
            &db,
            "INSERT INTO chunks (x, y, z, region_x, region_z, version, body) \
             VALUES (1, 0, 2, 0, 0, 4, '\\x00')",
        );
        refuses_records_without_meta(&pg);
    }
}

#[test]
fn a_header_this_build_cannot_serve_is_refused_before_the_data_dir_is_touched() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    restore(
        &snapshot(tmp.path(), "old.snap", &header(9), 3),
        &data,
        false,
    )
    .unwrap();
    let before = listing(&data);

    let mut h = header(20);
    h.generator_version += 1;
    let bad = snapshot(tmp.path(), "next-gen.snap", &h, 2);
    let want = format!(
        "generator version {} is not the one this build runs",
        h.generator_version
    );
    assert!(issues(&bad).contains(&want), "{}", issues(&bad));
    let err = format!("{:#}", restore(&bad, &data, true).unwrap_err());
    assert!(err.contains(&want), "{err}");
    assert_eq!(listing(&data), before);
    assert_eq!(world_of(&data), (9, 3));
    let fresh = tmp.path().join("fresh");
    restore(&bad, &fresh, false).unwrap_err();
    assert!(!fresh.exists(), "nothing created");

    // Parameters that do not parse, or are over the limit.
    let too_long = "#".repeat(MAX_GENERATOR_PARAMS_BYTES + 1);
    for (params, want) in [
        ("seed = \"one\"\n", "generator params are not valid"),
        (too_long.as_str(), "generator params are 65537 bytes"),
    ] {
        let mut h = header(20);
        h.generator_params = params.into();
        let bad = snapshot(tmp.path(), "params.snap", &h, 1);
        assert!(issues(&bad).contains(want), "{}", issues(&bad));
        restore(&bad, &data, true).unwrap_err();
        assert_eq!(world_of(&data), (9, 3));
    }
}

#[test]
fn zones_zone_add_would_refuse_fail_verify() {
    let tmp = tempfile::tempdir().unwrap();
    let zone = |name: &str, min, max| ZoneSpec {
        name: name.into(),
        min,
        max,
    };
    let (o, one) = (VoxelPos::new(0, 0, 0), VoxelPos::new(1, 1, 1));
    for (zones, want) in [
        (
            vec![zone("a", VoxelPos::new(5, 0, 0), o)],
            "zone 0 (\"a\"): zone min is above max",
        ),
        (
            vec![zone("a", o, one), zone("a", o, one)],
            "zone 1 (\"a\"): zone \"a\" already exists",
        ),
        (vec![zone("", o, one)], "zone name must be 1..=64 bytes"),
    ] {
        let mut h = header(9);
        h.zones = zones;
        let bad = snapshot(tmp.path(), "zones.snap", &h, 1);
        assert!(issues(&bad).contains(want), "{}", issues(&bad));
        let data = tmp.path().join("data");
        restore(&bad, &data, false).unwrap_err();
        assert!(!data.exists());
    }
}

#[test]
fn a_seq_0_snapshot_holding_chunks_fails_verify() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = snapshot(tmp.path(), "seq0.snap", &header(0), 2);
    let report = verify(&bad, |_| {}).unwrap();
    assert_eq!(report.issues.len(), 2, "{:?}", report.issues);
    assert!(
        report.issues[0].starts_with("record 0 at byte")
            && report.issues[0].contains("a snapshot at seq 0 holds no modified chunk"),
        "{:?}",
        report.issues
    );
    let data = tmp.path().join("data");
    restore(&bad, &data, false).unwrap_err();
    assert!(!data.exists());

    // Without chunks, seq 0 is a fresh world.
    let empty = snapshot(tmp.path(), "empty.snap", &header(0), 0);
    assert_eq!(restore(&empty, &data, false).unwrap(), 0);
    assert_eq!(world_of(&data), (0, 0));
}

#[test]
fn a_forced_postgres_restore_leaves_no_stale_seq_blocks() {
    let Some(db) = database("a_forced_postgres_restore_leaves_no_stale_seq_blocks") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let file = snapshot(tmp.path(), "world.snap", &header(9), 3);
    let config = tmp.path().join("strata.toml");
    std::fs::write(&config, db.store_toml()).unwrap();
    let args = |force| RestoreArgs {
        drop_access: false,
        file: file.clone(),
        data_dir: tmp.path().join("data"),
        force,
        config: Some(config.clone()),
    };
    // A cluster node reserves its block of seqs above the world's last_seq.
    let reserve = || {
        let pg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let cluster = ClusterConfig {
            node_id: "a".into(),
            ..ClusterConfig::default()
        };
        PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster)
            .unwrap()
            .reserve_seqs(9)
    };
    assert_eq!(snapshot_cmd::restore(&args(false)).unwrap(), 3);
    assert_eq!(reserve().unwrap(), 9);
    assert_eq!(sql(&db, "SELECT count(*) FROM seq_blocks"), ["1"]);
    let err = snapshot_cmd::restore(&args(false)).unwrap_err().to_string();
    assert!(err.contains("--force"), "{err}");

    // Bans and revocations stay; the old world's other blobs go.
    let store = pg_store(&db);
    store.put_blob(ACCESS_BLOB, b"bans").unwrap();
    store.put_blob("other", b"x").unwrap();
    drop(store);
    assert_eq!(snapshot_cmd::restore(&args(true)).unwrap(), 3);
    let store = pg_store(&db);
    assert_eq!(store.get_blob(ACCESS_BLOB).unwrap().unwrap(), b"bans");
    assert_eq!(store.get_blob("other").unwrap(), None);
    drop(store);
    // The restored world's first block starts where the old one's did:
    // the old block's row is gone, so reserving it again works.
    assert_eq!(reserve().unwrap(), 9);
    assert_eq!(sql(&db, "SELECT count(*) FROM seq_blocks"), ["1"]);
    let report = pg_store(&db).check().unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
}

/// The PostgreSQL world as (last_seq, chunks); its store checks clean.
fn pg_world(db: &strata_tests::postgres::PgDb) -> (String, String) {
    let report = pg_store(db).check().unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
    (
        sql(db, "SELECT last_seq FROM world").concat(),
        sql(db, "SELECT count(*) FROM chunks").concat(),
    )
}

/// `db` holding an old world (seq 9, 3 chunks) restored from a snapshot in
/// `dir`; returns a newer snapshot (seq 20, 5 chunks) beside it.
fn old_world_restored(db: &strata_tests::postgres::PgDb, dir: &Path) -> PathBuf {
    let old = snapshot(dir, "old.snap", &header(9), 3);
    let new = snapshot(dir, "new.snap", &header(20), 5);
    assert_eq!(pg_restore(db, dir, &old, false).unwrap(), 3);
    new
}

/// `restore` of `file` into `db`'s store, through the admin command.
fn pg_restore(
    db: &strata_tests::postgres::PgDb,
    tmp: &Path,
    file: &Path,
    force: bool,
) -> anyhow::Result<u64> {
    let config = tmp.join("strata.toml");
    std::fs::write(&config, db.store_toml()).unwrap();
    snapshot_cmd::restore(&RestoreArgs {
        drop_access: false,
        file: file.into(),
        data_dir: tmp.join("data"),
        force,
        config: Some(config),
    })
}

/// A restore into a database that holds a world, through a data dir
/// without that world's certificate and secret (a new node's), is refused
/// without `--force` before anything is made there; with it (a lost node's
/// recovery) the world is replaced and the data dir gets new ones.
#[test]
fn a_postgres_restore_beside_a_world_makes_nothing_unless_forced() {
    let Some(db) = database("a_postgres_restore_beside_a_world_makes_nothing") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let new = old_world_restored(&db, tmp.path());
    let config = tmp.path().join("strata.toml");
    let node = tmp.path().join("node2");
    let restore = |force| {
        snapshot_cmd::restore(&RestoreArgs {
            drop_access: false,
            file: new.clone(),
            data_dir: node.clone(),
            force,
            config: Some(config.clone()),
        })
    };
    let err = format!("{:#}", restore(false).unwrap_err());
    assert!(err.contains("already holds a world"), "{err}");
    assert!(!node.exists(), "nothing made");
    assert_eq!(pg_world(&db).0, "9", "the old world stays");
    assert_eq!(restore(true).unwrap(), 5);
    assert!(node.join("auth.secret").exists() && node.join("cert.der").exists());
    assert_eq!(pg_world(&db).0, "20");
}

#[test]
fn a_postgres_restore_cut_short_leaves_the_old_world() {
    let Some(db) = database("a_postgres_restore_cut_short_leaves_the_old_world") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let new = old_world_restored(&db, tmp.path());
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));

    // Replacing: the tables are emptied and the new chunks written inside
    // the transaction, which the failure rolls back. (Named as the admin
    // tools name their connections, as a restore's is.)
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let store = PgStore::open(&cfg.for_admin(), DEFAULT_REGION_CHUNKS).unwrap();
    let err = import(
        &new,
        &CutBeforeMeta(&store.import_in_one_transaction(true)),
        ZONES_BLOB,
        |_| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("no space left"), "{err}");
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    assert_eq!(sql(&db, "SELECT count(*) FROM blobs"), ["1"], "zones kept");

    // Nothing of the failed transaction holds the tables: a whole
    // restore replaces the world.
    assert_eq!(pg_restore(&db, tmp.path(), &new, true).unwrap(), 5);
    assert_eq!(pg_world(&db), ("20".into(), "5".into()));
}

#[test]
fn a_forced_postgres_restore_waits_for_no_running_node() {
    let Some(db) = database("a_forced_postgres_restore_waits_for_no_running_node") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let new = old_world_restored(&db, tmp.path());
    // Without --force: refused, saying why.
    let err = format!(
        "{:#}",
        pg_restore(&db, tmp.path(), &new, false).unwrap_err()
    );
    assert!(
        err.contains("its world table is not empty") && err.contains("--force"),
        "{err}"
    );

    // A node killed while holding a region's lease: refused, with its
    // name, until the lease runs out.
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let cluster = ClusterConfig {
        node_id: "west".into(),
        ..ClusterConfig::default()
    };
    let node = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster).unwrap();
    node.register_node().unwrap();
    let region = RegionId { x: 0, z: 0 };
    assert_eq!(
        node.acquire_regions(&[region].into_iter().collect())
            .unwrap(),
        RegionAccess::Granted
    );
    let epoch = sql(&db, "SELECT epoch FROM regions").concat();
    drop(node);
    let err = format!("{:#}", pg_restore(&db, tmp.path(), &new, true).unwrap_err());
    assert!(
        err.contains("leased by running nodes")
            && err.contains("\"west\"")
            && err.contains("stop every node first")
            && err.contains("unchanged"),
        "{err}"
    );
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    // Refused, a lost node's empty data dir gets no new identity (which
    // would have to be copied to every node, voiding their tokens).
    let lost = tmp.path().join("lost");
    let refused = snapshot_cmd::restore(&RestoreArgs {
        drop_access: false,
        file: new.clone(),
        data_dir: lost.clone(),
        force: true,
        config: Some(tmp.path().join("strata.toml")),
    });
    assert!(refused.is_err());
    assert!(!lost.exists(), "nothing made in {}", lost.display());
    sql(
        &db,
        "UPDATE regions SET lease_expires = now() - interval '1 second'",
    );

    // A running server (a store open, named as the server names its
    // connections): refused once its sessions stayed past the wait.
    let running = pg_store(&db);
    let err = format!("{:#}", pg_restore(&db, tmp.path(), &new, true).unwrap_err());
    assert!(
        err.contains("sessions of a running strata-server")
            && err.contains("stop every node first"),
        "{err}"
    );
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    drop(running);

    // A running server whose connections are named otherwise (its URL
    // says so) still holds the database while it serves it.
    let named_otherwise = PgStore::open(
        &PgConfig {
            url: format!("{} application_name=game", db.url()),
            ..PgConfig::default()
        },
        DEFAULT_REGION_CHUNKS,
    )
    .unwrap();
    named_otherwise.serve().unwrap();
    let err = format!("{:#}", pg_restore(&db, tmp.path(), &new, true).unwrap_err());
    assert!(
        err.contains("a running server holds this database") && err.contains("unchanged"),
        "{err}"
    );
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    named_otherwise.close().unwrap();
    drop(named_otherwise);

    // Something else using the world's tables: refused after a bounded
    // wait, the world unchanged.
    let (done_tx, holder) =
        store_common::hold_until_told(&db, "LOCK TABLE chunks IN ACCESS SHARE MODE");
    let err = format!("{:#}", pg_restore(&db, tmp.path(), &new, true).unwrap_err());
    done_tx.send(()).unwrap();
    holder.join().unwrap();
    assert!(
        err.contains("stayed in use") && err.contains("stop every node first"),
        "{err}"
    );
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));

    // A server stopping as the restore begins: its sessions leave within
    // the wait, and the restore goes ahead.
    let stopping = pg_store(&db);
    assert!(stopping.holds_world().unwrap().is_some());
    let stopped = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_secs(1));
        drop(stopping);
    });
    let started = std::time::Instant::now();
    assert_eq!(pg_restore(&db, tmp.path(), &new, true).unwrap(), 5);
    assert!(
        started.elapsed() >= std::time::Duration::from_millis(900),
        "the restore waited for the stopping server"
    );
    stopped.join().unwrap();
    assert_eq!(pg_world(&db), ("20".into(), "5".into()));
    // The region row stays, freed at a higher epoch: a node paused across
    // the restore is fenced, not let write at the epoch it had.
    let before: i64 = epoch.parse().unwrap();
    assert_eq!(sql(&db, "SELECT owner IS NULL FROM regions"), ["t"]);
    assert_eq!(
        sql(&db, "SELECT epoch FROM regions"),
        [(before + 1).to_string()]
    );
}

#[test]
fn failed_postgres_restores_give_their_one_connection_back() {
    let Some(db) = database("failed_postgres_restores_give_their_one_connection_back") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let new = old_world_restored(&db, tmp.path());
    // One connection, and little patience for a free one: a connection a
    // restore kept would fail every call after it.
    let cfg = PgConfig {
        url: db.url(),
        max_connections: 1,
        pool_wait_ms: 500,
        ..PgConfig::default()
    };
    let store = PgStore::open(&cfg.for_admin(), DEFAULT_REGION_CHUNKS).unwrap();

    // Refused at its start (the store holds a world).
    let err = import(
        &new,
        &store.import_in_one_transaction(false),
        ZONES_BLOB,
        |_| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("not empty"), "{err}");
    // Failed by PostgreSQL part-way, after the tables were emptied: a
    // batch holding one chunk twice.
    let twice = RawChunk {
        pos: ChunkPos::new(1, 0, 2),
        version: 4,
        encoded: encode_chunk(&terrain_chunk(3)),
    };
    let target = store.import_in_one_transaction(true);
    target.begin_import().unwrap();
    let err = target.import_chunks(&[twice.clone(), twice]).unwrap_err();
    assert!(err.to_string().contains("duplicate key"), "{err}");
    let err = target.finish_import(&WorldMeta::new(1, 1, ""), ZONES_BLOB, b"[]");
    assert!(err.is_err(), "the failed transaction's connection is gone");
    assert!(!target.commit_unknown());
    drop(target);
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));

    // The one connection serves a whole restore, and calls after it.
    let n = import(
        &new,
        &store.import_in_one_transaction(true),
        ZONES_BLOB,
        |_| {},
    )
    .unwrap();
    assert_eq!(n, 5);
    assert_eq!(
        store.holds_world().unwrap().as_deref(),
        Some("its world table is not empty")
    );
    assert_eq!(pg_world(&db), ("20".into(), "5".into()));
}

#[test]
fn a_postgres_restore_whose_commit_postgres_refuses_is_unchanged() {
    let Some(db) = database("a_postgres_restore_whose_commit_postgres_refuses_is_unchanged") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let new = old_world_restored(&db, tmp.path());
    // A check PostgreSQL runs only at COMMIT, refusing the new world row.
    sql(
        &db,
        "CREATE FUNCTION refuse_seq_20() RETURNS trigger LANGUAGE plpgsql AS $$ \
         BEGIN IF NEW.last_seq = 20 THEN RAISE EXCEPTION 'refused at commit'; END IF; \
         RETURN NEW; END $$; \
         CREATE CONSTRAINT TRIGGER refuse_seq_20 AFTER INSERT ON world \
         DEFERRABLE INITIALLY DEFERRED FOR EACH ROW EXECUTE FUNCTION refuse_seq_20()",
    );
    let err = format!("{:#}", pg_restore(&db, tmp.path(), &new, true).unwrap_err());
    assert!(
        err.contains("refused at commit") && err.contains("is unchanged"),
        "{err}"
    );
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
}

#[test]
fn a_server_does_not_start_on_a_database_a_restore_is_replacing() {
    let Some(db) = database("a_server_does_not_start_on_a_database_a_restore_is_replacing") else {
        return;
    };
    // A store opened before a restore's transaction took the lock alone.
    let store = pg_store(&db);
    let (done_tx, restoring) = store_common::hold_until_told(
        &db,
        &format!("SELECT pg_advisory_xact_lock({SERVING_LOCK})"),
    );
    let err = store.serve().unwrap_err().to_string();
    assert!(err.contains("a restore is replacing"), "{err}");
    // Opened during the restore, its migrations refuse at once.
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let err = PgStore::open(&cfg, DEFAULT_REGION_CHUNKS)
        .unwrap_err()
        .to_string();
    assert!(err.contains("a restore is replacing"), "{err}");
    done_tx.send(()).unwrap();
    restoring.join().unwrap();
    // Once it is done, a server takes the database; a second one without
    // `[cluster]` is refused (neither's commits are fenced).
    store.serve().unwrap();
    let err = pg_store(&db).serve().unwrap_err().to_string();
    assert!(err.contains("must be alone on it"), "{err}");
    // Gone (its session ends a moment later), it leaves the database free.
    drop(store);
    let next = pg_store(&db);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while let Err(e) = next.serve() {
        assert!(std::time::Instant::now() < deadline, "{e}");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

#[test]
fn an_offline_postgres_snapshot_and_running_servers_keep_off_each_other() {
    let Some(db) = database("an_offline_postgres_snapshot_and_running_servers") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let file = snapshot(tmp.path(), "world.snap", &header(9), 3);
    std::fs::create_dir_all(&data).unwrap();
    std::fs::write(data.join("strata.toml"), db.store_toml()).unwrap();
    // The data dir's config names the database: the restore goes there.
    let args = RestoreArgs {
        drop_access: false,
        file,
        data_dir: data.clone(),
        force: false,
        config: None,
    };
    assert_eq!(snapshot_cmd::restore(&args).unwrap(), 3);
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    let create = |out: &str| {
        snapshot_cmd::create(&snapshot_cmd::CreateArgs {
            config: None,
            out: tmp.path().join(out),
            target: offline(&data),
            max_pending_chunks: 0,
        })
    };
    // A running server: the offline snapshot is refused.
    let server = pg_store(&db);
    server.serve().unwrap();
    let err = format!("{:#}", create("a.snap").unwrap_err());
    assert!(err.contains("a running server"), "{err}");
    drop(server);
    // During an offline snapshot no server starts.
    let snapshotting = pg_store(&db);
    snapshotting.hold_alone().unwrap();
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let err = PgStore::open(&cfg, DEFAULT_REGION_CHUNKS)
        .and_then(|s| s.serve())
        .unwrap_err()
        .to_string();
    assert!(err.contains("an offline snapshot"), "{err}");
    // Its session ends a moment after it is dropped.
    drop(snapshotting);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let created = loop {
        match create("b.snap") {
            Ok(c) => break c,
            Err(e) if std::time::Instant::now() < deadline => {
                assert!(format!("{e:#}").contains("an offline snapshot"), "{e:#}");
                std::thread::sleep(std::time::Duration::from_millis(50));
            }
            Err(e) => panic!("{e:#}"),
        }
    };
    assert_eq!((created.seq, created.chunks), (9, 3));
}

/// An offline snapshot whose lock connection ended (a PostgreSQL restart,
/// a terminated backend) let servers in meanwhile: it is refused, not
/// written as one moment of the world.
#[test]
fn an_offline_postgres_snapshot_that_lost_its_lock_is_refused() {
    let Some(db) = database("an_offline_postgres_snapshot_that_lost_its_lock") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    old_world_restored(&db, tmp.path());
    let store = pg_store(&db);
    store.hold_alone().unwrap();
    store.still_alone().unwrap();
    let out = tmp.path().join("held.snap");
    snapshot_cmd::create_offline(&store, &out, &Default::default()).unwrap();
    sql(
        &db,
        &format!(
            "SELECT pg_terminate_backend(l.pid) FROM pg_locks l \
             JOIN pg_database d ON d.oid = l.database \
             WHERE l.locktype = 'advisory' AND d.datname = '{}' \
             AND l.pid <> pg_backend_pid()",
            db.name()
        ),
    );
    let started = std::time::Instant::now();
    while store.still_alone().is_ok() {
        assert!(
            started.elapsed() < std::time::Duration::from_secs(10),
            "the loss is seen"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let lost = tmp.path().join("lost.snap");
    let err = format!(
        "{:#}",
        snapshot_cmd::create_offline(&store, &lost, &Default::default()).unwrap_err()
    );
    assert!(err.contains("keeping servers off"), "{err}");
    assert!(!lost.exists(), "no snapshot file");
}

#[test]
fn a_server_with_a_migration_pending_says_a_restore_is_running_at_once() {
    let Some(db) = database("a_server_with_a_migration_pending_says_a_restore_is_running") else {
        return;
    };
    // A database migrated before 0008 (players without known_ms).
    drop(pg_store(&db));
    sql(
        &db,
        "DROP TABLE nodes; ALTER TABLE players DROP COLUMN known_ms; \
         ALTER TABLE world DROP COLUMN generation; \
         ALTER TABLE seq_blocks DROP COLUMN pruned_to, DROP COLUMN last_seq; \
         DROP INDEX seq_blocks_node, seq_blocks_reserved_at; \
         ALTER TABLE regions DROP COLUMN wanted_by, DROP COLUMN wanted_at; \
         DELETE FROM schema_migrations WHERE version >= 8",
    );
    // A forced restore's transaction: the lock alone, the tables locked.
    let (done_tx, restoring) = store_common::hold_until_told(
        &db,
        &format!(
            "SELECT pg_advisory_xact_lock({SERVING_LOCK}); \
             LOCK TABLE world, chunks, players IN ACCESS EXCLUSIVE MODE"
        ),
    );
    let cfg = PgConfig {
        url: db.url(),
        statement_timeout_ms: 60_000,
        ..PgConfig::default()
    };
    let started = std::time::Instant::now();
    let err = PgStore::open(&cfg, DEFAULT_REGION_CHUNKS)
        .unwrap_err()
        .to_string();
    // Not after the statement timeout, waiting on the restore's tables.
    assert!(err.contains("a restore is replacing"), "{err}");
    assert!(started.elapsed() < std::time::Duration::from_secs(30));
    done_tx.send(()).unwrap();
    restoring.join().unwrap();
    // Once it is done, the migrations run.
    pg_store(&db).serve().unwrap();
    let newest = strata_server::store::pg::MIGRATIONS.last().unwrap().0;
    assert_eq!(
        sql(&db, "SELECT max(version) FROM schema_migrations"),
        [newest.to_string()]
    );
}

#[test]
fn a_server_whose_lock_connection_ended_takes_the_lock_again_at_its_next_commit() {
    let Some(db) = database("a_server_whose_lock_connection_ended_takes_the_lock_again") else {
        return;
    };
    let store = pg_store(&db);
    store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
    store.serve().unwrap();
    let holders = &format!("SELECT count(*) {}", store_common::SERVING_LOCK_ROWS);
    assert_eq!(sql(&db, holders), ["1"]);
    // Its backend ended (an operator's pg_terminate_backend, a restart).
    sql(
        &db,
        &format!(
            "SELECT pg_terminate_backend(pid) {}",
            store_common::SERVING_LOCK_ROWS
        ),
    );
    let started = std::time::Instant::now();
    while sql(&db, holders) != ["0"] {
        assert!(started.elapsed() < std::time::Duration::from_secs(10));
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // The next commit sees the connection gone and takes the lock again.
    let mut seq = store_common::Seq::default();
    let pos = ChunkPos::new(1, 0, 2);
    let started = std::time::Instant::now();
    loop {
        store
            .commit_batch(&seq.batch(&[vec![(pos, terrain_chunk(3))]]))
            .unwrap();
        if sql(&db, holders) == ["1"] {
            break;
        }
        // The client learns of the end when its connection task does.
        assert!(started.elapsed() < std::time::Duration::from_secs(10));
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Ends every session on `db` but this test's own, and waits until they
/// are gone.
fn end_other_sessions(db: &strata_tests::postgres::PgDb) {
    let others = format!(
        "FROM pg_stat_activity WHERE datname = '{}' AND pid <> pg_backend_pid()",
        db.name()
    );
    sql(db, &format!("SELECT pg_terminate_backend(pid) {others}"));
    let started = std::time::Instant::now();
    while sql(db, &format!("SELECT count(*) {others}")) != ["0"] {
        assert!(started.elapsed() < std::time::Duration::from_secs(10));
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// A server alone on its database whose connections ended let a restore
/// in: its next commit is refused, even where the restored world
/// ends at the very seq the server is at (its seqs follow on), and writes
/// nothing. The restored world has an id of its own.
#[test]
fn a_commit_into_a_world_restored_under_the_server_is_refused() {
    let Some(db) = database("a_commit_into_a_world_restored_under_the_server") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    old_world_restored(&db, tmp.path());
    let store = pg_store(&db);
    store.serve().unwrap();
    let meta = store.load_meta().unwrap().unwrap();
    assert_eq!(meta.last_seq, 9);
    // As a server gives it: the world it would make.
    let meta = WorldMeta {
        last_seq: 0,
        ..meta
    };
    store.init_meta(&meta).unwrap();
    let served = store.world_id().expect("read at init_meta");
    // Every connection of the server's ended (a partition PostgreSQL
    // timed out; the process itself went on), so a restore sees none.
    end_other_sessions(&db);
    // The same snapshot again: a world at seq 9, as the server's.
    let old = tmp.path().join("old.snap");
    assert_eq!(pg_restore(&db, tmp.path(), &old, true).unwrap(), 3);
    let mut seq = store_common::Seq {
        last_seq: 9,
        ..Default::default()
    };
    let batch = seq.batch(&[vec![(ChunkPos::new(5, 1, 0), terrain_chunk(3))]]);
    let err = store.commit_batch(&batch).unwrap_err();
    assert!(matches!(err, StoreError::WorldReplaced { .. }), "{err}");
    assert!(err.to_string().contains("restart the server"), "{err}");
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    assert_eq!(sql(&db, "SELECT count(*) FROM edit_log"), ["0"]);
    let restored = pg_store(&db);
    restored.init_meta(&meta).unwrap();
    assert_ne!(restored.world_id().unwrap(), served);
}

/// A cluster node cut off from the database across a restore commits
/// nothing into the restored world, and is told the world was replaced
/// (which stops its engine), not only that a region was taken (after
/// which it would claim the region again and go on, its seqs, positions
/// and zones those of the old world).
#[test]
fn a_cluster_nodes_commit_into_a_world_restored_under_it_is_refused() {
    let Some(db) = database("a_cluster_nodes_commit_into_a_world_restored_under_it") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    old_world_restored(&db, tmp.path());
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    // No renewal within the test: the node is cut off from the database.
    let cluster = ClusterConfig {
        node_id: "a".into(),
        lease_ms: 120_000,
        renew_ms: 60_000,
        ..ClusterConfig::default()
    };
    let node = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster).unwrap();
    node.serve().unwrap();
    let meta = WorldMeta {
        last_seq: 0,
        ..node.load_meta().unwrap().unwrap()
    };
    node.init_meta(&meta).unwrap();
    let mut seq = store_common::Seq {
        last_seq: node.reserve_seqs(9).unwrap(),
        ..Default::default()
    };
    let pos = ChunkPos::new(5, 1, 0);
    node.commit_batch(&seq.batch(&[vec![(pos, terrain_chunk(3))]]))
        .unwrap();
    end_other_sessions(&db);
    // Its lease ran out meanwhile.
    sql(
        &db,
        "UPDATE regions SET lease_expires = now() - interval '1 second'",
    );
    let old = tmp.path().join("old.snap");
    assert_eq!(pg_restore(&db, tmp.path(), &old, true).unwrap(), 3);
    let err = node
        .commit_batch(&seq.batch(&[vec![(pos, terrain_chunk(4))]]))
        .unwrap_err();
    assert!(matches!(err, StoreError::WorldReplaced { .. }), "{err}");
    assert_eq!(pg_world(&db), ("9".into(), "3".into()));
    assert_eq!(sql(&db, "SELECT count(*) FROM edit_log"), ["0"]);
}

/// An offline snapshot with `--config` naming the database snapshots the
/// database's world, not a `world.sled` left in the data dir from before a
/// move to PostgreSQL.
#[test]
fn offline_tools_take_the_store_the_config_names() {
    let Some(db) = database("offline_tools_take_the_store_the_config_names") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    // The sled world it had (seq 9), then the database's (seq 20).
    let old = snapshot(tmp.path(), "old.snap", &header(9), 3);
    assert_eq!(restore(&old, &data, false).unwrap(), 3);
    let new = snapshot(tmp.path(), "new.snap", &header(20), 5);
    assert_eq!(pg_restore(&db, tmp.path(), &new, false).unwrap(), 5);
    let config = tmp.path().join("strata.toml");
    let out = tmp.path().join("backup.snap");
    let created = snapshot_cmd::create(&snapshot_cmd::CreateArgs {
        config: Some(config),
        out: out.clone(),
        target: offline(&data),
        max_pending_chunks: 0,
    })
    .unwrap();
    assert_eq!((created.seq, created.chunks), (20, 5));
}

/// Offline `zones add` with no `--config` starts from the zones the data
/// dir's own `strata.toml` gives a world that never stored any (here: no
/// spawn protection), as the server would, not from the built-in ones.
#[test]
fn offline_zones_start_from_the_data_dirs_config() {
    use strata_server::admin::zones_cmd::{self, ZoneAddArgs, ZonesCommand};
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let old = snapshot(tmp.path(), "old.snap", &header(9), 3);
    assert_eq!(restore(&old, &data, false).unwrap(), 3);
    // A world whose zones never changed: none stored.
    let db = strata_server::store::open_raw(&data.join(WORLD_DB_NAME)).unwrap();
    let blobs = db.open_tree(strata_server::store::TREE_BLOBS).unwrap();
    blobs.remove(ZONES_BLOB.as_bytes()).unwrap();
    db.flush().unwrap();
    drop((blobs, db));
    std::fs::write(
        data.join("strata.toml"),
        "[validation]\nspawn_protection_radius = 0\n",
    )
    .unwrap();
    let add = ZonesCommand::Add(ZoneAddArgs {
        name: "arena".into(),
        min: vec![0, 0, 0],
        max: vec![4, 4, 4],
        target: offline(&data),
        config: None,
    });
    let zones = zones_cmd::run(&add).unwrap();
    let names: Vec<&str> = zones.iter().map(|z| z.name.as_str()).collect();
    assert_eq!(names, ["arena"]);
}

/// A snapshot written whole but not renamed into place (`--out` names a
/// directory) leaves no `.partial` file beside it.
#[test]
fn a_snapshot_not_renamed_into_place_leaves_no_partial_file() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let old = snapshot(tmp.path(), "old.snap", &header(9), 3);
    assert_eq!(restore(&old, &data, false).unwrap(), 3);
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("keep"), b"x").unwrap();
    let before = listing(tmp.path());
    let err = snapshot_cmd::create(&snapshot_cmd::CreateArgs {
        config: None,
        out: out.clone(),
        target: offline(&data),
        max_pending_chunks: 0,
    })
    .unwrap_err();
    assert!(format!("{err:#}").contains("renaming into"), "{err:#}");
    assert_eq!(listing(tmp.path()), before);
}

/// A restore cut short after the data dir got its certificate and secret
/// (no world yet) is tried again with `--force` and no config: restored.
#[test]
fn a_restore_into_a_data_dir_without_its_world_is_tried_again() {
    let tmp = tempfile::tempdir().unwrap();
    let (new, data, db) = old_sled_world(tmp.path());
    std::fs::remove_dir_all(&db).unwrap();
    assert_eq!(restore(&new, &data, true).unwrap(), 5);
    assert_eq!(world_of(&data), (20, 5));
}

/// How long a restore onto a full disk may take to fail.
const FULL_DISK_FAILS_WITHIN: std::time::Duration = std::time::Duration::from_secs(60);

/// A small tmpfs, unmounted when dropped; `None` where mounting is not
/// allowed (not root, a container without the capability): the test then
/// says it did not run, and fails under CI (`strata_tests::not_run`).
struct SmallDisk(PathBuf);

impl SmallDisk {
    fn mount(dir: &Path, size: &str) -> Option<SmallDisk> {
        let at = dir.join("small-disk");
        std::fs::create_dir(&at).unwrap();
        let mounted = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o"])
            .arg(format!("size={size}"))
            .arg("tmpfs")
            .arg(&at)
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        mounted.then_some(SmallDisk(at))
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount")
            .arg("-l")
            .arg(&self.0)
            .status();
    }
}

/// A restore whose new store fills the disk fails with the disk's error
/// and lets go of the world (sled 0.34 can leave a flush waiting forever
/// after a write error, and dropping the store flushed), leaving the old
/// world as it was.
#[test]
fn a_restore_onto_a_full_disk_fails_and_leaves_the_old_world() {
    let tmp = tempfile::tempdir().unwrap();
    let Some(disk) = SmallDisk::mount(tmp.path(), "3m") else {
        let _: Option<()> = strata_tests::not_run(
            "a_restore_onto_a_full_disk_fails_and_leaves_the_old_world",
            "a 3 MiB tmpfs",
            "mount -t tmpfs failed (it needs root)",
        );
        return;
    };
    let small = snapshot(tmp.path(), "small.snap", &header(9), 3);
    let big = tmp.path().join("big.snap");
    write_noise_snapshot(&big, &header(20), 60);
    let data = disk.0.join("data");
    assert_eq!(restore(&small, &data, false).unwrap(), 3);
    let (tx, rx) = std::sync::mpsc::channel();
    let d = data.clone();
    std::thread::spawn(move || {
        let _ = tx.send(restore(&big, &d, true).map_err(|e| format!("{e:#}")));
    });
    let result = rx
        .recv_timeout(FULL_DISK_FAILS_WITHIN)
        .expect("the restore returned");
    let err = result.unwrap_err();
    assert!(err.contains("is unchanged"), "{err}");
    assert_eq!(world_of(&data), (9, 3));
    assert!(!with_suffix(&data.join(WORLD_DB_NAME), RESTORING_SUFFIX).exists());
}

/// The restored store is made as the config's `[store]` says: its segment
/// size (recorded for good when a store is made) is the config's.
#[test]
fn a_restore_makes_its_store_as_the_config_says() {
    let tmp = tempfile::tempdir().unwrap();
    let file = snapshot(tmp.path(), "s.snap", &header(9), 3);
    let config = tmp.path().join("strata.toml");
    let segment = 8 << 20;
    std::fs::write(
        &config,
        format!("[store]\nsegment_size_bytes = {segment}\n"),
    )
    .unwrap();
    let data = tmp.path().join("data");
    let restored = snapshot_cmd::restore(&RestoreArgs {
        drop_access: false,
        file,
        data_dir: data.clone(),
        force: false,
        config: Some(config),
    });
    assert_eq!(restored.unwrap(), 3);
    let db = data.join(WORLD_DB_NAME);
    assert_eq!(persisted_segment_size(&db), Some(segment));
    assert_ne!(segment, StoreConfig::default().segment_size_bytes);
    assert_eq!(world_of(&data), (9, 3));
}
