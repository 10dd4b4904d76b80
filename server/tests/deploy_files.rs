//! The deployment files agree with the workspace: the systemd units pass
//! `systemd-analyze verify` (skipped, saying so, where it is not
//! installed), every binary they name is one this package builds, the
//! Dockerfile builds a real package and copies real files, its ports match
//! the config, and every `strata-admin` command line in the deploy files
//! and the operations guide uses flags the binary accepts.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use strata_server::config::{ServerConfig, DEFAULT_LISTEN};

const SERVER_BIN: &str = env!("CARGO_BIN_EXE_strata-server");
const ADMIN_BIN: &str = env!("CARGO_BIN_EXE_strata-admin");
const UNITS: [&str; 4] = [
    "strata.service",
    "strata-backup.service",
    "strata-backup.timer",
    "strata-node@.service",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn deploy(name: &str) -> String {
    std::fs::read_to_string(root().join("deploy").join(name))
        .unwrap_or_else(|e| panic!("deploy/{name}: {e}"))
}

fn deploy_texts() -> Vec<(String, String)> {
    let mut names = vec!["Dockerfile".to_string(), "OPERATIONS.md".to_string()];
    names.extend(UNITS.iter().map(|u| format!("systemd/{u}")));
    names.into_iter().map(|n| (deploy(&n), n)).collect()
}

/// Binaries of this package: `src/bin/<name>.rs`.
fn package_bins() -> BTreeSet<String> {
    std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("src/bin"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect()
}

/// Names of the workspace's packages.
fn workspace_packages() -> BTreeSet<String> {
    let ws: toml::Table =
        toml::from_str(&std::fs::read_to_string(root().join("Cargo.toml")).unwrap()).unwrap();
    ws["workspace"]["members"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            let path = root().join(m.as_str().unwrap()).join("Cargo.toml");
            let t: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            t["package"]["name"].as_str().unwrap().to_string()
        })
        .collect()
}

#[test]
fn systemd_units_pass_systemd_analyze_verify() {
    let probe = Command::new("systemd-analyze").arg("--version").output();
    if probe.is_err() {
        eprintln!("skipped: systemd-analyze is not installed");
        return;
    }
    // verify checks that ExecStart binaries exist: point them at the builds.
    let dir = tempfile::tempdir().unwrap();
    let mut paths = Vec::new();
    for unit in UNITS {
        let text = deploy(&format!("systemd/{unit}"))
            .replace("/usr/local/bin/strata-server", SERVER_BIN)
            .replace("/usr/local/bin/strata-admin", ADMIN_BIN);
        // A template is verified as one of its instances.
        let path = dir.path().join(unit.replace("@.", "@1."));
        std::fs::write(&path, text).unwrap();
        paths.push(path);
    }
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .args(&paths)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "systemd-analyze verify: {stderr}");
    // Unknown keys and bad values are only warnings: none is allowed.
    let about_ours: Vec<&str> = stderr
        .lines()
        .filter(|l| {
            UNITS
                .iter()
                .any(|u| l.contains(u) || l.contains(&u.replace("@.", "@1.")))
        })
        .collect();
    assert!(about_ours.is_empty(), "warnings: {about_ours:#?}");
}

#[test]
fn units_and_dockerfile_name_real_binaries_packages_and_paths() {
    let bins = package_bins();
    assert!(bins.contains("strata-server") && bins.contains("strata-admin"));
    for (text, name) in deploy_texts() {
        for prefix in ["/usr/local/bin/", "target/release/"] {
            for (i, _) in text.match_indices(prefix) {
                let rest = &text[i + prefix.len()..];
                let bin: String = rest
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
                    .collect();
                if !bin.is_empty() {
                    assert!(bins.contains(&bin), "{name} names unknown binary {bin:?}");
                }
            }
        }
    }

    let docker = deploy("Dockerfile");
    assert!(docker.contains("cargo build --release --locked -p strata-server"));
    let packages = workspace_packages();
    for build in docker.lines().filter(|l| l.contains("cargo build")) {
        let words: Vec<&str> = build.split_whitespace().collect();
        for pkg in words.windows(2).filter(|w| w[0] == "-p").map(|w| w[1]) {
            assert!(
                packages.contains(pkg),
                "Dockerfile builds unknown package {pkg}"
            );
        }
    }
    for line in docker.lines().filter(|l| l.starts_with("COPY ")) {
        let args: Vec<&str> = line.split_whitespace().skip(1).collect();
        if args.iter().any(|a| a.starts_with("--from")) {
            continue;
        }
        for src in &args[..args.len() - 1] {
            assert!(root().join(src).exists(), "Dockerfile copies missing {src}");
        }
    }
    let user = docker
        .lines()
        .rfind(|l| l.starts_with("USER "))
        .expect("the image drops root");
    assert!(!user.contains("root") && !user.contains(" 0"), "{user}");
    assert!(docker.contains("VOLUME [\"/var/lib/strata\"]"));
    assert!(docker.contains("\"--data-dir\", \"/var/lib/strata\""));
    assert!(docker.contains("COPY deploy/strata.toml /etc/strata/strata.toml"));
    let port = DEFAULT_LISTEN.port();
    assert!(docker.contains(&format!("EXPOSE {port}/udp")));
    assert!(docker.contains(&format!("\"0.0.0.0:{port}\"")));
    let example = ServerConfig::load(Some(&root().join("deploy/strata.toml"))).unwrap();
    let metrics = example.metrics.listen.expect("the example enables metrics");
    assert!(
        docker.contains(&format!("/dev/tcp/127.0.0.1/{}", metrics.port())),
        "HEALTHCHECK probes the example's metrics port"
    );

    let service = deploy("systemd/strata.service");
    assert!(service.contains("StateDirectory=strata\n"));
    assert!(service.contains("--config /etc/strata/strata.toml --data-dir /var/lib/strata"));
    let node = deploy("systemd/strata-node@.service");
    assert!(node.contains("StateDirectory=strata/node-%i\n"));
    assert!(node.contains("--config /etc/strata/node-%i.toml --data-dir /var/lib/strata/node-%i"));
    for i in 1..=3 {
        let c = ServerConfig::load(Some(&root().join(format!("deploy/cluster/node-{i}.toml"))))
            .unwrap();
        assert_eq!(
            c.server.data_dir,
            Path::new(&format!("/var/lib/strata/node-{i}")),
            "the unit's data dir"
        );
    }
    let backup = deploy("systemd/strata-backup.service");
    assert!(backup.contains(&format!("--server 127.0.0.1:{port}")));
    assert!(backup.contains("--cert /var/lib/strata/cert.der"));
    // The token never on a command line; a stalled run does not hold the
    // next ones; what killed runs leave is cleaned.
    assert!(backup.contains("--token-file \"$CREDENTIALS_DIRECTORY/token\""));
    assert!(!backup.contains("--token \""));
    assert!(backup.contains("\nTimeoutStartSec="));
    assert!(backup.contains("-name 'strata-*.partial'"));
    // A stopped server stays stopped, and the documented token is one the
    // default `token_max_ttl` allows.
    assert!(backup.contains("\nRequisite=strata.service\n"));
    assert!(!backup.contains("\nWants="));
    let max = strata_server::config::DEFAULT_TOKEN_MAX_TTL.as_secs();
    for text in [backup.as_str(), deploy("OPERATIONS.md").as_str()] {
        for ttl in text.split("--ttl ").skip(1) {
            let digits: String = ttl.chars().take_while(char::is_ascii_digit).collect();
            let unit = match ttl[digits.len()..].chars().next() {
                Some('d') => 86_400,
                Some('h') => 3_600,
                Some('m') => 60,
                other => panic!("--ttl {digits} with unit {other:?}"),
            };
            let secs = digits.parse::<u64>().unwrap() * unit;
            assert!(secs <= max, "--ttl {digits}.. is over {max} s");
        }
    }
    assert!(deploy("systemd/strata-backup.timer").contains("Unit=strata-backup.service"));
}

/// `strata-admin` invocations in `text`: subcommand words and `--flags`.
fn admin_invocations(text: &str) -> Vec<(Vec<String>, Vec<String>)> {
    let joined = text.replace("\\\n", " ");
    let mut out = Vec::new();
    for (i, _) in joined.match_indices("strata-admin ") {
        let line = joined[i..].lines().next().unwrap();
        let mut words = Vec::new();
        let mut flags = Vec::new();
        for tok in line.split_whitespace().skip(1) {
            if ["|", ">", "&&", ";"].contains(&tok) || tok.contains('`') {
                break;
            }
            if let Some(flag) = tok.strip_prefix("--") {
                flags.push(format!("--{}", flag.trim_end_matches(['"', '\'', ','])));
            } else if flags.is_empty() && tok.chars().all(|c| c.is_ascii_lowercase() || c == '-') {
                words.push(tok.to_string());
            } else if flags.is_empty() {
                flags.push(String::new()); // a positional argument ends the subcommand
            }
        }
        flags.retain(|f| !f.is_empty());
        if !words.is_empty() {
            out.push((words, flags));
        }
    }
    out
}

fn admin_help(words: &[String]) -> Option<String> {
    let out = Command::new(ADMIN_BIN)
        .args(words)
        .arg("--help")
        .output()
        .unwrap();
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

#[test]
fn documented_admin_commands_use_real_flags() {
    let top = admin_help(&[]).unwrap();
    let mut checked = 0;
    for (text, name) in deploy_texts() {
        for (words, flags) in admin_invocations(&text) {
            // `snapshot` is built elsewhere in the project; its lines are
            // checked once the binary has the command.
            if !top.contains(&format!("  {} ", words[0])) {
                eprintln!(
                    "note: {name}: strata-admin has no {:?} command yet",
                    words[0]
                );
                continue;
            }
            let help = admin_help(&words).unwrap_or_else(|| {
                panic!(
                    "{name}: `strata-admin {}` is not a command",
                    words.join(" ")
                )
            });
            for f in &flags {
                assert!(
                    help.contains(&format!("{f} ")) || help.contains(&format!("{f}\n")),
                    "{name}: `strata-admin {}` has no flag {f}",
                    words.join(" ")
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 6, "only {checked} invocations checked");
}
