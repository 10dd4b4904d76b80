//! The progress bar: connected bots, accepted edits per second and ack p99,
//! drawn on stderr (hidden when stderr is not a terminal).

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use tokio::task::JoinHandle;

use super::stats::Stats;
use super::Fleet;

/// How often the bar is redrawn.
pub const PROGRESS_PERIOD: Duration = Duration::from_millis(500);

/// Draws until aborted; the bar's length is the run's duration in seconds.
pub fn spawn(fleet: Arc<Fleet>, total: usize, duration: Duration) -> (ProgressBar, JoinHandle<()>) {
    let bar = ProgressBar::with_draw_target(
        Some(duration.as_secs().max(1)),
        ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    let b = bar.clone();
    let task = tokio::spawn(async move {
        let start = Instant::now();
        let (mut last, mut last_at) = (0u64, Instant::now());
        loop {
            tokio::time::sleep(PROGRESS_PERIOD).await;
            let s = &fleet.stats;
            let accepted = Stats::get(&s.edits_accepted);
            let rate = (accepted - last) as f64 / last_at.elapsed().as_secs_f64();
            (last, last_at) = (accepted, Instant::now());
            b.set_position(start.elapsed().as_secs());
            b.set_message(format!(
                "{}/{total} bots | {rate:.0} edits/s | ack p99 {:.1} ms | {}",
                s.connected.load(Ordering::Relaxed),
                s.ack.summary().p99,
                fleet.phase_name(),
            ));
        }
    });
    (bar, task)
}
