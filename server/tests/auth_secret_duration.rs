//! The auth secret's file form and the `--ttl` duration parser.

use std::time::Duration;

use strata_protocol::Role;
use strata_server::auth::{
    format_duration, issue, parse_duration, verify, DurationError, HumanDuration, Secret,
    SecretError, SecretFile, MAX_DURATION,
};

#[test]
fn durations_parse_with_each_unit() {
    assert_eq!(parse_duration("30s"), Ok(Duration::from_secs(30)));
    assert_eq!(parse_duration("15m"), Ok(Duration::from_secs(900)));
    assert_eq!(parse_duration("12h"), Ok(Duration::from_secs(43_200)));
    assert_eq!(parse_duration("7d"), Ok(Duration::from_secs(604_800)));
    assert_eq!(parse_duration(" 7d\n"), Ok(Duration::from_secs(604_800)));
}

#[test]
fn bad_durations_have_typed_errors() {
    assert_eq!(parse_duration(""), Err(DurationError::Empty));
    assert_eq!(parse_duration("   "), Err(DurationError::Empty));
    assert_eq!(
        parse_duration("30"),
        Err(DurationError::MissingUnit("30".into()))
    );
    assert_eq!(
        parse_duration("5w"),
        Err(DurationError::UnknownUnit {
            input: "5w".into(),
            unit: "w".into()
        })
    );
    assert!(matches!(
        parse_duration("5 s"),
        Err(DurationError::UnknownUnit { .. })
    ));
    assert!(matches!(
        parse_duration("1.5h"),
        Err(DurationError::UnknownUnit { .. })
    ));
    assert!(matches!(
        parse_duration("5ms"),
        Err(DurationError::UnknownUnit { .. })
    ));
    assert_eq!(
        parse_duration("h"),
        Err(DurationError::BadNumber("h".into()))
    );
    assert_eq!(
        parse_duration("-5s"),
        Err(DurationError::BadNumber("-5s".into()))
    );
    assert_eq!(parse_duration("0s"), Err(DurationError::Zero));
    assert_eq!(parse_duration("0d"), Err(DurationError::Zero));
    assert!(matches!(
        parse_duration("36501d"),
        Err(DurationError::TooLong(_))
    ));
    assert!(matches!(
        parse_duration("99999999999999999999999s"),
        Err(DurationError::TooLong(_))
    ));
    assert!(matches!(
        parse_duration("999999999999999999d"),
        Err(DurationError::TooLong(_))
    ));
}

#[test]
fn durations_format_and_round_trip() {
    for (secs, text) in [
        (30, "30s"),
        (90, "90s"),
        (900, "15m"),
        (3_600, "1h"),
        (5_400, "90m"),
        (86_400, "1d"),
        (30 * 86_400, "30d"),
    ] {
        let d = Duration::from_secs(secs);
        assert_eq!(format_duration(d), text);
        assert_eq!(parse_duration(text), Ok(d));
        assert_eq!(HumanDuration(d).to_string(), text);
    }
    assert_eq!(
        parse_duration(&format_duration(MAX_DURATION)),
        Ok(MAX_DURATION)
    );
}

#[test]
fn secret_survives_a_save_load_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("auth.secret");
    let secret = Secret::generate().unwrap();
    secret.save(&path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(text.len(), 65, "64 hex characters and a newline");
    assert!(text.trim_end().bytes().all(|b| b.is_ascii_hexdigit()));

    let loaded = Secret::load(&path).unwrap();
    let t = issue(&secret, "kim", Role::Player, Duration::from_secs(60), 1000).unwrap();
    assert_eq!(verify(&loaded, &t, 1001).unwrap().player, "kim");
}

#[cfg(unix)]
#[test]
fn secret_file_is_owner_only() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("auth.secret");
    // A stale, world-readable temp file from a crash must not leak its mode.
    std::fs::write(dir.path().join("auth.secret.tmp"), "junk").unwrap();
    std::fs::set_permissions(
        dir.path().join("auth.secret.tmp"),
        std::fs::Permissions::from_mode(0o666),
    )
    .unwrap();
    Secret::generate().unwrap().save(&path).unwrap();
    let mode = std::fs::metadata(&path).unwrap().permissions().mode();
    assert_eq!(mode & 0o777, 0o600);
    assert!(!dir.path().join("auth.secret.tmp").exists());
}

#[test]
fn bad_secret_files_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("auth.secret");
    assert!(matches!(Secret::load(&path), Err(SecretError::Read { .. })));
    for (content, reason) in [
        (&b"abcd\n"[..], "expected 64 hex characters"),
        (&[b'z'; 64][..], "not hexadecimal"),
        (&[0xff, 0xfe][..], "not text"),
    ] {
        std::fs::write(&path, content).unwrap();
        match Secret::load(&path) {
            Err(SecretError::Invalid { reason: r, .. }) => assert_eq!(r, reason),
            other => panic!("expected Invalid({reason}), got {other:?}"),
        }
    }
    std::fs::write(&path, vec![b'0'; 100_000]).unwrap();
    assert!(matches!(Secret::load(&path), Err(SecretError::Read { .. })));
}

#[test]
fn secret_debug_does_not_leak_key_bytes() {
    let s = Secret::from_bytes([0xab; 32]);
    let shown = format!("{s:?}");
    assert_eq!(shown, "Secret(..)");
}
