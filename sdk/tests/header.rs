//! include/strata.h must be what cbindgen makes of the code today (CI runs
//! this). `STRATA_BLESS=1` rewrites it instead.

use std::path::Path;

#[test]
fn header_is_current() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(dir.join("cbindgen.toml")).unwrap();
    let bindings = cbindgen::Builder::new()
        .with_config(config)
        .with_src(dir.join("src/lib.rs"))
        .generate()
        .expect("cbindgen reads the crate");
    let mut fresh = Vec::new();
    bindings.write(&mut fresh);
    let path = dir.join("include/strata.h");
    if std::env::var("STRATA_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(&path, &fresh).unwrap();
        return;
    }
    let current = std::fs::read(&path).unwrap_or_default();
    assert!(
        current == fresh,
        "{} is stale; regenerate it with STRATA_BLESS=1 cargo test -p strata-sdk --test integration -- header_is_current",
        path.display()
    );
}

/// No `bool` in the ABI, nor in the Python mirror: C# (Unity) marshals a
/// `bool` field as a 4-byte Win32 BOOL by default, which shifts every field
/// after it. Flags are `uint8_t` (0 or 1) instead.
#[test]
fn no_bool_crosses_the_boundary() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let header = std::fs::read_to_string(root.join("include/strata.h")).unwrap();
    let bools: Vec<&str> = header
        .lines()
        .filter(|l| !l.trim_start().starts_with("//") && l.contains("bool "))
        .collect();
    assert!(bools.is_empty(), "bool in strata.h: {bools:?}");
    let python = root.join("../examples/python/strata_example.py");
    let python = std::fs::read_to_string(python).unwrap();
    assert!(!python.contains("c_bool"), "c_bool in the Python mirror");
}

/// `StrataEvent`'s layout is the ABI: a change must be deliberate (and
/// said in docs/SDK.md), since `strata_poll` writes the whole struct into
/// the caller's. Mirrors check theirs against `strata_event_size`.
#[test]
fn the_event_layout_is_pinned() {
    use std::mem::{offset_of, size_of};
    use strata::StrataEvent;
    assert_eq!(strata::strata_event_size(), size_of::<StrataEvent>());
    assert_eq!(size_of::<StrataEvent>(), 360);
    assert_eq!(offset_of!(StrataEvent, radius), 320);
    assert_eq!(offset_of!(StrataEvent, held), 328);
    assert_eq!(offset_of!(StrataEvent, held_known), 352);
}
