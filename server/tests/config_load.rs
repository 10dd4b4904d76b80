//! Server config: defaults, the deploy example, overrides, and validation
//! errors that name the offending field.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use strata_server::auth::HumanDuration;
use strata_server::config::{ConfigError, ServerConfig, DEFAULT_LISTEN};

fn deploy_example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/strata.toml")
}

fn invalid_field(text: &str) -> &'static str {
    match ServerConfig::from_toml_str(text) {
        Err(ConfigError::Invalid { field, .. }) => field,
        other => panic!("expected an Invalid error for {text:?}, got {other:?}"),
    }
}

#[test]
fn no_file_means_valid_defaults() {
    let config = ServerConfig::load(None).unwrap();
    assert_eq!(config, ServerConfig::default());
    config.validate().unwrap();
    assert_eq!(config.server.listen, DEFAULT_LISTEN);
    assert_eq!(config.server.data_dir, PathBuf::from("strata-data"));
    assert_eq!(config.metrics.listen, None);
    assert_eq!(
        config.auth.token_max_ttl,
        HumanDuration(Duration::from_secs(30 * 86_400))
    );
}

#[test]
fn empty_and_partial_files_fill_in_defaults() {
    assert_eq!(
        ServerConfig::from_toml_str("").unwrap(),
        ServerConfig::default()
    );
    let c =
        ServerConfig::from_toml_str("[interest]\nview_radius = 4\n[world.generator]\nseed = 7\n")
            .unwrap();
    let mut expected = ServerConfig::default();
    expected.interest.view_radius = 4;
    expected.world.generator.seed = 7;
    assert_eq!(c, expected);
}

#[test]
fn deploy_example_is_the_defaults_plus_metrics_and_console() {
    let loaded = ServerConfig::load(Some(&deploy_example())).unwrap();
    let mut expected = ServerConfig::default();
    // The deliberate changes: the example enables the metrics endpoint and
    // the console, both on loopback.
    expected.metrics.listen = Some("127.0.0.1:9464".parse().unwrap());
    expected.console.listen = Some("127.0.0.1:9465".parse().unwrap());
    assert_eq!(loaded, expected);
}

#[test]
fn deploy_example_mentions_every_option() {
    // Serializing the defaults lists every key; each must appear in the
    // example, so a new option cannot be added without documenting it.
    let text = std::fs::read_to_string(deploy_example()).unwrap();
    let defaults: toml::Table =
        toml::from_str(&ServerConfig::default().to_toml_string().unwrap()).unwrap();
    let example: toml::Table = toml::from_str(&text).unwrap();
    for (section, table) in &defaults {
        let Some(table) = table.as_table() else {
            panic!("top-level key {section} is not a section");
        };
        assert!(
            text.contains(&format!("[{section}]")),
            "[{section}] missing"
        );
        for key in table.keys() {
            assert!(
                example[section].as_table().unwrap().contains_key(key),
                "{section}.{key} missing from deploy/strata.toml"
            );
        }
    }
    assert!(text.contains("[metrics]") && example["metrics"].get("listen").is_some());
}

#[test]
fn serialized_config_round_trips() {
    let mut c = ServerConfig::default();
    c.tls.extra_names = vec!["strata.example".into(), "10.1.2.3".into()];
    c.metrics.listen = Some("127.0.0.1:9000".parse().unwrap());
    c.auth.token_max_ttl = HumanDuration(Duration::from_secs(7200));
    let text = c.to_toml_string().unwrap();
    assert!(text.contains("token_max_ttl = \"2h\""), "{text}");
    assert_eq!(ServerConfig::from_toml_str(&text).unwrap(), c);
}

#[test]
fn overrides_win_over_the_file() {
    let mut c = ServerConfig::from_toml_str(
        "[server]\nlisten = \"0.0.0.0:5000\"\ndata_dir = \"/srv/strata\"\n",
    )
    .unwrap();
    c.apply_overrides(None, None);
    assert_eq!(c.server.data_dir, PathBuf::from("/srv/strata"));
    let addr: SocketAddr = "127.0.0.1:6000".parse().unwrap();
    c.apply_overrides(Some(PathBuf::from("/tmp/x")), Some(addr));
    assert_eq!(c.server.data_dir, PathBuf::from("/tmp/x"));
    assert_eq!(c.server.listen, addr);
}

/// Loads `text` from a file and returns the Parse error's line and message.
fn load_error(text: &str) -> (Option<usize>, String) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("strata.toml");
    std::fs::write(&path, text).unwrap();
    match ServerConfig::load(Some(&path)) {
        Err(e @ ConfigError::Parse { .. }) => {
            let shown = e.to_string();
            let ConfigError::Parse { path: p, line, .. } = e else {
                unreachable!()
            };
            assert_eq!(p, path);
            assert!(shown.contains(&path.display().to_string()), "{shown}");
            (line, shown)
        }
        other => panic!("expected a Parse error for {text:?}, got {other:?}"),
    }
}

#[test]
fn a_misspelled_section_is_an_error_naming_it_and_its_line() {
    let (line, msg) =
        load_error("[server]\nmax_connections = 10\n\n[metric]\nlisten = \"127.0.0.1:9464\"\n");
    assert_eq!(line, Some(4));
    assert!(msg.contains("line 4") && msg.contains("`metric`"), "{msg}");
    // A misspelled nested section, and a key inside an inline table.
    let (line, msg) = load_error("[world]\n[world.generatr]\nseed = 7\n");
    assert_eq!(line, Some(2));
    assert!(
        msg.contains("line 2") && msg.contains("`generatr`"),
        "{msg}"
    );
    let (_, msg) = load_error("world = { generator = { sead = 7 } }\n");
    assert!(msg.contains("line 1") && msg.contains("`sead`"), "{msg}");
}

#[test]
fn a_misspelled_key_in_a_known_section_is_an_error_naming_it_and_its_line() {
    let (line, msg) = load_error("# comment\n[net]\nwriter_queue = 8\nstream_window = 5\n");
    assert_eq!(line, Some(4));
    assert!(
        msg.contains("line 4") && msg.contains("`stream_window`"),
        "{msg}"
    );
    // Edit bounds come from [world.generator]; they are not a validation key.
    let (_, msg) = load_error("[validation.bounds]\nmin_y = 0\n");
    assert!(msg.contains("line 1") && msg.contains("`bounds`"), "{msg}");
    // A rate bucket takes exactly its two keys.
    let (line, msg) =
        load_error("[validation.edit_rate]\ncapacity = 20\nper_second = 5\nburst = 99\n");
    assert_eq!(line, Some(4));
    assert!(msg.contains("line 4") && msg.contains("`burst`"), "{msg}");
}

#[test]
fn an_unknown_top_level_key_is_an_error_naming_it_and_its_line() {
    let (line, msg) = load_error("\n\ntick_ms = 50\n[engine]\ntick_ms = 50\n");
    assert_eq!(line, Some(3));
    assert!(msg.contains("line 3") && msg.contains("`tick_ms`"), "{msg}");
    // Without a file, the message still names the line.
    let err = ServerConfig::from_toml_str("[server]\nlisten = \"127.0.0.1:1\"\ndata = \"x\"\n")
        .unwrap_err();
    assert!(
        matches!(err, ConfigError::Parse { line: Some(3), .. }),
        "{err:?}"
    );
    assert!(
        err.to_string()
            .starts_with("cannot parse config line 3: unknown field `data`"),
        "{err}"
    );
}

#[test]
fn bad_values_name_their_field() {
    let cases = [
        ("[server]\nmax_connections = 0", "server.max_connections"),
        (
            "[server]\nmax_connections = 70000",
            "server.max_connections",
        ),
        ("[server]\ndata_dir = \"\"", "server.data_dir"),
        ("[server]\nnet_threads = 257", "server.net_threads"),
        (
            "[validation.edit_rate]\ncapacity = 0\nper_second = 5",
            "validation.edit_rate.capacity",
        ),
        (
            "[validation.volume_rate]\ncapacity = 0\nper_second = 0",
            "validation.volume_rate.capacity",
        ),
        (
            "[validation.volume_weight]\nsmooth = 0",
            "validation.volume_weight.smooth",
        ),
        (
            "[validation.volume_weight]\nexplode = 1001",
            "validation.volume_weight.explode",
        ),
        ("[interest]\nhysteresis = 17", "interest.hysteresis"),
        (
            "[validation.position_rate]\ncapacity = 0\nper_second = 5",
            "validation.position_rate.capacity",
        ),
        (
            "[validation.position_rate]\ncapacity = 5\nper_second = 0",
            "validation.position_rate.per_second",
        ),
        (
            "[validation.placement_rate]\ncapacity = 0\nper_second = 1",
            "validation.placement_rate.capacity",
        ),
        (
            "[validation.join_rate]\ncapacity = 0\nper_second = 1",
            "validation.join_rate.capacity",
        ),
        ("[tls]\nextra_names = [\"bad name!\"]", "tls.extra_names"),
        ("[tls]\nextra_names = [\"\"]", "tls.extra_names"),
        (
            "[net]\nstream_receive_window = 0",
            "net.stream_receive_window",
        ),
        (
            "[net]\nstream_receive_window = 1000",
            "net.stream_receive_window",
        ),
        (
            "[net]\nconnection_receive_window = 0",
            "net.connection_receive_window",
        ),
        (
            "[net]\nstream_receive_window = 524288\nconnection_receive_window = 262144",
            "net.connection_receive_window",
        ),
        ("[net]\nsend_window = 1024", "net.send_window"),
        ("[net]\nmax_uni_streams = 65", "net.max_uni_streams"),
        ("[net]\nidle_timeout_ms = 0", "net.idle_timeout_ms"),
        ("[net]\nidle_timeout_ms = 600001", "net.idle_timeout_ms"),
        ("[net]\nkeep_alive_ms = 30000", "net.keep_alive_ms"),
        ("[net]\nkeep_alive_ms = 0", "net.keep_alive_ms"),
        (
            "[net]\ndatagram_receive_buffer = 100",
            "net.datagram_receive_buffer",
        ),
        (
            "[net]\ndatagram_send_buffer = 0",
            "net.datagram_send_buffer",
        ),
        ("[net]\nwriter_queue = 0", "net.writer_queue"),
        (
            "[net]\nsend_budget_bytes_per_tick = 0",
            "net.send_budget_bytes_per_tick",
        ),
        ("[net]\nack_delay_max_ms = 1001", "net.ack_delay_max_ms"),
        ("[net]\nsend_interval_ms = 1001", "net.send_interval_ms"),
        (
            "[net]\nack_eliciting_threshold = 65",
            "net.ack_eliciting_threshold",
        ),
        ("[auth]\ntoken_max_ttl = \"400d\"", "auth.token_max_ttl"),
        ("[interest]\nview_radius = 0", "interest.view_radius"),
        ("[interest]\nview_radius = 33", "interest.view_radius"),
        ("[world.generator]\nmin_y = -2000000", "world.generator"),
        ("[world.generator]\nmax_y = 2000000", "world.generator"),
        (
            "[world.generator]\nmin_y = 0\nmax_y = 63",
            "world.generator",
        ),
        ("[engine]\ntick_ms = 0", "engine.tick_ms"),
        ("[engine]\ncommand_queue = 0", "engine.command_queue"),
        ("[engine]\nsession_commands = 0", "engine.session_commands"),
        ("[engine]\npremesh_radius = 9", "engine.premesh_radius"),
        ("[engine]\npremesh_inflight = 0", "engine.premesh_inflight"),
        ("[engine]\npremesh_threads = 0", "engine.premesh_threads"),
        ("[engine]\npremesh_threads = 65", "engine.premesh_threads"),
        ("[engine]\npremesh_backlog = 0", "engine.premesh_backlog"),
        (
            "[engine]\npremesh_generated_chunks = 0",
            "engine.premesh_generated_chunks",
        ),
        (
            "[engine]\npatch_base_chunks = 2000000",
            "engine.patch_base_chunks",
        ),
        (
            "[engine]\nsnapshot_cache_entries = 0",
            "engine.snapshot_cache_entries",
        ),
        (
            "[engine]\nfull_frame_cache_entries = 0",
            "engine.full_frame_cache_entries",
        ),
        (
            "[net]\ncontrol_writer_queue = 0",
            "net.control_writer_queue",
        ),
        (
            "[validation.request_rate]\ncapacity = 0\nper_second = 10",
            "validation.request_rate.capacity",
        ),
        (
            "[validation.request_rate]\ncapacity = 10\nper_second = 0",
            "validation.request_rate.per_second",
        ),
        (
            "[server]\nretry_above_handshakes = 70000",
            "server.retry_above_handshakes",
        ),
        ("[metrics]\nmax_connections = 0", "metrics.max_connections"),
        ("[engine]\nstream_us = 0", "engine.stream_us"),
        ("[engine]\nresident_chunks = 3", "engine.resident_chunks"),
        (
            "[engine]\nsnapshot_preimages = 0",
            "engine.snapshot_preimages",
        ),
        (
            "[engine]\nsnapshot_preimage_bytes = 1000",
            "engine.snapshot_preimage_bytes",
        ),
        (
            "[sequencer]\nqueue_capacity = 0",
            "sequencer.queue_capacity",
        ),
        (
            "[sequencer]\ncollision_cache_capacity = 1",
            "sequencer.collision_cache_capacity",
        ),
        (
            "[sequencer]\ncollision_cache_capacity = 10000000",
            "sequencer.collision_cache_capacity",
        ),
        (
            "[store]\ncache_capacity_bytes = 1000",
            "store.cache_capacity_bytes",
        ),
        ("[store]\nflush_every_ms = 60001", "store.flush_every_ms"),
        ("[console]\nmax_watchers = 0", "console.max_watchers"),
        (
            "[console]\nmax_body_bytes = 9999999",
            "console.max_body_bytes",
        ),
        ("[console]\nsample_ms = 10", "console.sample_ms"),
        (
            "[console]\nidle_timeout_ms = 500",
            "console.idle_timeout_ms",
        ),
        (
            "[console]\nscene_max_chunks = 0",
            "console.scene_max_chunks",
        ),
        // Under one chunk with its border: every scene refused.
        (
            "[console]\nscene_max_chunks = 26",
            "console.scene_max_chunks",
        ),
        (
            "[console]\nedits_per_sample = 0",
            "console.edits_per_sample",
        ),
        ("[console]\nrender_threads = 0", "console.render_threads"),
        ("[console]\nevent_queue = 2000", "console.event_queue"),
        (
            "[console]\nregions_per_request = 0",
            "console.regions_per_request",
        ),
        (
            "[store]\nsegment_size_bytes = 65536",
            "store.segment_size_bytes",
        ),
        (
            "[store]\nsegment_size_bytes = 3000000",
            "store.segment_size_bytes",
        ),
        ("[validation]\nreach = 1000.0", "validation.reach"),
        ("[validation]\nreach = nan", "validation.reach"),
        ("[validation]\nreach = -1.0", "validation.reach"),
        (
            "[validation]\nlos_tolerance = inf",
            "validation.los_tolerance",
        ),
        ("[validation]\neye_height = -0.5", "validation.eye_height"),
        ("[validation]\nmax_speed = 1e9", "validation.max_speed"),
        (
            "[validation]\nspeed_slack_factor = nan",
            "validation.speed_slack_factor",
        ),
        (
            "[validation]\nspeed_slack_voxels = 5000.0",
            "validation.speed_slack_voxels",
        ),
        ("[validation]\nmax_move_ms = 0", "validation.max_move_ms"),
        (
            "[validation]\nmax_move_ms = 60001",
            "validation.max_move_ms",
        ),
        // In range each, but a move of 20 s at 20 voxels/s is longer than
        // a path may be swept (502 voxels, 256 at most).
        (
            "[validation]\nmax_move_ms = 20000",
            "validation.max_move_ms",
        ),
        ("[validation]\nmax_speed = 200.0", "validation.max_move_ms"),
        (
            "[validation.gravity]\njump_voxels = -1.0",
            "validation.gravity.jump_voxels",
        ),
        (
            "[validation.gravity]\njump_voxels = nan",
            "validation.gravity.jump_voxels",
        ),
    ];
    for (text, field) in cases {
        assert_eq!(invalid_field(text), field, "config {text:?}");
    }
}

#[test]
fn invalid_error_message_names_field_and_reason() {
    let err = ServerConfig::from_toml_str("[interest]\nview_radius = 33").unwrap_err();
    assert_eq!(
        err.to_string(),
        "config field `interest.view_radius` is invalid: 33 is outside 1..=32"
    );
}

#[test]
fn type_errors_and_bad_durations_are_parse_errors_with_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    for text in [
        "[auth]\ntoken_max_ttl = \"soon\"",
        "[auth]\ntoken_max_ttl = \"0s\"",
        "[server]\nlisten = \"not an address\"",
        "[world.generator]\nseed = -1",
        "[interest]\nview_radius = 300",
        "[net\n",
    ] {
        std::fs::write(&path, text).unwrap();
        match ServerConfig::load(Some(&path)) {
            Err(ConfigError::Parse { path: p, .. }) => assert_eq!(p, path),
            other => panic!("expected a Parse error for {text:?}, got {other:?}"),
        }
    }
}

#[test]
fn missing_file_is_a_read_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("absent.toml");
    assert!(matches!(
        ServerConfig::load(Some(&path)),
        Err(ConfigError::Read { .. })
    ));
}

#[test]
fn the_postgres_store_needs_a_url_and_sane_limits() {
    assert_eq!(
        invalid_field("[store]\nbackend = \"postgres\"\n"),
        "store.postgres.url"
    );
    assert_eq!(
        invalid_field("[store.postgres]\nmax_connections = 0\n"),
        "store.postgres.max_connections"
    );
    assert_eq!(
        invalid_field("[store.postgres]\nstatement_timeout_ms = 0\n"),
        "store.postgres.statement_timeout_ms"
    );
    let c = ServerConfig::from_toml_str(
        "[store]\nbackend = \"postgres\"\n[store.postgres]\nurl = \"host=127.0.0.1 dbname=w\"\n",
    )
    .unwrap();
    assert_eq!(
        c.store.backend,
        strata_server::store::StoreBackend::Postgres
    );
}

#[test]
fn a_cluster_node_needs_postgres_a_name_and_a_renewal_inside_its_lease() {
    let pg =
        "[store]\nbackend = \"postgres\"\n[store.postgres]\nurl = \"host=127.0.0.1 dbname=w\"\n";
    assert_eq!(
        invalid_field("[cluster]\nnode_id = \"a\"\n"),
        "cluster.node_id",
        "sled cannot be shared"
    );
    for (cluster, field) in [
        ("[cluster]\n", "cluster.node_id"),
        ("[cluster]\nnode_id = \"a/b\"\n", "cluster.node_id"),
        (
            "[cluster]\nnode_id = \"a\"\nlease_ms = 100\n",
            "cluster.lease_ms",
        ),
        (
            "[cluster]\nnode_id = \"a\"\nlease_ms = 1000\nrenew_ms = 501\n",
            "cluster.renew_ms",
        ),
        (
            "[cluster]\nnode_id = \"a\"\nrenew_ms = 0\n",
            "cluster.renew_ms",
        ),
        (
            "[cluster]\nnode_id = \"a\"\nadvertise = \"host :1\"\n",
            "cluster.advertise",
        ),
        (
            "[cluster]\nnode_id = \"a\"\nposition_reads = 0\n",
            "cluster.position_reads",
        ),
        (
            "[cluster]\nnode_id = \"a\"\nposition_read_ms = 0\n",
            "cluster.position_read_ms",
        ),
    ] {
        assert_eq!(invalid_field(&format!("{pg}{cluster}")), field, "{cluster}");
    }
    let c = ServerConfig::from_toml_str(&format!("{pg}[cluster]\nnode_id = \"node-1\"\n")).unwrap();
    let cluster = c.cluster.unwrap();
    assert_eq!(cluster.node_id, "node-1");
    assert!(cluster.adopt && cluster.advertise.is_empty());
    assert_eq!(
        (cluster.lease_ms, cluster.renew_ms),
        (
            strata_server::cluster::DEFAULT_LEASE_MS,
            strata_server::cluster::DEFAULT_RENEW_MS
        )
    );
    assert_eq!(
        (cluster.position_reads, cluster.position_read_ms),
        (
            strata_server::cluster::DEFAULT_POSITION_READS,
            strata_server::cluster::DEFAULT_POSITION_READ_MS
        )
    );
    assert!(
        cluster.position_reads < c.store.postgres.max_connections,
        "the default leaves the pool connections"
    );
    // Reads leave the pool a connection for commits (a pool of one is
    // shared): a config that asks for more starts, with fewer.
    for (pool, asked, used) in [(9, 8, 8), (8, 8, 7), (2, 2, 1), (1, 2, 1)] {
        let text = format!(
            "{pg}max_connections = {pool}\n[cluster]\nnode_id = \"a\"\nposition_reads = {asked}\n"
        );
        let c = ServerConfig::from_toml_str(&text).unwrap();
        let reads = c.cluster.unwrap().position_reads_with(pool);
        assert_eq!(reads, used, "pool {pool}, asked {asked}");
    }
    assert_eq!(ServerConfig::default().cluster, None);
}

#[test]
fn the_cluster_examples_are_valid_nodes_of_one_cluster() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/cluster");
    let mut ids = Vec::new();
    for i in 1..=3 {
        let path = dir.join(format!("node-{i}.toml"));
        let c = ServerConfig::load(Some(path.as_path())).unwrap();
        c.validate().unwrap();
        assert_eq!(
            c.store.backend,
            strata_server::store::StoreBackend::Postgres
        );
        let cluster = c.cluster.expect("a [cluster] section");
        assert_eq!(cluster.node_id, format!("node-{i}"));
        assert!(cluster.advertise.contains(&format!("node-{i}")));
        ids.push(cluster.node_id);
    }
    ids.dedup();
    assert_eq!(ids.len(), 3, "unique node ids");
}
