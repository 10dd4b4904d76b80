//! Data dir: first-run generation, reuse on later runs, permissions, and
//! refusal of broken layouts, including a world whose identity files are
//! missing.

use std::time::Duration;

use strata_protocol::Role;
use strata_server::admin::snapshot_cmd::{self, RestoreArgs};
use strata_server::app;
use strata_server::auth::{issue, verify, SecretError};
use strata_server::config::ServerConfig;
use strata_server::datadir::{
    DataDir, DataDirError, CERT_NAME, KEY_NAME, SECRET_NAME, WORLD_DB_NAME,
};
use strata_server::store::{ChunkStore, SledStore, WorldMeta};
use strata_server::tls::{CertPair, TlsError};

#[test]
fn first_run_creates_everything_and_reports_it() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("nested").join("data");
    let (dir, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert_eq!(report.created_dir.as_deref(), Some(root.as_path()));
    assert_eq!(report.created_cert, Some(root.join(CERT_NAME)));
    assert_eq!(report.created_secret, Some(root.join(SECRET_NAME)));
    assert!(report.created_anything());
    let text = report.to_string();
    assert!(text.starts_with("generated "), "{text}");
    assert!(text.contains(&format!(
        "certificate at {}",
        root.join(CERT_NAME).display()
    )));
    assert!(text.contains(&format!(
        "auth secret at {}",
        root.join(SECRET_NAME).display()
    )));

    for name in [CERT_NAME, KEY_NAME, SECRET_NAME] {
        assert!(root.join(name).is_file(), "{name}");
    }
    assert_eq!(dir.root(), root);
    assert_eq!(dir.world_db_path(), root.join("world.sled"));
    assert_eq!(dir.cert_path(), root.join(CERT_NAME));
    assert_eq!(dir.key_path(), root.join(KEY_NAME));
    assert_eq!(dir.secret_path(), root.join(SECRET_NAME));
    assert_eq!(
        std::fs::read(root.join(CERT_NAME)).unwrap(),
        dir.cert().cert_der().as_ref()
    );
}

#[test]
fn second_run_reuses_the_same_files() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    let (first, _) = DataDir::open_or_init(&root, &[]).unwrap();
    let before: Vec<Vec<u8>> = [CERT_NAME, KEY_NAME, SECRET_NAME]
        .iter()
        .map(|n| std::fs::read(root.join(n)).unwrap())
        .collect();

    let (second, report) = DataDir::open_or_init(&root, &["ignored.example".into()]).unwrap();
    assert!(!report.created_anything());
    assert_eq!(report.to_string(), "reused existing data dir");
    let after: Vec<Vec<u8>> = [CERT_NAME, KEY_NAME, SECRET_NAME]
        .iter()
        .map(|n| std::fs::read(root.join(n)).unwrap())
        .collect();
    assert_eq!(before, after);
    assert_eq!(first.cert().cert_der(), second.cert().cert_der());

    // A token minted with the first run's secret verifies after a restart.
    let t = issue(
        first.secret(),
        "zoe",
        Role::Admin,
        Duration::from_secs(60),
        500,
    )
    .unwrap();
    assert_eq!(verify(second.secret(), &t, 501).unwrap().role, Role::Admin);

    let existing = DataDir::open_existing(&root).unwrap();
    assert_eq!(existing.cert().cert_der(), first.cert().cert_der());
}

#[cfg(unix)]
#[test]
fn private_files_are_owner_only() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    DataDir::open_or_init(&root, &[]).unwrap();
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&root.join(SECRET_NAME)), 0o600);
    assert_eq!(mode(&root.join(KEY_NAME)), 0o600);
    assert_eq!(mode(&root), 0o700);
    assert_eq!(mode(&root.join(CERT_NAME)), 0o644);
}

#[test]
fn a_file_in_place_of_the_dir_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("data");
    std::fs::write(&path, "not a dir").unwrap();
    assert!(matches!(
        DataDir::open_or_init(&path, &[]),
        Err(DataDirError::NotADirectory(p)) if p == path
    ));
    assert!(matches!(
        DataDir::open_existing(&path),
        Err(DataDirError::NotADirectory(_))
    ));
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "not a dir");
}

#[test]
fn open_existing_never_creates() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    assert!(matches!(
        DataDir::open_existing(&root),
        Err(DataDirError::Missing(_))
    ));
    assert!(!root.exists());
    std::fs::create_dir(&root).unwrap();
    assert!(matches!(
        DataDir::open_existing(&root),
        Err(DataDirError::Secret(SecretError::Read { .. }))
    ));
    assert!(!root.join(SECRET_NAME).exists());
}

#[test]
fn half_a_certificate_is_refused_not_regenerated() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    DataDir::open_or_init(&root, &[]).unwrap();
    std::fs::remove_file(root.join(KEY_NAME)).unwrap();
    match DataDir::open_or_init(&root, &[]) {
        Err(DataDirError::HalfCertificate { present, missing }) => {
            assert_eq!(present, root.join(CERT_NAME));
            assert_eq!(missing, root.join(KEY_NAME));
        }
        other => panic!("expected HalfCertificate, got {other:?}"),
    }
    assert!(!root.join(KEY_NAME).exists());
}

#[test]
fn a_certificate_save_cut_short_is_finished_at_the_next_start() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    let (first, _) = DataDir::open_or_init(&root, &[]).unwrap();
    // The key was written, the certificate not yet moved into place.
    let staged = strata_server::tls::staged_cert(&root.join(CERT_NAME));
    std::fs::rename(root.join(CERT_NAME), &staged).unwrap();
    // An admin tool reads the pair as it is, and moves nothing.
    let tool = DataDir::open_existing(&root).unwrap();
    assert_eq!(tool.cert().cert_der(), first.cert().cert_der());
    assert!(staged.is_file() && !root.join(CERT_NAME).exists());
    let (dir, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert_eq!(report.created_cert, None, "the same pair, not a new one");
    assert_eq!(dir.cert().cert_der(), first.cert().cert_der());
    assert!(root.join(CERT_NAME).is_file() && !staged.exists());
    // Without the staged certificate, a lone key is refused as before.
    std::fs::remove_file(root.join(CERT_NAME)).unwrap();
    assert!(matches!(
        DataDir::open_or_init(&root, &[]),
        Err(DataDirError::HalfCertificate { .. })
    ));
}

#[test]
fn mismatched_or_corrupt_files_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    DataDir::open_or_init(&root, &[]).unwrap();

    // A key from another certificate.
    let other = tmp.path().join("other");
    DataDir::open_or_init(&other, &[]).unwrap();
    std::fs::copy(other.join(KEY_NAME), root.join(KEY_NAME)).unwrap();
    assert!(matches!(
        DataDir::open_or_init(&root, &[]),
        Err(DataDirError::Tls(TlsError::Rustls(_)))
    ));

    // Garbage key bytes.
    std::fs::write(root.join(KEY_NAME), b"garbage").unwrap();
    assert!(matches!(
        CertPair::load(&root.join(CERT_NAME), &root.join(KEY_NAME)),
        Err(TlsError::Rustls(_))
    ));

    // A corrupt secret.
    std::fs::copy(other.join(KEY_NAME), root.join(KEY_NAME)).unwrap();
    std::fs::copy(other.join(CERT_NAME), root.join(CERT_NAME)).unwrap();
    std::fs::write(root.join(SECRET_NAME), "short\n").unwrap();
    assert!(matches!(
        DataDir::open_or_init(&root, &[]),
        Err(DataDirError::Secret(SecretError::Invalid { .. }))
    ));
}

#[test]
fn a_failed_init_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    let bad = vec!["not a name!".to_string()];
    assert!(matches!(
        DataDir::open_or_init(&root, &bad),
        Err(DataDirError::Tls(TlsError::BadName(n))) if n == "not a name!"
    ));
    assert!(!root.exists());

    // Same with an existing, empty dir: no secret appears.
    std::fs::create_dir(&root).unwrap();
    assert!(DataDir::open_or_init(&root, &bad).is_err());
    assert_eq!(std::fs::read_dir(&root).unwrap().count(), 0);
}

#[test]
fn only_missing_pieces_are_generated() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    DataDir::open_or_init(&root, &[]).unwrap();
    let secret_before = std::fs::read(root.join(SECRET_NAME)).unwrap();
    std::fs::remove_file(root.join(CERT_NAME)).unwrap();
    std::fs::remove_file(root.join(KEY_NAME)).unwrap();

    let (_, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert_eq!(report.created_dir, None);
    assert_eq!(report.created_secret, None);
    assert_eq!(report.created_cert, Some(root.join(CERT_NAME)));
    assert_eq!(
        report.to_string(),
        format!(
            "generated certificate at {}",
            root.join(CERT_NAME).display()
        )
    );
    assert_eq!(
        std::fs::read(root.join(SECRET_NAME)).unwrap(),
        secret_before
    );
}

/// A data dir as a server leaves it: identity files and a world store.
fn data_dir_with_world(root: &std::path::Path) {
    let (dir, _) = DataDir::open_or_init(root, &[]).unwrap();
    let store = SledStore::open(&dir.world_db_path()).unwrap();
    store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
}

fn files(root: &std::path::Path) -> Vec<std::ffi::OsString> {
    let mut names: Vec<_> = std::fs::read_dir(root)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    names.sort();
    names
}

#[test]
fn a_world_without_its_secret_is_refused_not_given_a_new_one() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    data_dir_with_world(&root);
    std::fs::remove_file(root.join(SECRET_NAME)).unwrap();
    let before = files(&root);
    let err = DataDir::open_or_init(&root, &[]).unwrap_err();
    assert!(
        matches!(&err, DataDirError::MissingSecret { missing, world }
            if *missing == root.join(SECRET_NAME)
                && *world == root.join(WORLD_DB_NAME).display().to_string()),
        "{err:?}"
    );
    let msg = err.to_string();
    for part in [SECRET_NAME, "every token", "Restore", "from a backup"] {
        assert!(msg.contains(part), "{part:?} not in {msg}");
    }
    assert_eq!(files(&root), before, "nothing was written");
}

#[test]
fn a_world_without_its_certificate_is_refused_not_given_a_new_one() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    data_dir_with_world(&root);
    std::fs::remove_file(root.join(CERT_NAME)).unwrap();
    std::fs::remove_file(root.join(KEY_NAME)).unwrap();
    let before = files(&root);
    let err = DataDir::open_or_init(&root, &["x.example".into()]).unwrap_err();
    assert!(
        matches!(&err, DataDirError::MissingCertificate { cert, key, .. }
            if *cert == root.join(CERT_NAME) && *key == root.join(KEY_NAME)),
        "{err:?}"
    );
    let msg = err.to_string();
    for part in [CERT_NAME, KEY_NAME, "pinned", "from a backup"] {
        assert!(msg.contains(part), "{part:?} not in {msg}");
    }
    assert_eq!(files(&root), before, "nothing was written");

    // With the files back the world opens as before.
    data_dir_with_world(&tmp.path().join("other"));
    for name in [CERT_NAME, KEY_NAME] {
        std::fs::copy(tmp.path().join("other").join(name), root.join(name)).unwrap();
    }
    let (_, report) = DataDir::open_or_init(&root, &[]).unwrap();
    assert!(!report.created_anything(), "{report}");
}

#[test]
fn the_server_refuses_to_start_on_a_world_without_its_secret() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    data_dir_with_world(&root);
    std::fs::remove_file(root.join(SECRET_NAME)).unwrap();
    let mut cfg = ServerConfig::default();
    cfg.apply_overrides(Some(root.clone()), Some("127.0.0.1:0".parse().unwrap()));
    let rt = tokio::runtime::Runtime::new().unwrap();
    let err = match rt.block_on(app::start(cfg)) {
        Ok(_) => panic!("started without auth.secret"),
        Err(e) => format!("{e:#}"),
    };
    assert!(err.contains("auth.secret is missing"), "{err}");
    assert!(!root.join(SECRET_NAME).exists());
}

#[test]
fn forced_restore_into_a_data_dir_keeps_its_identity() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    data_dir_with_world(&root);
    let snap = tmp.path().join("w.snap");
    // A killed run's unfinished snapshot of the same name (its process
    // gone: no pid is that large) is removed by the next one.
    let stale = tmp.path().join(format!("w.snap.{}-0.partial", u32::MAX));
    std::fs::write(&stale, b"half a snapshot").unwrap();
    {
        let store = SledStore::open(&root.join(WORLD_DB_NAME)).unwrap();
        snapshot_cmd::create_offline(&store, &snap, &Default::default()).unwrap();
    }
    assert!(!stale.exists());
    let identity = |root: &std::path::Path| {
        [CERT_NAME, KEY_NAME, SECRET_NAME].map(|n| std::fs::read(root.join(n)).unwrap())
    };
    let before = identity(&root);
    let args = RestoreArgs {
        drop_access: false,
        file: snap,
        data_dir: root.clone(),
        force: true,
        config: None,
    };
    snapshot_cmd::restore(&args).unwrap();
    assert_eq!(identity(&root), before);
    assert!(DataDir::open_or_init(&root, &[]).is_ok());

    // Without its secret the world is not replaced and no secret appears.
    std::fs::remove_file(root.join(SECRET_NAME)).unwrap();
    let err = format!("{:#}", snapshot_cmd::restore(&args).unwrap_err());
    assert!(err.contains("auth.secret is missing"), "{err}");
    assert!(!root.join(SECRET_NAME).exists());
    let store = SledStore::open(&root.join(WORLD_DB_NAME)).unwrap();
    assert_eq!(store.load_meta().unwrap().unwrap().seed, 7);
}

/// An offline snapshot of a world whose zones were never changed holds the
/// spawn protection its server applies (the default zones), and a restore
/// of it keeps that protection.
#[test]
fn an_offline_snapshot_keeps_the_default_spawn_protection() {
    use strata_server::app::ZONES_BLOB;
    use strata_server::sequencer::Sequencer;
    use strata_server::validate::zones::Zone;
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    data_dir_with_world(&root);
    let snap = tmp.path().join("w.snap");
    let cfg = ServerConfig::default();
    {
        let store = SledStore::open(&root.join(WORLD_DB_NAME)).unwrap();
        assert_eq!(store.get_blob(ZONES_BLOB).unwrap(), None, "never changed");
        snapshot_cmd::create_offline(&store, &snap, &cfg).unwrap();
    }
    let spawn = Sequencer::default_zones(&cfg.validation);
    assert_eq!(spawn.len(), 1, "the spawn protection");
    let header = strata_server::snapshot::SnapshotReader::open(&snap)
        .unwrap()
        .header()
        .clone();
    let names = |zones: &[String]| zones.to_vec();
    assert_eq!(
        names(
            &header
                .zones
                .iter()
                .map(|z| z.name.clone())
                .collect::<Vec<_>>()
        ),
        names(&spawn.iter().map(|z| z.name.clone()).collect::<Vec<_>>())
    );
    let other = tmp.path().join("other");
    snapshot_cmd::restore(&RestoreArgs {
        drop_access: false,
        file: snap,
        data_dir: other.clone(),
        force: false,
        config: None,
    })
    .unwrap();
    let store = SledStore::open(&other.join(WORLD_DB_NAME)).unwrap();
    let stored: Vec<Zone> =
        serde_json::from_slice(&store.get_blob(ZONES_BLOB).unwrap().unwrap()).unwrap();
    assert_eq!(stored.len(), 1);
    assert_eq!((stored[0].min, stored[0].max), (spawn[0].min, spawn[0].max));
}

/// The offline tools open a sled data dir's store only if a server made
/// one: a data dir without `world.sled` (never started, or a PostgreSQL
/// server's without its strata.toml) is refused, and none is created.
#[test]
fn offline_tools_make_no_store_in_a_data_dir_without_one() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("data");
    DataDir::open_or_init(&root, &[]).unwrap();
    let err = match strata_server::admin::remote::open_offline_store(&root) {
        Ok(_) => panic!("opened a store that was not there"),
        Err(e) => format!("{e:#}"),
    };
    assert!(err.contains("does not exist"), "{err}");
    assert!(!root.join(WORLD_DB_NAME).exists());
}

#[test]
fn a_node_of_a_postgres_world_without_its_identity_files_is_refused() {
    let Some(db) = strata_tests::postgres::database("datadir_pg_identity") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let config = |root: &std::path::Path| {
        let mut cfg = ServerConfig::default();
        cfg.apply_overrides(
            Some(root.to_path_buf()),
            Some("127.0.0.1:0".parse().unwrap()),
        );
        cfg.store.backend = strata_server::store::StoreBackend::Postgres;
        cfg.store.postgres.url = db.url();
        cfg
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    // The first node makes the world and the identity files.
    let first = tmp.path().join("node-1");
    let running = rt.block_on(app::start(config(&first))).unwrap();
    rt.block_on(running.shutdown()).unwrap();
    // A second node started before they were copied to it: refused, and
    // nothing written (its own secret would sign tickets nobody accepts).
    let second = tmp.path().join("node-2");
    let err = match rt.block_on(app::start(config(&second))) {
        Ok(_) => panic!("started with a new auth.secret beside a world"),
        Err(e) => format!("{e:#}"),
    };
    assert!(err.contains("auth.secret is missing"), "{err}");
    assert!(err.contains("PostgreSQL"), "{err}");
    assert!(!second.exists(), "nothing was written");
    // With node 1's files it starts, and makes none of its own.
    std::fs::create_dir(&second).unwrap();
    for name in [SECRET_NAME, CERT_NAME, KEY_NAME] {
        std::fs::copy(first.join(name), second.join(name)).unwrap();
    }
    let running = rt.block_on(app::start(config(&second))).unwrap();
    rt.block_on(running.shutdown()).unwrap();
    for name in [SECRET_NAME, CERT_NAME, KEY_NAME] {
        assert_eq!(
            std::fs::read(first.join(name)).unwrap(),
            std::fs::read(second.join(name)).unwrap()
        );
    }
}
