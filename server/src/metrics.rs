//! Prometheus metrics: names in one place, exporter on a configurable port.

use std::net::SocketAddr;

use std::sync::Arc;
use std::time::Duration;

use axum::http::StatusCode;
use axum::routing::get;
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};

use crate::health::Health;

pub const CONNECTIONS: &str = "strata_connections";
pub const SESSIONS_TOTAL: &str = "strata_sessions_total";
pub const EDITS_ACCEPTED: &str = "strata_edits_accepted_total";
pub const EDITS_REJECTED: &str = "strata_edits_rejected_total";
pub const QUEUE_DEPTH: &str = "strata_sequencer_queue_depth";
pub const FLUSH_SECONDS: &str = "strata_flush_seconds";
pub const FSYNC_SECONDS: &str = "strata_fsync_seconds";
pub const STORE_FLUSH_NUDGES: &str = "strata_store_flush_nudges_total";
pub const CHECKPOINT_SECONDS: &str = "strata_checkpoint_seconds";
pub const CHECKPOINT_CHUNKS_TOTAL: &str = "strata_checkpoint_chunks_total";
/// Encoded bytes handed to the store, by `kind`: `commit` (a group
/// commit's log page, deltas and chunk records) or `checkpoint` (chunk
/// records rewritten with their deltas folded in). What the disk takes is
/// more: the store's own framing, rewrites and the file system's journal.
pub const STORE_BYTES: &str = "strata_store_bytes_total";
pub const TICK_SECONDS: &str = "strata_tick_seconds";
pub const TICK_LANES: &str = "strata_tick_lanes";
pub const TICKS_APPLIED_AHEAD: &str = "strata_ticks_applied_ahead_total";
/// Collision meshes built on the engine's behalf, by `kind`: `changed` (one
/// per chunk a tick changed), `rewarm` (a stale neighbour mesh
/// rebuilt by the tick) or `on_demand` (built while a check waited).
pub const COLLISION_MESHES: &str = "strata_collision_meshes_total";
/// Cell layers (32 a chunk) of the tick's collision meshes by `how`:
/// `meshed`, or `reused` (copied from the chunk's previous mesh, which the
/// change could not reach).
pub const MESH_LAYERS: &str = "strata_mesh_layers_total";
/// The tick's collision meshes by how much of their neighbourhood was
/// copied: `copied="layers"` (only the layers the re-mesh reads: the tick
/// knew which its changes reach) or `copied="whole"`.
pub const MESH_NEIGHBOURHOODS: &str = "strata_mesh_neighbourhoods_total";
/// Rewarmed collision meshes by `outcome`: `used` (looked up before being
/// dropped) or `wasted` (dropped unused: stale again, replaced or evicted).
pub const COLLISION_REWARMS: &str = "strata_collision_rewarms_total";
/// Generated-chunk cache lookups by `cache` (`premesh`, `patch_base`) and
/// `outcome` (`hit`, or `generated` again).
pub const GENERATED_CHUNKS: &str = "strata_generated_chunks_total";
/// Snapshot-frame cache lookups by `outcome`: `hit`, `miss`, `evicted`
/// (entries dropped when it filled up) or `evicted_requested`.
pub const SNAPSHOT_CACHE: &str = "strata_snapshot_cache_total";
/// Snapshot and patch frames built, by `on`: `workers` (ahead of the
/// streaming loop, in parallel) or `engine` (by the loop itself).
pub const SNAPSHOT_FRAMES_BUILT: &str = "strata_snapshot_frames_built_total";
pub const EDIT_LATENCY_SECONDS: &str = "strata_edit_latency_seconds";
/// From a session decoding an edit to the engine taking it: how long
/// edits wait in the engine's queue (QUIC's part comes before it).
pub const EDIT_INBOX_SECONDS: &str = "strata_edit_inbox_seconds";
pub const TICK_PHASE_SECONDS: &str = "strata_tick_phase_seconds";
/// A tick's apply by `part`: wait, prepare, lanes, merge (`ApplySplit`).
pub const APPLY_PART_SECONDS: &str = "strata_apply_part_seconds";
pub const BYTES_SENT: &str = "strata_bytes_sent_total";
pub const UDP_DATAGRAMS: &str = "strata_udp_datagrams_total";
pub const UDP_BYTES: &str = "strata_udp_bytes_total";
pub const QUIC_LOST_PACKETS: &str = "strata_quic_lost_packets_total";
pub const QUIC_CONGESTION_EVENTS: &str = "strata_quic_congestion_events_total";
pub const QUIC_RTT_SECONDS: &str = "strata_quic_rtt_seconds";
pub const DELTAS_DROPPED: &str = "strata_deltas_dropped_total";
pub const DELTAS_SENT: &str = "strata_deltas_sent_total";
/// A session's batch of a tick's updates, by how it went: `written` into
/// the stream at once, `begun` (its rest left to the writer), `queued`.
pub const FANOUT_BATCHES: &str = "strata_fanout_batches_total";
pub const OPS_SENT: &str = "strata_ops_sent_total";
pub const POSITIONS_DROPPED: &str = "strata_positions_dropped_total";
pub const POSITIONS_REFUSED: &str = "strata_positions_refused_total";
pub const REQUESTS_THROTTLED: &str = "strata_requests_throttled_total";
pub const SESSION_QUEUE_FULL: &str = "strata_session_queue_full_total";
pub const RESYNCS: &str = "strata_resyncs_total";
pub const RESIDENT_CHUNKS: &str = "strata_resident_chunks";
/// Regions a cluster node holds the lease of (`[cluster] max_held_regions`
/// bounds it).
pub const REGIONS_HELD: &str = "strata_cluster_regions_held";
/// Edits refused because claiming their regions would pass
/// `max_held_regions`.
pub const REGION_CLAIMS_REFUSED: &str = "strata_cluster_claims_refused_total";
/// Regions let go by a cluster node's renewals, by `why`: `idle` (no edit
/// in `[cluster] release_idle_ms`), `cap` (past half of
/// `max_held_regions`) or `handoff` (another node asked for it, and no
/// edit here in `handoff_idle_ms`).
pub const REGIONS_RELEASED: &str = "strata_cluster_regions_released_total";
pub const PREMESH_BUILT: &str = "strata_premesh_meshes_total";
pub const PREMESH_STALE: &str = "strata_premesh_stale_total";
pub const PREMESH_SKIPPED: &str = "strata_premesh_skipped_total";
pub const PATCH_BYTES: &str = "strata_patch_payload_bytes_total";
pub const SNAPSHOTS_SENT: &str = "strata_snapshots_sent_total";
pub const SESSIONS_KICKED: &str = "strata_sessions_kicked_total";
pub const CONNECTIONS_REFUSED: &str = "strata_connections_refused_total";
pub const CONNECTIONS_RETRIED: &str = "strata_connections_retried_total";
pub const LOG_PRUNED_TOTAL: &str = "strata_log_pruned_total";
pub const STORE_ERRORS: &str = "strata_store_errors_total";
pub const STORE_COMMIT_RETRIES: &str = "strata_store_commit_retries_total";

/// How often the recorder's rolling summaries are advanced.
pub const UPKEEP_EVERY: Duration = Duration::from_secs(5);
/// The name of the thread that runs the upkeep.
pub const UPKEEP_THREAD: &str = "strata-metrics";

/// The process's Prometheus recorder, installed by the first call (the
/// metrics listener and the web console read the same one).
pub fn shared() -> anyhow::Result<PrometheusHandle> {
    static HANDLE: std::sync::Mutex<Option<PrometheusHandle>> = std::sync::Mutex::new(None);
    let mut slot = HANDLE.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(h) = &*slot {
        return Ok(h.clone());
    }
    let h = install()?;
    *slot = Some(h.clone());
    Ok(h)
}

/// Installs the Prometheus recorder (call once, before anything records;
/// [`shared`] does so once per process).
pub fn install() -> anyhow::Result<PrometheusHandle> {
    let handle = PrometheusBuilder::new().install_recorder()?;
    // The recorder keeps every histogram sample until a render or an
    // upkeep drains it: without the metrics endpoint (a console nobody
    // watches) that is hundreds of MB a day. A thread of its own, so no
    // runtime need be running.
    let upkeep = handle.clone();
    std::thread::Builder::new()
        .name(UPKEEP_THREAD.into())
        .spawn(move || loop {
            std::thread::sleep(UPKEEP_EVERY);
            upkeep.run_upkeep();
        })?;
    metrics::describe_gauge!(CONNECTIONS, "Open QUIC connections");
    metrics::describe_counter!(
        LOG_PRUNED_TOTAL,
        "Edit log entries removed as older than [store] log_retention"
    );
    metrics::describe_counter!(
        STORE_ERRORS,
        "Store operations that failed outside a commit, by op (read: chunks a player or the premesher needed; regions: a cluster node's claims and holders; checkpoint; prune; seqs: a cluster node's next seq block)"
    );
    metrics::describe_counter!(
        STORE_COMMIT_RETRIES,
        "Commits tried again, or their outcome asked again, while PostgreSQL was unreachable (a server without [cluster], within [store.postgres] commit_retry_ms)"
    );
    metrics::describe_counter!(SESSIONS_TOTAL, "Sessions that joined the world");
    metrics::describe_counter!(
        CONNECTIONS_REFUSED,
        "Connections turned away, by reason (handshakes, per_address, sessions, admin_sessions, join_rate; a token that does not verify: bad_token; a banned player or revoked token: denied; a player's token on the admin protocol: not_admin; on a cluster node, logins whose stored position was not read: position_reads, no turn in [cluster] position_read_ms; position_read_slow, the read did not end in it; position_read_failed)"
    );
    metrics::describe_counter!(
        CONNECTIONS_RETRIED,
        "Connection attempts from unvalidated addresses answered with a QUIC Retry ([server] retry_above_handshakes)"
    );
    metrics::describe_counter!(
        SESSIONS_KICKED,
        "Sessions the server disconnected for misbehaving, by reason"
    );
    metrics::describe_counter!(
        REQUESTS_THROTTLED,
        "Requests (subscriptions, resyncs, forgets, snapshots, tickets, pings, edits, a session's first view) that waited for their player's [validation.request_rate] tokens"
    );
    metrics::describe_counter!(
        SESSION_QUEUE_FULL,
        "Requests that found their session's share of the engine queue ([engine] session_commands) in use: a request waited, an edit was answered Busy"
    );
    metrics::describe_counter!(
        POSITIONS_DROPPED,
        "Position datagrams dropped: reason=rate past the session's [validation.position_rate], queue_full when the engine's queue was full, placement past the player's [validation.placement_rate] (reports of a session with no position yet)"
    );
    metrics::describe_counter!(
        POSITIONS_REFUSED,
        "Position reports refused by a rule, by reason: too_fast, inside_solid, path_blocked (a wall between the held position and the report), too_high (gravity), outside_spawn, bounds; stale ones are not counted"
    );
    metrics::describe_counter!(
        DELTAS_SENT,
        "Chunk deltas queued to sessions (one per session that sees the chunk)"
    );
    metrics::describe_counter!(
        FANOUT_BATCHES,
        "Sessions' batches of a tick's updates, by how they went: written (into the QUIC stream at once, by a fan-out worker), begun (the rest left to the session's writer), queued (to the writer task)"
    );
    metrics::describe_counter!(
        OPS_SENT,
        "Edits sent as one op instead of deltas (one per session that replays it)"
    );
    metrics::describe_counter!(EDITS_ACCEPTED, "Edits acknowledged after they were durable");
    metrics::describe_counter!(EDITS_REJECTED, "Edits refused, by reason");
    metrics::describe_gauge!(
        QUEUE_DEPTH,
        "Edits waiting for the sequencer (their sight check or the tick)"
    );
    metrics::describe_histogram!(FLUSH_SECONDS, "Group-commit latency");
    metrics::describe_histogram!(
        FSYNC_SECONDS,
        "The fsyncs that end a group commit (part of its latency)"
    );
    metrics::describe_counter!(
        STORE_FLUSH_NUDGES,
        "sled flushes that ran past 250 ms, so the store flushed again to wake them (a failed disk, or a slow one)"
    );
    metrics::describe_histogram!(
        CHECKPOINT_SECONDS,
        "Background checkpoint passes (folding committed deltas into chunk records): time spent folding, pauses left out"
    );
    metrics::describe_counter!(
        CHECKPOINT_CHUNKS_TOTAL,
        "Chunks whose deltas a checkpoint folded into their records"
    );
    metrics::describe_counter!(
        STORE_BYTES,
        "Encoded bytes handed to the store, by kind (commit, checkpoint)"
    );
    metrics::describe_histogram!(TICK_SECONDS, "Sequencer tick duration");
    metrics::describe_counter!(
        TICKS_APPLIED_AHEAD,
        "Batches applied while the one before them committed (an engine behind its tick rate)"
    );
    metrics::describe_counter!(
        COLLISION_MESHES,
        "Collision meshes built: kind=changed (chunks a tick changed), rewarm (stale neighbour meshes rebuilt by a tick), on_demand (a line-of-sight check waited)"
    );
    metrics::describe_counter!(
        MESH_LAYERS,
        "Cell layers of the ticks' collision meshes by how: meshed, or reused (copied from the chunk's previous mesh)"
    );
    metrics::describe_counter!(
        MESH_NEIGHBOURHOODS,
        "The ticks' collision meshes by what of their neighbourhood was copied: copied=layers (only the layers a change reached and around them) or whole"
    );
    metrics::describe_counter!(
        COLLISION_REWARMS,
        "Rewarmed collision meshes by outcome: used (looked up before being dropped) or wasted (dropped unused)"
    );
    metrics::describe_counter!(
        GENERATED_CHUNKS,
        "Generated-chunk cache lookups by cache (premesh, patch_base) and outcome (hit, generated)"
    );
    metrics::describe_counter!(
        SNAPSHOT_CACHE,
        "Snapshot-frame cache lookups by outcome (hit, miss), and frames evicted from a full cache: evicted (the shared frames), evicted_requested (whole frames kept for clients that ask for them)"
    );
    metrics::describe_counter!(
        SNAPSHOT_FRAMES_BUILT,
        "Snapshot and patch frames built, on the workers ahead of streaming or on the engine thread"
    );
    metrics::describe_histogram!(
        TICK_LANES,
        "Lanes of joined regions a tick with edits applied in parallel"
    );
    metrics::describe_histogram!(
        EDIT_LATENCY_SECONDS,
        "From the engine taking an edit to its acknowledgement (durable)"
    );
    metrics::describe_histogram!(
        EDIT_INBOX_SECONDS,
        "From a session decoding an edit to the engine taking it"
    );
    metrics::describe_histogram!(
        TICK_PHASE_SECONDS,
        "Tick time by phase: apply, apply_ahead (the next batch applied while one commits), commit, mesh_wait, finish (meshes in, acknowledgements), fanout, stream, evict"
    );
    metrics::describe_histogram!(
        APPLY_PART_SECONDS,
        "A tick's apply by part: wait (for a worker), prepare (serial), lanes (parallel), merge (serial, neighbourhoods copied in parallel)"
    );
    metrics::describe_counter!(BYTES_SENT, "Bytes written to clients");
    metrics::describe_counter!(
        UDP_DATAGRAMS,
        "UDP datagrams of client and admin connections, by direction (sent, received)"
    );
    metrics::describe_counter!(
        UDP_BYTES,
        "UDP payload bytes of client and admin connections (QUIC headers, ACKs and retransmissions included), by direction"
    );
    metrics::describe_counter!(QUIC_LOST_PACKETS, "Packets QUIC declared lost");
    metrics::describe_counter!(
        QUIC_CONGESTION_EVENTS,
        "Congestion events (a connection's congestion window shrank)"
    );
    metrics::describe_histogram!(
        QUIC_RTT_SECONDS,
        "Smoothed round-trip time, one reading per open connection every 5 s"
    );
    metrics::describe_gauge!(RESIDENT_CHUNKS, "Chunks held in the sequencer's memory");
    metrics::describe_gauge!(REGIONS_HELD, "Regions this cluster node holds the lease of");
    metrics::describe_counter!(
        REGION_CLAIMS_REFUSED,
        "Edits refused because their regions would pass [cluster] max_held_regions"
    );
    metrics::describe_counter!(
        REGIONS_RELEASED,
        "Regions let go by this cluster node's renewals, by why (idle, cap, handoff)"
    );
    metrics::describe_counter!(PREMESH_BUILT, "Collision meshes built ahead of need");
    metrics::describe_counter!(PREMESH_STALE, "Background meshes dropped as outdated");
    metrics::describe_counter!(
        PREMESH_SKIPPED,
        "Player chunks dropped from the full background-mesh backlog"
    );
    metrics::describe_counter!(
        PATCH_BYTES,
        "Payload bytes of patches built (modified chunks sent as deltas from generated)"
    );
    metrics::describe_counter!(SNAPSHOTS_SENT, "Chunk frames streamed, by kind");
    Ok(handle)
}

/// Binds the metrics listener (`[metrics] listen`); fails early if taken.
pub async fn bind(addr: SocketAddr) -> anyhow::Result<tokio::net::TcpListener> {
    Ok(tokio::net::TcpListener::bind(addr).await?)
}

/// Default connections the metrics listener holds at once
/// (`[metrics] max_connections`).
pub const DEFAULT_MAX_CONNECTIONS: usize = 32;
/// Largest `[metrics] max_connections`.
pub const MAX_CONNECTIONS: usize = 4096;
/// A metrics connection silent this long, or a request unanswered this
/// long, is closed: scrapers do not hold slots idle.
pub const CONNECTION_DEADLINE: std::time::Duration = std::time::Duration::from_secs(10);

/// Serves `GET /metrics` (Prometheus text) and `GET /healthz` (200 `ready`,
/// or 503 with the reason) until the task is dropped, on at most
/// `max_connections` connections at once. When every one is taken, a new
/// connection closes the oldest accepted over a second ago that is between
/// requests, else one sending a request or held up writing its answer for
/// over a second (`console::conn_limit`): connections left silent, sending
/// request after request or reading slowly cannot keep a readiness probe
/// out.
pub async fn serve(
    listener: tokio::net::TcpListener,
    max_connections: usize,
    handle: PrometheusHandle,
    health: Arc<Health>,
) {
    let app = axum::Router::new()
        .route("/metrics", get(move || std::future::ready(handle.render())))
        .route(
            "/healthz",
            get(move || {
                std::future::ready(match health.check() {
                    Ok(()) => (StatusCode::OK, "ready\n"),
                    Err(why) => (StatusCode::SERVICE_UNAVAILABLE, why),
                })
            }),
        );
    let limited = crate::console::LimitedListener::new(
        listener,
        max_connections,
        crate::console::Deadlines {
            idle: CONNECTION_DEADLINE,
            request: CONNECTION_DEADLINE,
            // No request here is ever admitted: each may be closed alike.
            unadmitted: Some(CONNECTION_DEADLINE),
        },
    );
    if let Err(e) = axum::serve(limited, app).await {
        tracing::error!(error = %e, "metrics listener failed");
    }
}

pub use strata_protocol::reject_label;

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    async fn get(addr: SocketAddr, path: &str) -> String {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        let req = format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
        s.write_all(req.as_bytes()).await.unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).await.unwrap();
        out
    }

    /// The recorder's samples are drained whether or not an endpoint
    /// serves them (the console alone installs it too).
    #[test]
    fn the_shared_recorder_comes_with_its_upkeep_thread() {
        let upkeep_threads = || {
            std::fs::read_dir("/proc/self/task")
                .unwrap()
                .filter_map(|t| std::fs::read_to_string(t.unwrap().path().join("comm")).ok())
                .filter(|name| name.trim_end() == UPKEEP_THREAD)
                .count()
        };
        shared().unwrap();
        shared().unwrap();
        // A thread names itself once it runs.
        let started = std::time::Instant::now();
        while upkeep_threads() == 0 && started.elapsed() < Duration::from_secs(10) {
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(upkeep_threads(), 1);
    }

    #[tokio::test]
    async fn healthz_follows_the_server_and_metrics_render() {
        let listener = bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
        let addr = listener.local_addr().unwrap();
        let handle = PrometheusBuilder::new().build_recorder().handle();
        let health = Arc::new(Health::default());
        let server = tokio::spawn(serve(listener, 4, handle, health.clone()));
        let r = get(addr, "/healthz").await;
        assert!(
            r.starts_with("HTTP/1.1 503") && r.ends_with("not accepting connections"),
            "{r}"
        );
        health.set_accepting(true);
        let r = get(addr, "/healthz").await;
        assert!(
            r.starts_with("HTTP/1.1 200") && r.ends_with("ready\n"),
            "{r}"
        );
        health.engine_stopped();
        let r = get(addr, "/healthz").await;
        assert!(
            r.starts_with("HTTP/1.1 503") && r.ends_with("engine stopped"),
            "{r}"
        );
        assert!(get(addr, "/metrics").await.starts_with("HTTP/1.1 200"));
        assert!(get(addr, "/nothing").await.starts_with("HTTP/1.1 404"));
        server.abort();
    }

    /// A connection sending a request keeps its slot for a second at
    /// least; a silent one, or one trickling a request for longer, makes
    /// room for a new one: a readiness probe is answered while silent
    /// connections hold every slot.
    #[tokio::test]
    async fn the_endpoint_holds_at_most_its_connections_silent_ones_make_room() {
        let handle = PrometheusBuilder::new().build_recorder().handle();
        let listener = bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
        let addr = listener.local_addr().unwrap();
        let server = tokio::spawn(serve(listener, 2, handle.clone(), Arc::default()));
        let connect = || tokio::net::TcpStream::connect(addr);
        let (mut silent, mut trickling) = (connect().await.unwrap(), connect().await.unwrap());
        trickling
            .write_all(b"GET /metrics HTTP/1.1\r\n")
            .await
            .unwrap();
        // Let the server take both first: they hold the two slots.
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        let r = tokio::time::timeout(std::time::Duration::from_secs(5), get(addr, "/healthz"))
            .await
            .expect("answered past a silent connection");
        assert!(r.starts_with("HTTP/1.1 503"), "{r}");
        let mut buf = [0u8; 64];
        assert_eq!(
            silent.read(&mut buf).await.unwrap_or(0),
            0,
            "silent one closed"
        );
        drop(trickling);
        server.abort();

        // One slot, held by a request being sent: the next waits for its
        // grace, then takes it.
        let listener = bind("127.0.0.1:0".parse().unwrap()).await.unwrap();
        let addr = listener.local_addr().unwrap();
        let server = tokio::spawn(serve(listener, 1, handle, Arc::default()));
        let mut trickling = tokio::net::TcpStream::connect(addr).await.unwrap();
        trickling
            .write_all(b"GET /metrics HTTP/1.1\r\n")
            .await
            .unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        let waiting = tokio::spawn(get(addr, "/metrics"));
        tokio::time::sleep(std::time::Duration::from_millis(300)).await;
        assert!(!waiting.is_finished(), "served beyond the cap");
        let r = tokio::time::timeout(std::time::Duration::from_secs(10), waiting)
            .await
            .expect("served once the request's grace is over")
            .unwrap();
        assert!(r.starts_with("HTTP/1.1 200"), "{r}");
        assert_eq!(
            trickling.read(&mut buf).await.unwrap_or(0),
            0,
            "trickler closed"
        );
        server.abort();
    }
}
