//! Snapshot files: one corrupt byte in a chunk record is named by record
//! and position (library and CLI), restore refuses it, truncation is
//! caught, and diff lists exactly the chunks that differ.

use crate::snapshot_common::header;

use std::process::Command;

use strata_server::snapshot::diff::diff;
use strata_server::snapshot::{verify, SnapshotWriter};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkGenerator, ChunkPos};

/// Writes real generated chunks (dense ones, near the surface) at the given versions.
fn write(path: &std::path::Path, seq: u64, chunks: &[(ChunkPos, u64)]) -> Vec<u64> {
    let g = Generator::fractal(GenParams::default()).unwrap();
    let mut w = SnapshotWriter::new(std::fs::File::create(path).unwrap(), &header(seq)).unwrap();
    let mut offsets = Vec::new();
    let mut at = header(seq).encode().unwrap().len() as u64;
    for &(pos, v) in chunks {
        let bytes = encode_chunk(&g.generate(pos));
        offsets.push(at);
        at += (25 + bytes.len() + 8) as u64;
        w.chunk(pos, v, &bytes).unwrap();
    }
    w.finish().unwrap();
    offsets
}

#[test]
fn corrupt_byte_is_named_and_restore_refuses() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good.snap");
    let chunks: Vec<(ChunkPos, u64)> = (0..4)
        .map(|i| (ChunkPos::new(i, 1, 0), 1 + i as u64))
        .collect();
    let offsets = write(&good, 9, &chunks);
    let report = verify(&good, |_| {}).unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
    assert_eq!(report.chunks, 4);

    // Flip one byte inside record 2's payload.
    let mut bytes = std::fs::read(&good).unwrap();
    bytes[offsets[2] as usize + 40] ^= 0x01;
    let bad = tmp.path().join("bad.snap");
    std::fs::write(&bad, &bytes).unwrap();
    let report = verify(&bad, |_| {}).unwrap();
    assert!(!report.is_ok());
    assert!(
        report.issues[0].starts_with(&format!(
            "record 2 at byte {} (chunk (2, 1, 0)): checksum mismatch",
            offsets[2]
        )),
        "{:?}",
        report.issues
    );
    assert!(report
        .issues
        .iter()
        .any(|i| i.contains("file checksum mismatch")));
    assert_eq!(report.chunks, 3, "the other records still check");

    let exe = env!("CARGO_BIN_EXE_strata-admin");
    let out = Command::new(exe)
        .args(["snapshot", "verify"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("record 2 at byte") && stdout.contains("chunk (2, 1, 0)"),
        "{stdout}"
    );
    let target = tmp.path().join("restored");
    let out = Command::new(exe)
        .args(["snapshot", "restore"])
        .arg(&bad)
        .arg("--data-dir")
        .arg(&target)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("record 2"));
    assert!(!target.exists(), "nothing was written");

    // Truncation is caught at the footer.
    let cut = tmp.path().join("cut.snap");
    std::fs::write(&cut, &bytes[..offsets[3] as usize]).unwrap();
    let report = verify(&cut, |_| {}).unwrap();
    assert!(
        report.issues.iter().any(|i| i.contains("truncated")),
        "{:?}",
        report.issues
    );

    // A good snapshot restores into a data dir whose store checks clean.
    let out = Command::new(exe)
        .args(["snapshot", "restore"])
        .arg(&good)
        .arg("--data-dir")
        .arg(&target)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new(exe)
        .args(["inspect", "chunk", "3", "1", "0", "--data-dir"])
        .arg(&target)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("version: 4") && text.contains("state: modified"),
        "{text}"
    );
    let out = Command::new(exe)
        .args(["stats", "--data-dir"])
        .arg(&target)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("seq: 9") && text.contains("modified_chunks: 4"),
        "{text}"
    );
}

#[test]
fn diff_lists_changed_added_and_removed_chunks() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a.snap");
    let b = tmp.path().join("b.snap");
    let p = |x| ChunkPos::new(x, 1, 0);
    write(&a, 5, &[(p(0), 1), (p(1), 1), (p(2), 3)]);
    write(&b, 7, &[(p(0), 1), (p(2), 4), (p(3), 1)]);
    let d = diff(&a, &b).unwrap();
    assert!(d.same_world);
    assert_eq!((d.seq_a, d.seq_b), (5, 7));
    let listed: Vec<(ChunkPos, Option<u64>, Option<u64>)> = d
        .chunks
        .iter()
        .map(|c| (c.pos, c.a.map(|s| s.0), c.b.map(|s| s.0)))
        .collect();
    assert_eq!(
        listed,
        vec![
            (p(1), Some(1), None),
            (p(2), Some(3), Some(4)),
            (p(3), None, Some(1))
        ]
    );
}
