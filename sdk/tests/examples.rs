//! The C and Python examples, compiled and run against a real server on
//! 127.0.0.1: each connects, digs, sees its own delta, meshes the chunk.

use crate::common;

use std::process::Command;

use common::{check_run, field, lib_dir, root, run_bounded, Server};

/// Compiles examples/c/main.c against libstrata; `link` picks the library.
fn compile_c(out_dir: &std::path::Path, name: &str, link: &[String]) -> std::path::PathBuf {
    let exe = out_dir.join(name);
    let root = root();
    let out = run_bounded(
        Command::new("cc")
            .arg("-std=c99")
            .arg("-Wall")
            .arg("-Werror")
            .arg("-D_POSIX_C_SOURCE=199309L")
            .arg(root.join("examples/c/main.c"))
            .arg("-I")
            .arg(root.join("sdk/include"))
            .args(link)
            .arg("-o")
            .arg(&exe),
    );
    assert!(out.status.success(), "cc failed");
    exe
}

fn run_c(server: &Server, exe: &std::path::Path, player: &str) -> String {
    let out = run_bounded(
        Command::new(exe)
            // Cargo's path lists target/debug first, where a libstrata.so of
            // an older build may lie: the executable's rpath names the one
            // just built.
            .env_remove("LD_LIBRARY_PATH")
            .arg(server.address())
            .arg(server.cert_file())
            .arg(server.token(player)),
    );
    assert!(out.status.success(), "the C example failed");
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn c_example_runs_against_a_server_with_the_shared_library() {
    let server = Server::start();
    let lib = lib_dir().display().to_string();
    let exe = compile_c(
        server.dir.path(),
        "strata_example",
        &[
            format!("-L{lib}"),
            "-lstrata".into(),
            format!("-Wl,-rpath,{lib}"),
        ],
    );
    let out = run_c(&server, &exe, "c-dynamic");
    check_run(&out);
    // The library checked its own meshes against the server's hashes.
    let checked: u64 = field(&out, "stats", "meshes_checked");
    let mismatches: u64 = field(&out, "stats", "mesh_mismatches");
    assert!(checked > 0, "no mesh was checked");
    assert_eq!(mismatches, 0);
    // A bad LOD is an error code and a message, not a crash.
    let status: i32 = field(&out, "error", "status");
    assert_eq!(status, strata::StrataStatus::Mesh as i32);
    assert!(
        out.contains("message=lod 9 is above the maximum 3"),
        "{out}"
    );
}

#[test]
fn c_example_runs_against_a_server_with_the_static_library() {
    let server = Server::start();
    let lib = lib_dir().join("libstrata.a").display().to_string();
    let system = ["-lpthread", "-ldl", "-lm", "-lrt", "-lgcc_s", "-lc"].map(String::from);
    let mut link = vec![lib];
    link.extend(system);
    let exe = compile_c(server.dir.path(), "strata_example_static", &link);
    check_run(&run_c(&server, &exe, "c-static"));
}

#[test]
fn python_example_runs_against_a_server() {
    let server = Server::start();
    let out = run_bounded(
        Command::new("python3")
            .arg(root().join("examples/python/strata_example.py"))
            .arg(lib_dir().join("libstrata.so"))
            .arg(server.address())
            .arg(server.cert_file())
            .arg(server.token("python")),
    );
    assert!(out.status.success(), "the Python example failed");
    check_run(&String::from_utf8(out.stdout).unwrap());
}
