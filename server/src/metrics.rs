//! Prometheus metrics: names in one place, exporter on a configurable port.

use std::net::SocketAddr;

use metrics_exporter_prometheus::PrometheusBuilder;

pub const CONNECTIONS: &str = "strata_connections";
pub const SESSIONS_TOTAL: &str = "strata_sessions_total";
pub const EDITS_ACCEPTED: &str = "strata_edits_accepted_total";
pub const EDITS_REJECTED: &str = "strata_edits_rejected_total";
pub const QUEUE_DEPTH: &str = "strata_sequencer_queue_depth";
pub const FLUSH_SECONDS: &str = "strata_flush_seconds";
pub const FSYNC_SECONDS: &str = "strata_fsync_seconds";
pub const TICK_SECONDS: &str = "strata_tick_seconds";
pub const EDIT_LATENCY_SECONDS: &str = "strata_edit_latency_seconds";
pub const TICK_PHASE_SECONDS: &str = "strata_tick_phase_seconds";
pub const BYTES_SENT: &str = "strata_bytes_sent_total";
pub const DELTAS_DROPPED: &str = "strata_deltas_dropped_total";
pub const POSITIONS_DROPPED: &str = "strata_positions_dropped_total";
pub const RESYNCS: &str = "strata_resyncs_total";
pub const RESIDENT_CHUNKS: &str = "strata_resident_chunks";
pub const PREMESH_BUILT: &str = "strata_premesh_meshes_total";
pub const PREMESH_STALE: &str = "strata_premesh_stale_total";
pub const PREMESH_SKIPPED: &str = "strata_premesh_skipped_total";
pub const PATCH_BYTES: &str = "strata_patch_payload_bytes_total";
pub const SNAPSHOTS_SENT: &str = "strata_snapshots_sent_total";
pub const SESSIONS_KICKED: &str = "strata_sessions_kicked_total";

/// Serves `/metrics` on `addr` from a background thread of the exporter.
pub fn install(addr: SocketAddr) -> anyhow::Result<()> {
    PrometheusBuilder::new()
        .with_http_listener(addr)
        .install()?;
    metrics::describe_gauge!(CONNECTIONS, "Open QUIC connections");
    metrics::describe_counter!(SESSIONS_TOTAL, "Sessions that joined the world");
    metrics::describe_counter!(
        SESSIONS_KICKED,
        "Sessions the server disconnected for misbehaving, by reason"
    );
    metrics::describe_counter!(
        POSITIONS_DROPPED,
        "Position datagrams dropped because the engine's queue was full"
    );
    metrics::describe_counter!(EDITS_ACCEPTED, "Edits acknowledged after they were durable");
    metrics::describe_counter!(EDITS_REJECTED, "Edits refused, by reason");
    metrics::describe_gauge!(QUEUE_DEPTH, "Edits waiting for the sequencer");
    metrics::describe_histogram!(FLUSH_SECONDS, "Group-commit latency");
    metrics::describe_histogram!(
        FSYNC_SECONDS,
        "The fsyncs that end a group commit (part of its latency)"
    );
    metrics::describe_histogram!(TICK_SECONDS, "Sequencer tick duration");
    metrics::describe_histogram!(
        EDIT_LATENCY_SECONDS,
        "From the engine taking an edit to its acknowledgement (durable)"
    );
    metrics::describe_histogram!(
        TICK_PHASE_SECONDS,
        "Tick time by phase: apply, commit, mesh_wait, fanout, stream, evict"
    );
    metrics::describe_counter!(BYTES_SENT, "Bytes written to clients");
    metrics::describe_gauge!(RESIDENT_CHUNKS, "Chunks held in the sequencer's memory");
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
    Ok(())
}

/// Metric label for a rejection reason.
pub fn reject_label(r: &strata_protocol::RejectReason) -> &'static str {
    use strata_protocol::RejectReason::*;
    match r {
        NotPermitted { .. } => "not_permitted",
        RadiusTooLarge { .. } => "radius",
        PowerTooLarge { .. } => "power",
        OutOfReach { .. } => "reach",
        NoLineOfSight => "line_of_sight",
        RateLimited => "rate",
        VolumeRateLimited => "volume_rate",
        OutOfBounds => "bounds",
        ProtectedZone { .. } => "protected_zone",
        NoPosition => "no_position",
        Invalid { .. } => "invalid",
        Busy => "busy",
    }
}
