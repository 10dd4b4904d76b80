//! Chart figures read from the server's own metrics registry (the one
//! `/metrics` serves): nothing is recorded for the console alone.
//! Counters are sent as totals (the page turns them into rates);
//! latencies are the registry's rolling p50 and p99.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::metrics as m;

/// One sample of the charts' figures.
#[derive(Debug, Default, Clone, PartialEq, Serialize)]
pub struct StatsSample {
    pub edits_accepted: f64,
    /// Refused edits by reason.
    pub edits_rejected: BTreeMap<String, f64>,
    /// Seconds from the engine taking an edit to its acknowledgement.
    pub ack_p50: Option<f64>,
    pub ack_p99: Option<f64>,
    /// Seconds of a tick's broadcast (fan-out) phase.
    pub broadcast_p50: Option<f64>,
    pub broadcast_p99: Option<f64>,
    /// p50 seconds of each tick phase.
    pub tick_phases: BTreeMap<String, f64>,
    /// Group-commit latency.
    pub commit_p50: Option<f64>,
    pub commit_p99: Option<f64>,
    pub bytes_out: f64,
}

/// `(name, value)` pairs of a sample's labels.
type Labels<'a> = Vec<(&'a str, &'a str)>;

/// One line of the Prometheus text format: name, labels, value.
fn parse_line(line: &str) -> Option<(&str, Labels<'_>, f64)> {
    if line.starts_with('#') || line.is_empty() {
        return None;
    }
    let (head, value) = line.rsplit_once(' ')?;
    let value: f64 = value.parse().ok()?;
    let (name, labels) = match head.split_once('{') {
        Some((n, rest)) => (n, rest.strip_suffix('}')?),
        None => (head, ""),
    };
    let labels = labels
        .split(',')
        .filter_map(|kv| {
            let (k, v) = kv.split_once('=')?;
            Some((k, v.trim_matches('"')))
        })
        .collect();
    Some((name, labels, value))
}

fn label<'a>(labels: &[(&'a str, &'a str)], key: &str) -> Option<&'a str> {
    labels.iter().find(|(k, _)| *k == key).map(|(_, v)| *v)
}

/// The figures in a rendering of the registry.
pub fn sample(text: &str) -> StatsSample {
    let mut s = StatsSample::default();
    let finite = |v: f64| v.is_finite().then_some(v);
    for line in text.lines() {
        let Some((name, labels, v)) = parse_line(line) else {
            continue;
        };
        let q = label(&labels, "quantile");
        match (name, q) {
            (m::EDITS_ACCEPTED, _) => s.edits_accepted += v,
            (m::EDITS_REJECTED, _) => {
                let reason = label(&labels, "reason").unwrap_or("other");
                *s.edits_rejected.entry(reason.to_string()).or_default() += v;
            }
            (m::BYTES_SENT, _) => s.bytes_out += v,
            (m::EDIT_LATENCY_SECONDS, Some("0.5")) => s.ack_p50 = finite(v),
            (m::EDIT_LATENCY_SECONDS, Some("0.99")) => s.ack_p99 = finite(v),
            (m::FLUSH_SECONDS, Some("0.5")) => s.commit_p50 = finite(v),
            (m::FLUSH_SECONDS, Some("0.99")) => s.commit_p99 = finite(v),
            (m::TICK_PHASE_SECONDS, Some(q)) => {
                let phase = label(&labels, "phase").unwrap_or("other");
                match (phase, q) {
                    ("fanout", "0.5") => s.broadcast_p50 = finite(v),
                    ("fanout", "0.99") => s.broadcast_p99 = finite(v),
                    _ => {}
                }
                if q == "0.5" && v.is_finite() {
                    s.tick_phases.insert(phase.to_string(), v);
                }
            }
            _ => {}
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_counters_and_quantiles() {
        let text = "# TYPE x counter\n\
            strata_edits_accepted_total 12\n\
            strata_edits_rejected_total{reason=\"reach\"} 3\n\
            strata_edits_rejected_total{reason=\"rate\"} 2\n\
            strata_edit_latency_seconds{quantile=\"0.5\"} 0.01\n\
            strata_edit_latency_seconds{quantile=\"0.99\"} 0.04\n\
            strata_tick_phase_seconds{phase=\"fanout\",quantile=\"0.5\"} 0.001\n\
            strata_tick_phase_seconds{phase=\"apply\",quantile=\"0.5\"} 0.002\n\
            strata_bytes_sent_total 4096\n";
        let s = sample(text);
        assert_eq!(s.edits_accepted, 12.0);
        assert_eq!(s.edits_rejected["reach"], 3.0);
        assert_eq!(s.edits_rejected["rate"], 2.0);
        assert_eq!((s.ack_p50, s.ack_p99), (Some(0.01), Some(0.04)));
        assert_eq!(s.broadcast_p50, Some(0.001));
        assert_eq!(s.tick_phases["apply"], 0.002);
        assert_eq!(s.bytes_out, 4096.0);
    }
}
