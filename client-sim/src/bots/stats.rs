//! Counters and latency histograms shared by every bot of a run.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use hdrhistogram::Histogram;
use serde::Serialize;

/// Longest latency a histogram records (longer ones are clamped), in µs.
pub const MAX_LATENCY_US: u64 = 3_600_000_000;

/// A latency histogram in microseconds.
#[derive(Debug)]
pub struct Latencies(Mutex<Histogram<u64>>);

impl Default for Latencies {
    fn default() -> Self {
        Self(Mutex::new(
            Histogram::new_with_bounds(1, MAX_LATENCY_US, 3).expect("valid bounds"),
        ))
    }
}

/// Percentiles of a latency histogram, in milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct LatencyMs {
    pub count: u64,
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

impl Latencies {
    pub fn record(&self, d: Duration) {
        let us = (d.as_micros() as u64).clamp(1, MAX_LATENCY_US);
        self.0.lock().expect("not poisoned").saturating_record(us);
    }

    pub fn summary(&self) -> LatencyMs {
        let h = self.0.lock().expect("not poisoned");
        if h.is_empty() {
            return LatencyMs::default();
        }
        let ms = |us: u64| us as f64 / 1000.0;
        LatencyMs {
            count: h.len(),
            p50: ms(h.value_at_quantile(0.50)),
            p99: ms(h.value_at_quantile(0.99)),
            max: ms(h.max()),
        }
    }
}

/// Live counters of a run (read by the progress bar).
#[derive(Debug, Default)]
pub struct Stats {
    pub connected: AtomicUsize,
    pub reconnects: AtomicU64,
    pub edits_sent: AtomicU64,
    pub edits_accepted: AtomicU64,
    /// Edits that got no verdict: the connection ended first.
    pub edits_unanswered: AtomicU64,
    /// Edits skipped because no target was in reach and sight.
    pub edits_skipped: AtomicU64,
    pub rejected: Mutex<BTreeMap<String, u64>>,
    pub ack: Latencies,
    pub broadcast: Latencies,
}

impl Stats {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }

    pub fn reject(&self, reason: &str) {
        *self
            .rejected
            .lock()
            .expect("not poisoned")
            .entry(reason.to_string())
            .or_default() += 1;
    }

    pub fn rejected(&self) -> BTreeMap<String, u64> {
        self.rejected.lock().expect("not poisoned").clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_in_milliseconds() {
        let l = Latencies::default();
        assert_eq!(l.summary(), LatencyMs::default());
        for ms in 1..=100 {
            l.record(Duration::from_millis(ms));
        }
        let s = l.summary();
        assert_eq!(s.count, 100);
        assert!((s.p50 - 50.0).abs() < 0.1, "{s:?}");
        assert!((s.p99 - 99.0).abs() < 0.1, "{s:?}");
        assert!((s.max - 100.0).abs() < 0.1, "{s:?}");
        let st = Stats::default();
        st.reject("rate_limited");
        st.reject("rate_limited");
        assert_eq!(st.rejected()["rate_limited"], 2);
    }
}
