//! The end-of-run summary: one JSON line with `--json`, else a short table.

use std::collections::BTreeMap;
use std::fmt::Write;

use serde::Serialize;

use super::stats::{Latencies, LatencyMs};
use crate::prediction::PredictionStats;

/// Pairs the per-second ack and broadcast latencies of a run.
pub fn timeline(ack: &Latencies, broadcast: &Latencies) -> Vec<SecondLatency> {
    let (a, b) = (ack.timeline(), broadcast.timeline());
    (0..a.len().max(b.len()))
        .map(|second| SecondLatency {
            second,
            ack: a.get(second).copied().unwrap_or_default(),
            broadcast: b.get(second).copied().unwrap_or_default(),
        })
        .collect()
}

/// Latencies observed in one second of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct SecondLatency {
    pub second: usize,
    pub ack: LatencyMs,
    pub broadcast: LatencyMs,
}

/// What a run measured and whether every replica converged.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Summary {
    pub bots: usize,
    pub profile: String,
    /// Seconds of editing (the `--duration`).
    pub duration_s: f64,
    /// Bots that stopped reading their updates (`--stalled`).
    pub stalled: usize,
    pub connected_at_end: usize,
    /// Bots whose task panicked: their counters and replicas are missing
    /// from everything below, and the run is not consistent.
    pub bots_failed: usize,
    /// Connections a bot had to open again after losing one.
    pub reconnects: u64,
    pub edits_sent: u64,
    pub edits_accepted: u64,
    /// Rejections by reason (snake_case names of `RejectReason`).
    pub edits_rejected: BTreeMap<String, u64>,
    /// Edits whose connection ended before the verdict arrived.
    pub edits_unanswered: u64,
    /// Edit slots skipped: no target in reach and sight.
    pub edits_skipped: u64,
    /// Edit slots that fell due while the bot's last edit still awaited its
    /// verdict (or while a step ran late), so no edit was sent for them: a
    /// server slow to answer sends fewer edits, and `ack_latency_ms` does
    /// not see the wait they would have had (coordinated omission).
    pub edit_slots_skipped: u64,
    /// Times a bot walked from one region into another (regions of
    /// `--region-chunks` chunks, as the server's `[sequencer] region_chunks`).
    pub region_crossings: u64,
    /// Times a bot moved to the cluster node a `RegionElsewhere` named and
    /// arrived there with its ticket (`--follow-owners`).
    pub handoffs: u64,
    /// `PositionRefused` answers the bots heard, by reason (snake_case);
    /// each moved its bot back to where the server held it.
    pub positions_refused: BTreeMap<String, u64>,
    pub edits_accepted_per_second: f64,
    /// From sending an edit to its `EditAccepted`: accepted edits only
    /// (refused ones are in `edits_rejected`, those never answered in
    /// `edits_unanswered`, slots never sent in `edit_slots_skipped`).
    pub ack_latency_ms: LatencyMs,
    /// From sending an edit to the arrival of its delta at another bot.
    pub broadcast_latency_ms: LatencyMs,
    /// Ack and broadcast latency per second of the run (by the second the
    /// latency was observed), to tell ramp-up from steady state.
    pub latency_by_second: Vec<SecondLatency>,
    /// Updates-stream bytes received, summed over bots.
    pub bytes_in: u64,
    /// Control-stream and datagram bytes sent, summed over bots.
    pub bytes_out: u64,
    pub deltas: u64,
    /// Mean delta payload, in bytes.
    pub mean_delta_bytes: f64,
    /// Whole chunks received: snapshots and patches.
    pub snapshots: u64,
    /// Of those, patches (modified chunks as deltas from generated).
    pub patched: u64,
    /// Chunks regenerated from the seed (`Generated`; 0 with `--thin`).
    pub generated: u64,
    /// Chunks taken forward by replaying ops (`--op-replay`).
    pub op_chunks: u64,
    /// Op chunks whose replayed hash differed from the server's (each
    /// resynced; also in `resyncs`).
    pub op_mismatches: u64,
    /// Resync requests the replicas sent (version gaps, bad hashes).
    pub resyncs: u64,
    pub meshes_checked: u64,
    pub mesh_mismatches: u64,
    /// Replica chunks compared with the server's copy at the end.
    pub chunks_verified: u64,
    /// Compared chunks whose version or hash differed from the server's.
    pub replica_mismatches: u64,
    /// Chunks the server did not answer for before the timeout.
    pub chunks_unverified: u64,
    /// Two bots, or two connections of one bot, holding different contents
    /// for one chunk version; a replica whose versions of a chunk went
    /// backwards; or a bot that received a chunk older after a reconnect
    /// than before it.
    pub order_violations: u64,
    /// Final replica chunks older than an acknowledged version.
    pub ack_missing: u64,
    /// The world went quiet before the end-of-run check.
    pub quiet: bool,
    /// Seconds from the start until every bot had joined and loaded its
    /// surroundings (at most the ramp timeout); edits start after it.
    pub ramp_s: f64,
    /// Bots ready when the edits started.
    pub ready_at_start: usize,
    /// Seconds spent waiting for quiet, then comparing with the server.
    pub quiet_wait_s: f64,
    pub verify_s: f64,
    /// The bots' client-side predictions, summed (`null` without `--predict`).
    pub prediction: Option<PredictionStats>,
    /// What the hostile players did and what got through (`null` without
    /// `--hostile`). Everything above counts the honest bots only.
    pub hostile: Option<HostileSummary>,
}

/// The hostile players of a run (`--hostile N --attack KIND`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct HostileSummary {
    /// The attack's name (`position-flood`, `rejected-edits`...).
    pub attack: String,
    /// Hostile players that ran it.
    pub players: usize,
    /// Seconds from the hostiles' start until the last one stopped.
    pub duration_s: f64,
    /// The attack's counters, summed over its players; every counter the
    /// attack documents (`Attack::counters`) is present, zeros included.
    pub counters: BTreeMap<String, u64>,
    /// Refused edits by reason (snake_case names of `RejectReason`).
    pub rejected: BTreeMap<String, u64>,
    /// Connections the server closed or refused, by reason: the
    /// `ErrorCode` name (`Kicked`, `NotAuthenticated`...) or the kind of
    /// QUIC close (`refused`, `timed_out`, `transport`...).
    pub closed_by_server: BTreeMap<String, u64>,
}

impl Summary {
    /// True when every replica converged on the server's world.
    pub fn consistent(&self) -> bool {
        self.quiet
            && self.bots_failed == 0
            && self.replica_mismatches == 0
            && self.mesh_mismatches == 0
            && self.chunks_unverified == 0
            && self.order_violations == 0
            && self.ack_missing == 0
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("plain data serializes")
    }

    /// A few human-readable lines.
    pub fn human(&self) -> String {
        let mut s = String::new();
        let l = |x: &LatencyMs| {
            format!(
                "p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms",
                x.p50, x.p99, x.max
            )
        };
        let _ = writeln!(
            s,
            "{} bots ({}) for {:.0} s, {} connected at the end, {} reconnects{}",
            self.bots,
            self.profile,
            self.duration_s,
            self.connected_at_end,
            self.reconnects,
            if self.bots_failed > 0 {
                format!(", {} failed (panicked)", self.bots_failed)
            } else {
                String::new()
            }
        );
        let rejected: u64 = self.edits_rejected.values().sum();
        let _ = writeln!(
            s,
            "edits: {} sent, {} accepted ({:.1}/s), {} rejected {:?}, {} unanswered",
            self.edits_sent,
            self.edits_accepted,
            self.edits_accepted_per_second,
            rejected,
            self.edits_rejected,
            self.edits_unanswered
        );
        let _ = writeln!(
            s,
            "ack latency (accepted edits only): {}; not timed: {} rejected, {} unanswered, {} slots skipped while an edit awaited its verdict",
            l(&self.ack_latency_ms),
            rejected,
            self.edits_unanswered,
            self.edit_slots_skipped
        );
        let _ = writeln!(s, "broadcast latency: {}", l(&self.broadcast_latency_ms));
        let _ = writeln!(
            s,
            "traffic: {} B in, {} B out, {} deltas (mean {:.0} B), {} snapshots ({} patches), {} generated, {} op chunks ({} mismatched), {} resyncs",
            self.bytes_in,
            self.bytes_out,
            self.deltas,
            self.mean_delta_bytes,
            self.snapshots,
            self.patched,
            self.generated,
            self.op_chunks,
            self.op_mismatches,
            self.resyncs
        );
        let _ = writeln!(
            s,
            "consistency: {} chunks verified, {} replica mismatches, {} unverified, {} of {} meshes mismatched, {} order violations, {} acked versions missing{}",
            self.chunks_verified,
            self.replica_mismatches,
            self.chunks_unverified,
            self.mesh_mismatches,
            self.meshes_checked,
            self.order_violations,
            self.ack_missing,
            if self.quiet { "" } else { " (world never went quiet)" }
        );
        if let Some(p) = &self.prediction {
            let _ = writeln!(
                s,
                "prediction: {} made, {} exact ({:.1}%), {} mispredicted ({} only outside the edit's box), {} rolled back, {} unverified, {} pending, {} skipped",
                p.made,
                p.exact,
                100.0 * p.exact as f64 / p.made.max(1) as f64,
                p.mispredicted,
                p.mispredicted_outside_box,
                p.rolled_back,
                p.unverified,
                p.pending,
                p.skipped
            );
        }
        if let Some(h) = &self.hostile {
            let _ = writeln!(
                s,
                "hostile: {} x {} for {:.1} s: {:?}, rejected {:?}, closed by the server {:?}",
                h.players, h.attack, h.duration_s, h.counters, h.rejected, h.closed_by_server
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_has_the_documented_keys() {
        let s = Summary {
            bots: 2,
            quiet: true,
            ..Default::default()
        };
        assert!(s.consistent());
        let v: serde_json::Value = serde_json::from_str(&s.to_json()).unwrap();
        for key in [
            "bots",
            "edits_sent",
            "edits_accepted",
            "edits_rejected",
            "edits_unanswered",
            "edit_slots_skipped",
            "bots_failed",
            "ack_latency_ms",
            "broadcast_latency_ms",
            "bytes_in",
            "bytes_out",
            "mean_delta_bytes",
            "resyncs",
            "replica_mismatches",
            "mesh_mismatches",
        ] {
            assert!(v.get(key).is_some(), "{key}");
        }
        assert!(v["ack_latency_ms"].get("p99").is_some());
        assert!(s.human().contains("2 bots"));
        assert!(v["prediction"].is_null() && !s.human().contains("prediction"));
        assert!(v["hostile"].is_null() && !s.human().contains("hostile"));
        let hostile = Summary {
            hostile: Some(HostileSummary {
                attack: "teleport".into(),
                players: 1,
                counters: [("jumps".to_string(), 3)].into(),
                ..Default::default()
            }),
            ..s.clone()
        };
        let v: serde_json::Value = serde_json::from_str(&hostile.to_json()).unwrap();
        assert_eq!(v["hostile"]["attack"], "teleport");
        assert_eq!(v["hostile"]["counters"]["jumps"], 3);
        assert!(hostile.human().contains("hostile: 1 x teleport"));
        let predicted = Summary {
            prediction: Some(PredictionStats {
                made: 4,
                exact: 3,
                ..Default::default()
            }),
            ..s.clone()
        };
        let v: serde_json::Value = serde_json::from_str(&predicted.to_json()).unwrap();
        assert_eq!(v["prediction"]["exact"], 3);
        assert!(predicted.human().contains("3 exact (75.0%)"));
        let bad = Summary {
            mesh_mismatches: 1,
            ..s.clone()
        };
        assert!(!bad.consistent());
        let failed = Summary {
            bots_failed: 1,
            ..s
        };
        assert!(!failed.consistent());
        assert!(failed.human().contains("1 failed"), "{}", failed.human());
    }
}
