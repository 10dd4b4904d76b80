//! Runs the real `strata-admin` binary as a child process on generated
//! volume files: output formats, the `--stats` line, and every bad-input
//! case exiting non-zero with a message naming the problem.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use strata_server::admin::obj::read_obj;
use strata_server::admin::ply::read_ply;

const BIN: &str = env!("CARGO_BIN_EXE_strata-admin");
const DIMS: [u32; 3] = [40, 24, 36];

/// Rolling ground: solid below a height that varies with x and z.
fn write_volume(dir: &Path) -> PathBuf {
    let mut v = Vec::new();
    for z in 0..DIMS[2] {
        for y in 0..DIMS[1] {
            for x in 0..DIMS[0] {
                let h = 8 + (x % 13) as i32 / 2 + (z % 7) as i32;
                v.push((128 + (h - y as i32) * 24).clamp(0, 255) as u8);
            }
        }
    }
    let path = dir.join("ground.raw");
    std::fs::write(&path, v).unwrap();
    path
}

fn run(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("strata-admin runs")
}

fn dims_args() -> Vec<String> {
    DIMS.iter().map(|d| d.to_string()).collect()
}

fn mesh(volume: &Path, extra: &[&str]) -> Output {
    let dims = dims_args();
    let mut args = vec!["mesh", "--volume", volume.to_str().unwrap(), "--dims"];
    args.extend(dims.iter().map(String::as_str));
    args.extend(extra);
    run(&args)
}

fn stats_of(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(
        stdout.lines().count(),
        1,
        "exactly one stats line: {stdout:?}"
    );
    serde_json::from_str(stdout.trim()).expect("stats line is JSON")
}

#[test]
fn stats_line_and_ply_output() {
    let dir = tempfile::tempdir().unwrap();
    let vol = write_volume(dir.path());
    let ply = dir.path().join("ground.ply");
    let out = mesh(
        &vol,
        &["--threads", "2", "--stats", "--out", ply.to_str().unwrap()],
    );
    let stats = stats_of(&out);
    let keys: Vec<&str> = stats
        .as_object()
        .unwrap()
        .keys()
        .map(String::as_str)
        .collect();
    assert_eq!(keys.len(), 5);
    for k in ["cells", "vertices", "triangles", "mesh_seconds", "threads"] {
        assert!(keys.contains(&k), "missing {k}");
    }
    assert_eq!(stats["cells"], 39 * 23 * 35);
    assert_eq!(stats["threads"], 2);
    assert!(stats["mesh_seconds"].as_f64().unwrap() >= 0.0);
    let mesh = read_ply(&std::fs::read(&ply).unwrap()).expect("PLY parses");
    assert_eq!(
        mesh.positions.len() as u64,
        stats["vertices"].as_u64().unwrap()
    );
    assert_eq!(
        mesh.indices.len() as u64,
        3 * stats["triangles"].as_u64().unwrap()
    );
    assert!(mesh.indices.len() > 100);
    assert!(mesh.materials.iter().all(|&m| m == mesh.materials[0]));
}

#[test]
fn obj_output_matches_ply_and_thread_counts_agree() {
    let dir = tempfile::tempdir().unwrap();
    let vol = write_volume(dir.path());
    let (ply, obj) = (dir.path().join("a.ply"), dir.path().join("b.OBJ"));
    let one = stats_of(&mesh(
        &vol,
        &["--threads", "1", "--stats", "--out", ply.to_str().unwrap()],
    ));
    let two = stats_of(&mesh(
        &vol,
        &["--threads", "2", "--stats", "--out", obj.to_str().unwrap()],
    ));
    for k in ["cells", "vertices", "triangles"] {
        assert_eq!(one[k], two[k], "{k}");
    }
    let ply2 = dir.path().join("c.ply");
    stats_of(&mesh(
        &vol,
        &["--threads", "2", "--stats", "--out", ply2.to_str().unwrap()],
    ));
    assert_eq!(
        std::fs::read(&ply).unwrap(),
        std::fs::read(&ply2).unwrap(),
        "1 and 2 threads write identical bytes"
    );
    let p = read_ply(&std::fs::read(&ply).unwrap()).unwrap();
    let o = read_obj(&std::fs::read_to_string(&obj).unwrap()).expect("OBJ parses");
    assert_eq!(
        o.positions, p.positions,
        "same mesh whatever the format and thread count"
    );
    assert_eq!(o.normals, p.normals);
    assert_eq!(o.triangles.concat(), p.indices);
}

#[test]
fn lod_and_iso_flags_change_the_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let vol = write_volume(dir.path());
    let base = stats_of(&mesh(&vol, &["--stats"]));
    let coarse = stats_of(&mesh(&vol, &["--stats", "--lod", "2"]));
    assert_eq!(coarse["cells"], (39 / 4) * (23 / 4) * (35 / 4));
    assert!(coarse["triangles"].as_u64() < base["triangles"].as_u64());
    // Density climbs 24 per voxel downwards (clamped at 255), so iso 250.5 sits
    // about 5.4 voxels below the default surface on flat ground; steps between
    // terraces spread the mean a little.
    let mean_y = |iso: &str| {
        let ply = dir.path().join(format!("iso{iso}.ply"));
        stats_of(&mesh(
            &vol,
            &["--stats", "--iso", iso, "--out", ply.to_str().unwrap()],
        ));
        let m = read_ply(&std::fs::read(&ply).unwrap()).unwrap();
        m.positions.iter().map(|p| p[1] as f64).sum::<f64>() / m.positions.len() as f64
    };
    let drop = mean_y("127.5") - mean_y("250.5");
    assert!((5.0..6.5).contains(&drop), "surface moved by {drop}");
}

#[test]
fn without_stats_nothing_is_printed() {
    let dir = tempfile::tempdir().unwrap();
    let vol = write_volume(dir.path());
    let out = mesh(&vol, &[]);
    assert!(out.status.success());
    assert!(out.stdout.is_empty());
}

/// Runs `args` after `mesh`, expects failure and a stderr mentioning each of `needles`.
fn fails(args: &[&str], needles: &[&str]) {
    let mut all = vec!["mesh"];
    all.extend(args);
    let out = run(&all);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} should fail");
    assert!(out.stdout.is_empty(), "{args:?} printed on stdout");
    for n in needles {
        assert!(
            stderr.contains(n),
            "{args:?}: stderr lacks {n:?}:\n{stderr}"
        );
    }
}

#[test]
fn bad_input_exits_nonzero_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let vol = write_volume(dir.path());
    let v = vol.to_str().unwrap();
    let out_ply = dir.path().join("never.ply");
    let o = out_ply.to_str().unwrap();
    fails(
        &["--volume", v, "--dims", "40", "24", "35"],
        &["34560 bytes", "33600 bytes"],
    );
    fails(
        &["--volume", v, "--dims", "40", "0", "36", "--out", o],
        &["dimension y is 0"],
    );
    fails(
        &[
            "--volume",
            v,
            "--dims",
            "4294967296",
            "4294967296",
            "4294967296",
        ],
        &["overflow"],
    );
    fails(
        &["--volume", v, "--dims", "40", "24", "36", "--out", "m.stl"],
        &["unknown extension", "stl"],
    );
    let missing = dir.path().join("missing.raw");
    fails(
        &[
            "--volume",
            missing.to_str().unwrap(),
            "--dims",
            "2",
            "2",
            "2",
        ],
        &["cannot read volume file", "missing.raw"],
    );
    fails(
        &["--volume", v, "--dims", "40", "24", "36", "--lod", "4"],
        &["--lod", "0..=3"],
    );
    fails(&["--volume", v, "--dims", "40", "24"], &["--dims"]);
    fails(
        &["--volume", v, "--dims", "40", "24", "36", "--threads", "0"],
        &["--threads"],
    );
    assert!(!out_ply.exists(), "failed runs write nothing");
}

#[test]
fn help_is_available_everywhere() {
    for args in [&["--help"][..], &["mesh", "--help"], &["help", "mesh"]] {
        let out = run(args);
        assert!(out.status.success(), "{args:?}");
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("Usage"),
            "{args:?}"
        );
    }
    let mesh_help = String::from_utf8(run(&["mesh", "--help"]).stdout).unwrap();
    for flag in [
        "--volume",
        "--dims",
        "--iso",
        "--lod",
        "--threads",
        "--out",
        "--stats",
    ] {
        assert!(mesh_help.contains(flag), "mesh --help lacks {flag}");
    }
}
