//! Counters and latency histograms shared by every bot of a run.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use hdrhistogram::Histogram;
use serde::Serialize;

/// Longest latency a histogram records (longer ones are clamped), in µs.
pub const MAX_LATENCY_US: u64 = 3_600_000_000;

/// Seconds of a run the per-second latency timeline covers.
pub const TIMELINE_SECONDS: usize = 3600;

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, MAX_LATENCY_US, 3).expect("valid bounds")
}

/// A latency histogram in microseconds, overall and per second of the run.
#[derive(Debug)]
pub struct Latencies {
    /// Second 0 of the timeline: the start of the edits.
    start: Mutex<Instant>,
    all: Mutex<Histogram<u64>>,
    by_second: Mutex<Vec<Histogram<u64>>>,
}

impl Default for Latencies {
    fn default() -> Self {
        Self {
            start: Mutex::new(Instant::now()),
            all: Mutex::new(histogram()),
            by_second: Mutex::new(Vec::new()),
        }
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

impl LatencyMs {
    fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        let ms = |us: u64| us as f64 / 1000.0;
        Self {
            count: h.len(),
            p50: ms(h.value_at_quantile(0.50)),
            p99: ms(h.value_at_quantile(0.99)),
            max: ms(h.max()),
        }
    }
}

impl Latencies {
    /// Records a latency observed now.
    pub fn record(&self, d: Duration) {
        let us = (d.as_micros() as u64).clamp(1, MAX_LATENCY_US);
        self.all.lock().expect("not poisoned").saturating_record(us);
        let start = *self.start.lock().expect("not poisoned");
        let second = (start.elapsed().as_secs() as usize).min(TIMELINE_SECONDS - 1);
        let mut by = self.by_second.lock().expect("not poisoned");
        if by.len() <= second {
            by.resize_with(second + 1, histogram);
        }
        by[second].saturating_record(us);
    }

    /// Starts the per-second timeline now.
    pub fn restart_timeline(&self) {
        *self.start.lock().expect("not poisoned") = Instant::now();
        self.by_second.lock().expect("not poisoned").clear();
    }

    pub fn summary(&self) -> LatencyMs {
        LatencyMs::of(&self.all.lock().expect("not poisoned"))
    }

    /// Percentiles of the latencies observed in each second since the run
    /// started (seconds with none give zeros).
    pub fn timeline(&self) -> Vec<LatencyMs> {
        let by = self.by_second.lock().expect("not poisoned");
        by.iter().map(LatencyMs::of).collect()
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
    /// Edit slots that fell due while the bot's last edit still awaited its
    /// verdict, or while a step ran late: no edit was sent for them.
    pub edit_slots_skipped: AtomicU64,
    /// Walks from one region into another (`BotsConfig::region_chunks`).
    pub region_crossings: AtomicU64,
    /// Moves to the node a `RegionElsewhere` named (`--follow-owners`).
    pub handoffs: AtomicU64,
    pub rejected: Mutex<BTreeMap<String, u64>>,
    /// `PositionRefused` answers heard, by reason.
    pub position_refusals: Mutex<BTreeMap<String, u64>>,
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

    pub fn position_refused(&self, reason: &str) {
        *self
            .position_refusals
            .lock()
            .expect("not poisoned")
            .entry(reason.to_string())
            .or_default() += 1;
    }

    pub fn positions_refused(&self) -> BTreeMap<String, u64> {
        self.position_refusals.lock().expect("not poisoned").clone()
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
        let t = l.timeline();
        assert_eq!(t.iter().map(|s| s.count).sum::<u64>(), 100, "{t:?}");
        assert!(t.last().unwrap().max > 99.0);
        let st = Stats::default();
        st.reject("rate_limited");
        st.reject("rate_limited");
        assert_eq!(st.rejected()["rate_limited"], 2);
    }
}
