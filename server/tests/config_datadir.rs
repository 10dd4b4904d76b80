//! Data dir: first-run generation, reuse on later runs, permissions, and
//! refusal of broken layouts.

use std::time::Duration;

use strata_protocol::Role;
use strata_server::auth::{issue, verify, SecretError};
use strata_server::datadir::{DataDir, DataDirError, CERT_NAME, KEY_NAME, SECRET_NAME};
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
