//! strata-server's integration tests, one module per file beside this one,
//! in one test binary: the server and its dependencies are linked once, not
//! once per file (CI's test build, README). Run one file's tests with
//! `cargo test -p strata-server --test integration -- net_edits::`.

// Shared helpers; `common` also brings `on_both_backends!`.
#[macro_use]
mod common;
mod offline_common;
mod sequencer_common;
mod snapshot_common;
mod store_common;

mod admin_access;
mod admin_check;
mod admin_cli;
mod admin_export;
mod admin_map;
mod admin_online;
mod admin_snapshot_cow;
mod admin_snapshot_file;
mod admin_snapshot_stop;
mod auth_secret_duration;
mod auth_tls_quic;
mod auth_tokens;
mod client_hostile_server;
mod cluster_routing;
mod config_datadir;
mod config_load;
mod console_api;
mod deploy_files;
mod durability;
mod health_store;
mod mesh_cli;
mod metrics_endpoint;
mod net_admission;
mod net_auth;
mod net_chained_commits;
mod net_continuity;
mod net_edits;
mod net_eviction;
mod net_frame_cache;
mod net_heightmap;
mod net_interest;
mod net_join_order;
mod net_mesh_hashes;
mod net_queue_share;
mod net_rejoin;
mod net_robustness;
mod net_stream;
mod net_threads;
mod net_transport;
mod sequencer_apply;
mod sequencer_fuzz;
mod sequencer_interest;
mod sequencer_regions;
mod snapshot_restore;
mod store_batch;
mod store_bench;
mod store_check;
mod store_crash;
mod store_deltas;
mod store_generated;
mod store_pg;
mod store_pg_bench;
mod store_pg_lease;
mod store_pg_outage;
mod store_power_cut;
mod store_roundtrip;
mod validate_config;
mod validate_position;
mod validate_rules;
