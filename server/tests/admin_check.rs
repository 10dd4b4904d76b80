//! `strata-admin check` on a stopped server's data dir: a clean store
//! passes; damage planted in the raw sled database (as a bad disk or a bug
//! would leave it) fails with a non-zero exit and a line naming each record;
//! a store held open by a running process is refused as locked.

use crate::offline_common;

use std::path::Path;

use offline_common::*;
use strata_server::store::keys::chunk_key;
use strata_server::store::{encode_chunk_value, SledStore, TREE_CHUNKS, TREE_META};
use strata_terrain::material::ids;
use strata_terrain::{Chunk, ChunkPos, Voxel};

fn check(dir: &Path) -> std::process::Output {
    admin(&["check", "--data-dir", dir.to_str().unwrap()])
}

#[test]
fn clean_store_passes_and_planted_damage_is_named() {
    let fx = build();
    let dir = fx.data_dir();
    let clean = ok(&check(dir));
    assert!(clean.contains("checked 3 log entries"), "{clean}");
    assert!(clean.contains("OK: the store is consistent"), "{clean}");

    // An edited chunk, whose record we will corrupt.
    let victim = *fx.deltas.keys().next().unwrap();
    let orphan = ChunkPos::new(50, 0, 50);
    {
        let db = strata_server::store::open_raw(&dir.join("world.sled")).unwrap();
        let chunks = db.open_tree(TREE_CHUNKS).unwrap();
        let stone = Chunk::uniform(Voxel::solid(ids::STONE));
        chunks
            .insert(chunk_key(orphan), encode_chunk_value(1, &stone))
            .unwrap();
        let version = fx.deltas[&victim].0;
        let mut garbage = version.to_be_bytes().to_vec();
        garbage.extend_from_slice(b"\x28\xb5\x2f\xfd not zstd");
        chunks.insert(chunk_key(victim), garbage).unwrap();
        db.open_tree(TREE_META)
            .unwrap()
            .insert("junk", &b"left over"[..])
            .unwrap();
        db.open_tree("stray").unwrap().insert("k", "v").unwrap();
        db.flush().unwrap();
    }
    let out = check(dir);
    assert!(!out.status.success(), "damage gives a non-zero exit");
    let report = String::from_utf8(out.stdout).unwrap();
    let expect = [
        "PROBLEM chunk (50, 0, 50) (version 1): stored but no log entry changed it".to_string(),
        format!(
            "PROBLEM chunk ({}, {}, {}): snapshot does not decode",
            victim.x, victim.y, victim.z
        ),
        "PROBLEM meta key \"junk\": orphaned record".to_string(),
        "PROBLEM tree \"stray\": 1 orphaned records".to_string(),
        "NOT CLEAN: 4 problems".to_string(),
    ];
    for line in &expect {
        assert!(
            report.contains(line.as_str()),
            "{line:?} missing from:\n{report}"
        );
    }
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("not clean (4 problems)"), "{stderr}");
}

#[test]
fn refuses_a_locked_store_and_a_missing_one() {
    let fx = build();
    let held = SledStore::open(&fx.data_dir().join("world.sled")).unwrap();
    let out = check(fx.data_dir());
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("locked") && stderr.contains("stop strata-server"),
        "{stderr}"
    );
    drop(held);

    let empty = tempfile::tempdir().unwrap();
    let out = check(empty.path());
    assert!(String::from_utf8_lossy(&out.stderr).contains("world.sled does not exist"));
    assert!(
        !empty.path().join("world.sled").exists(),
        "check creates nothing"
    );
    let out = check(&empty.path().join("nope"));
    assert!(String::from_utf8_lossy(&out.stderr).contains("does not exist"));
}
