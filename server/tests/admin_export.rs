//! `strata-admin export-mesh` on a stopped server's data dir: per-chunk LOD-0
//! mesh hashes equal the server's collision mesh hashes (the ones its deltas
//! carry), the welded mesh is closed everywhere except where the region box
//! cuts it, and PLY, OBJ and GLB carry the same mesh.

use crate::offline_common;

use std::collections::HashMap;
use std::path::Path;

use offline_common::*;
use strata_server::admin::export::ExportMesh;
use strata_server::admin::glb::read_glb;
use strata_server::admin::obj::read_obj;
use strata_server::admin::ply::read_ply;
use strata_terrain::material::ids;
use strata_terrain::{ChunkPos, MaterialTable, CHUNK_SIZE};

fn export(fx: &Fixture, out: &Path, extra: &[&str]) -> String {
    let region = region_args();
    let mut args = vec![
        "export-mesh",
        "--data-dir",
        fx.data_dir().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--region",
    ];
    args.extend(region.iter().map(String::as_str));
    args.extend(extra);
    ok(&admin(&args))
}

/// The region's box in world voxels, over the world's chunk rows
/// (`min_y` -128 and `max_y` 255 by default: rows -5..=7).
fn region_box() -> ([f32; 3], [f32; 3]) {
    let [x0, z0, x1, z1] = REGION;
    let s = CHUNK_SIZE as f32;
    (
        [x0 as f32 * s, -5.0 * s, z0 as f32 * s],
        [(x1 + 1) as f32 * s, 8.0 * s, (z1 + 1) as f32 * s],
    )
}

/// Every directed edge is used once, and an edge without its twin (an
/// open edge) lies in one face plane of the region box: the mesh is closed
/// and consistently oriented except where the box cuts it.
fn closed_except_on_the_box(m: &ExportMesh) -> usize {
    let (lo, hi) = region_box();
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in m.indices.chunks_exact(3) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *directed.entry((a, b)).or_default() += 1;
        }
    }
    let mut open = 0;
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "edge {a}->{b} used {n} times");
        if directed.contains_key(&(b, a)) {
            continue;
        }
        open += 1;
        let (pa, pb) = (m.positions[a as usize], m.positions[b as usize]);
        let on_face = (0..3)
            .any(|k| (pa[k] == lo[k] && pb[k] == lo[k]) || (pa[k] == hi[k] && pb[k] == hi[k]));
        assert!(on_face, "open edge {pa:?}-{pb:?} inside the region");
    }
    open
}

#[test]
fn lod0_chunk_hashes_are_the_servers_and_the_weld_is_closed() {
    let mut fx = build();
    let out = fx.data_dir().join("region.ply");
    let stdout = export(&fx, &out, &["--lod", "0", "--chunk-hashes", "--stats"]);
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let (stats, chunks) = lines.split_last().unwrap();
    let mut seen = HashMap::new();
    let mut triangles = 0;
    for c in chunks {
        let pos = ChunkPos::new(
            c["x"].as_i64().unwrap() as i32,
            c["y"].as_i64().unwrap() as i32,
            c["z"].as_i64().unwrap() as i32,
        );
        let hash = c["mesh_hash"].as_u64().unwrap();
        let version = c["version"].as_u64().unwrap();
        // The server's collision cache path, for every chunk of the region.
        assert_eq!(hash, fx.sequencer.mesh_hash(pos), "{pos:?}");
        assert_eq!(
            version,
            fx.sequencer.world().peek(pos).map_or(0, |v| v.version)
        );
        triangles += c["triangles"].as_u64().unwrap();
        seen.insert(pos, (version, hash));
    }
    // Every edited chunk, at the version and mesh hash its delta carried.
    assert!(fx.deltas.len() >= 3, "{:?}", fx.deltas);
    for (pos, (version, hash)) in &fx.deltas {
        assert_eq!(seen.get(pos), Some(&(*version, *hash)), "{pos:?}");
    }
    assert_eq!(stats["triangles"].as_u64().unwrap(), triangles);
    assert_eq!(stats["chunks"], 3 * 3 * 13);

    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&out).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o644, "an ordinary readable file");
    }
    let mesh = read_ply(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(
        mesh.positions.len() as u64,
        stats["vertices"].as_u64().unwrap()
    );
    assert_eq!(mesh.indices.len() as u64, 3 * triangles);
    assert!(mesh.materials.contains(&ids::BRICK));
    let open = closed_except_on_the_box(&mesh);
    assert!(open > 0, "the terrain surface is cut by the region's sides");
}

#[test]
fn glb_and_obj_carry_the_same_lod1_mesh() {
    let fx = build();
    let dir = fx.data_dir();
    let (glb, ply, obj) = (dir.join("r.glb"), dir.join("r.ply"), dir.join("r.obj"));
    export(&fx, &glb, &["--lod", "1"]);
    export(&fx, &ply, &["--lod", "1"]);
    export(&fx, &obj, &["--lod", "1"]);
    let g = read_glb(&std::fs::read(&glb).unwrap()).unwrap();
    let p = read_ply(&std::fs::read(&ply).unwrap()).unwrap();
    assert_eq!(g.mesh, p, "GLB and PLY hold the same mesh");
    let o = read_obj(&std::fs::read_to_string(&obj).unwrap()).unwrap();
    assert_eq!(o.positions, p.positions);
    assert_eq!(o.triangles.len() * 3, p.indices.len());
    assert!(!p.indices.is_empty());
    closed_except_on_the_box(&p);

    // glTF requirements the reader does not enforce by itself.
    let j = &g.json;
    assert_eq!(j["asset"]["version"], "2.0");
    let attrs = &j["meshes"][0]["primitives"][0]["attributes"];
    for a in ["POSITION", "NORMAL", "COLOR_0", "_MATERIAL"] {
        assert!(attrs[a].is_u64(), "{a} present");
    }
    let (lo, hi) = region_box();
    let min = j["accessors"][0]["min"].as_array().unwrap();
    let max = j["accessors"][0]["max"].as_array().unwrap();
    for k in 0..3 {
        assert!(min[k].as_f64().unwrap() >= f64::from(lo[k]));
        assert!(max[k].as_f64().unwrap() <= f64::from(hi[k]));
    }
    let table = MaterialTable::default();
    for (c, m) in g.colors.iter().zip(&g.mesh.materials) {
        let [r, gg, b, _] = table.rgba(*m);
        assert_eq!(*c, [r, gg, b, 255]);
    }
    for n in &g.mesh.normals {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-3, "unit normals: {n:?}");
    }
}

#[test]
fn bad_arguments_fail_without_output() {
    let fx = build();
    let dir = fx.data_dir();
    let run = |out: &str, region: &[&str], extra: &[&str]| {
        let mut args = vec!["export-mesh", "--data-dir", dir.to_str().unwrap()];
        args.extend(["--out", out, "--region"]);
        args.extend(region);
        args.extend(extra);
        admin(&args)
    };
    let stl = dir.join("m.stl");
    let out = run(stl.to_str().unwrap(), &["0", "0", "0", "0"], &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown extension"));
    let ply = dir.join("m.ply");
    let out = run(ply.to_str().unwrap(), &["1", "0", "0", "0"], &[]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("--region"));
    let out = run(
        ply.to_str().unwrap(),
        &["0", "0", "0", "0"],
        &["--rows", "2", "1"],
    );
    assert!(String::from_utf8_lossy(&out.stderr).contains("--rows"));
    // Rows or columns whose arithmetic would overflow, or whose box could
    // not be held, are refused before anything is read or allocated.
    for rows in [
        ["-100000000", "100000000"],
        ["-2147483648", "2147483647"],
        ["0", "256"],
    ] {
        let out = run(
            ply.to_str().unwrap(),
            &["0", "0", "0", "0"],
            &[&["--rows"][..], &rows[..]].concat(),
        );
        assert_eq!(out.status.code(), Some(1), "{rows:?}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("--rows"),
            "{rows:?}"
        );
    }
    for region in [
        ["2147483647", "0", "2147483647", "0"],
        ["-2147483648", "0", "2147483647", "0"],
        ["131073", "0", "131073", "0"],
    ] {
        let out = run(ply.to_str().unwrap(), &region, &[]);
        assert_eq!(out.status.code(), Some(1), "{region:?}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("--region"),
            "{region:?}"
        );
    }
    let out = run(
        ply.to_str().unwrap(),
        &["0", "0", "0", "0"],
        &["--lod", "4"],
    );
    assert!(!out.status.success());
    assert!(!stl.exists() && !ply.exists());
    let strays = std::fs::read_dir(dir)
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with(".strata-out")
        })
        .count();
    assert_eq!(strays, 0, "no temporary file left behind");
    // What a killed run left (nobody holds it) is removed by the next
    // export beside it; a running writer's (held: `stale_outputs::hold`)
    // is kept, whatever process id its name carries.
    let stale = dir.join(".strata-out-7-AbC123");
    let live = dir.join(".strata-out-7-XyZ789");
    std::fs::write(&stale, b"half a mesh").unwrap();
    std::fs::write(&live, b"a mesh being written").unwrap();
    let writer = std::fs::File::options().write(true).open(&live).unwrap();
    strata_server::admin::stale_outputs::hold(&writer).unwrap();
    let out = run(ply.to_str().unwrap(), &["0", "0", "0", "0"], &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(ply.exists());
    assert!(!stale.exists(), "a dead writer's staged file is removed");
    assert!(live.exists(), "a running writer's is kept");
    assert!(String::from_utf8_lossy(&out.stderr).contains("left unfinished"));
    drop(writer);
}
