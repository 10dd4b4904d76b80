//! QUIC transport figures per connection, summed into the process's
//! metrics: UDP datagrams and bytes each way, lost packets, congestion
//! events and the smoothed RTT. Each connection's counters are read every
//! [`SAMPLE_EVERY`] while it is open and once more when it closes, and
//! only the growth since the last reading is added.

use std::future::Future;
use std::time::Duration;

use quinn::ConnectionStats;

use crate::metrics as m;

/// How often an open connection's transport counters are read.
pub const SAMPLE_EVERY: Duration = m::UPKEEP_EVERY;

/// Runs `work` (the connection's session), reading `conn`'s counters
/// every [`SAMPLE_EVERY`] meanwhile and once more when `work` ends.
/// Holds a handle to `conn` only as long as `work` runs: dropping the last
/// handle is what closes a connection nobody closed.
pub async fn sampled<F: Future>(conn: quinn::Connection, work: F) -> F::Output {
    let mut last = Totals::default();
    let mut every = tokio::time::interval(SAMPLE_EVERY);
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    every.tick().await;
    tokio::pin!(work);
    loop {
        tokio::select! {
            out = &mut work => {
                Totals::of(&conn.stats()).record_since(last);
                return out;
            }
            _ = every.tick() => {
                let stats = conn.stats();
                last = Totals::of(&stats).record_since(last);
                metrics::histogram!(m::QUIC_RTT_SECONDS).record(stats.path.rtt.as_secs_f64());
            }
        }
    }
}

/// The counters of one connection that only grow.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct Totals {
    datagrams_sent: u64,
    datagrams_received: u64,
    bytes_sent: u64,
    bytes_received: u64,
    lost_packets: u64,
    congestion_events: u64,
}

impl Totals {
    fn of(s: &ConnectionStats) -> Self {
        Self {
            datagrams_sent: s.udp_tx.datagrams,
            datagrams_received: s.udp_rx.datagrams,
            bytes_sent: s.udp_tx.bytes,
            bytes_received: s.udp_rx.bytes,
            lost_packets: s.path.lost_packets,
            congestion_events: s.path.congestion_events,
        }
    }

    /// Adds the growth since `before` to the metrics; returns `self`.
    fn record_since(self, before: Self) -> Self {
        let d = self.since(before);
        let sent = [("direction", "sent")];
        let received = [("direction", "received")];
        metrics::counter!(m::UDP_DATAGRAMS, &sent).increment(d.datagrams_sent);
        metrics::counter!(m::UDP_DATAGRAMS, &received).increment(d.datagrams_received);
        metrics::counter!(m::UDP_BYTES, &sent).increment(d.bytes_sent);
        metrics::counter!(m::UDP_BYTES, &received).increment(d.bytes_received);
        metrics::counter!(m::QUIC_LOST_PACKETS).increment(d.lost_packets);
        metrics::counter!(m::QUIC_CONGESTION_EVENTS).increment(d.congestion_events);
        self
    }

    /// Growth since `before`; a counter never goes back, but a smaller
    /// reading counts as no growth rather than wrapping.
    fn since(self, before: Self) -> Self {
        Self {
            datagrams_sent: self.datagrams_sent.saturating_sub(before.datagrams_sent),
            datagrams_received: self
                .datagrams_received
                .saturating_sub(before.datagrams_received),
            bytes_sent: self.bytes_sent.saturating_sub(before.bytes_sent),
            bytes_received: self.bytes_received.saturating_sub(before.bytes_received),
            lost_packets: self.lost_packets.saturating_sub(before.lost_packets),
            congestion_events: self
                .congestion_events
                .saturating_sub(before.congestion_events),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_growth_since_the_last_reading_counts() {
        let a = Totals {
            datagrams_sent: 10,
            datagrams_received: 7,
            bytes_sent: 12_000,
            bytes_received: 900,
            lost_packets: 1,
            congestion_events: 0,
        };
        let b = Totals {
            datagrams_sent: 25,
            datagrams_received: 9,
            bytes_sent: 30_000,
            bytes_received: 1_000,
            lost_packets: 1,
            congestion_events: 2,
        };
        let d = b.since(a);
        assert_eq!(
            d,
            Totals {
                datagrams_sent: 15,
                datagrams_received: 2,
                bytes_sent: 18_000,
                bytes_received: 100,
                lost_packets: 0,
                congestion_events: 2,
            }
        );
        // A reading below the last one adds nothing (never wraps).
        assert_eq!(a.since(b), Totals::default());
        assert_eq!(b.since(Totals::default()), b);
    }
}
