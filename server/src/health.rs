//! Readiness, for `/healthz` on the metrics listener: ready while the
//! server accepts connections, its engine thread runs and ticks, and its
//! store answers.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

/// How long the engine may go without finishing a tick before the server
/// says it is not ready: a commit whose fsync never returns, a store that
/// hangs, a deadlock. Far above any tick seen under load (hundreds of ms).
pub const ENGINE_STALL: Duration = Duration::from_secs(10);

/// How long store operations of one kind ([`StoreWork`]) may go on
/// failing, none of that kind succeeding, before the server says it is
/// not ready: a store that fails fast (a database gone, a disk refusing
/// reads) leaves the engine ticking and every player's reads refused. The
/// failures must span this long: one alone is a blip. Ready again once
/// one of that kind succeeds, or once none has failed for as long as a
/// failure of that kind counts (nothing tried it since).
pub const STORE_FAILING: Duration = Duration::from_secs(5);

/// How long a failure of periodic background work counts, unless that
/// work succeeds since (plus twice its period, [`Health::expect_every`]):
/// longer than a pass's period and its store's timeouts, so a store that
/// stays down keeps the server unready between two slow failures. Work
/// that comes with players' traffic (the engine's, position saves and
/// reads) may stop with it: its failures count [`STORE_FAILING`].
pub const FAILURE_KEPT: Duration = Duration::from_secs(30);

/// What a store operation was for. Each kind keeps its own run of
/// failures and is ended only by its own success: a read that works (a
/// checkpoint listing nothing) says nothing of another kind's writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreWork {
    /// The engine's chunk reads and commits, and its region reads, claims
    /// and reloads (those report failures only: held regions are answered
    /// from the lease book).
    Engine,
    /// The checkpoint thread's passes.
    Checkpoint,
    /// The checkpoint thread's edit-log pruning.
    Prune,
    /// Saves of the players' positions.
    PositionSaves,
    /// A cluster node's lease renewals (and adoptions, releases).
    Leases,
    /// Reads of the stored access list (its reload, admin commands).
    Access,
    /// Reloads of the stored protected zones.
    Zones,
    /// A cluster node's reads of a joining player's stored position.
    PositionReads,
}

impl StoreWork {
    const ALL: [StoreWork; 8] = [
        StoreWork::Engine,
        StoreWork::Checkpoint,
        StoreWork::Prune,
        StoreWork::PositionSaves,
        StoreWork::Leases,
        StoreWork::Access,
        StoreWork::Zones,
        StoreWork::PositionReads,
    ];

    /// What `/healthz` answers while this kind is failing.
    fn reason(self) -> &'static str {
        match self {
            StoreWork::Engine => {
                "store failing: the engine's reads and commits fail, none succeeds"
            }
            StoreWork::Checkpoint => "store failing: checkpoints fail, none succeeds",
            StoreWork::Prune => "store failing: pruning the edit log fails, none succeeds",
            StoreWork::PositionSaves => "store failing: saving positions fails, none succeeds",
            StoreWork::Leases => "store failing: renewing region leases fails, none succeeds",
            StoreWork::Access => "store failing: reading the access list fails, none succeeds",
            StoreWork::Zones => "store failing: reading protected zones fails, none succeeds",
            StoreWork::PositionReads => {
                "store failing: reading players' positions fails, none succeeds"
            }
        }
    }
}

/// One kind's run of failures (ms on [`clock_ms`], 0 for none), read
/// and written whole: reports of one kind may come from several threads.
#[derive(Debug, Default, Clone, Copy)]
struct Run {
    /// The first failure since the last success (or since a quiet spell
    /// longer than the kind's failures count).
    since: u64,
    /// The last failure.
    last: u64,
}

/// One kind's run and period.
#[derive(Debug, Default)]
struct Kind {
    run: Mutex<Run>,
    /// The kind's period ([`Health::expect_every`]), 0 when it has none.
    period: AtomicU64,
}

#[derive(Debug, Default)]
pub struct Health {
    accepting: AtomicBool,
    engine_stopped: AtomicBool,
    /// When the engine last finished a tick ([`clock_ms`]); 0 before its
    /// first.
    ticked_ms: AtomicU64,
    /// By [`StoreWork`], in [`StoreWork::ALL`]'s order.
    store: [Kind; StoreWork::ALL.len()],
}

/// Milliseconds since this process first asked, at least 1: a monotonic
/// clock for [`Health`].
fn clock_ms() -> u64 {
    static START: OnceLock<Instant> = OnceLock::new();
    let start = *START.get_or_init(Instant::now);
    (start.elapsed().as_millis() as u64).max(1)
}

impl Health {
    /// `Ok` when ready, else why not.
    pub fn check(&self) -> Result<(), &'static str> {
        self.check_at(clock_ms())
    }

    fn check_at(&self, now_ms: u64) -> Result<(), &'static str> {
        let ticked = self.ticked_ms.load(Ordering::Acquire);
        if self.engine_stopped.load(Ordering::Acquire) {
            return Err("engine stopped");
        } else if !self.accepting.load(Ordering::Acquire) {
            return Err("not accepting connections");
        } else if ticked > 0 && now_ms.saturating_sub(ticked) > ENGINE_STALL.as_millis() as u64 {
            return Err("engine stalled: no tick finished lately");
        }
        match StoreWork::ALL
            .into_iter()
            .find(|&w| self.failing(w, now_ms))
        {
            Some(w) => Err(w.reason()),
            None => Ok(()),
        }
    }

    fn kind(&self, work: StoreWork) -> &Kind {
        &self.store[work as usize]
    }

    fn run(&self, work: StoreWork) -> std::sync::MutexGuard<'_, Run> {
        self.kind(work)
            .run
            .lock()
            .unwrap_or_else(|p| p.into_inner())
    }

    /// How long a failure of `work` counts without another.
    fn kept_ms(&self, work: StoreWork) -> u64 {
        match work {
            // These come with players' actions: none lately says nothing
            // tried the store.
            StoreWork::Engine | StoreWork::PositionSaves | StoreWork::PositionReads => {
                STORE_FAILING.as_millis() as u64
            }
            _ => {
                let period = self.kind(work).period.load(Ordering::Acquire);
                FAILURE_KEPT.as_millis() as u64 + 2 * period
            }
        }
    }

    fn failing(&self, work: StoreWork, now_ms: u64) -> bool {
        let Run { since, last } = *self.run(work);
        since > 0
            && last.saturating_sub(since) >= STORE_FAILING.as_millis() as u64
            && now_ms.saturating_sub(last) < self.kept_ms(work)
    }

    /// `work` runs about every `period`: its failures count that much
    /// longer ([`FAILURE_KEPT`]).
    pub fn expect_every(&self, work: StoreWork, period: Duration) {
        let ms = u64::try_from(period.as_millis()).unwrap_or(u64::MAX / 4);
        self.kind(work)
            .period
            .store(ms.min(u64::MAX / 4), Ordering::Release);
    }

    /// How a store operation for `work` went. Errors that are not the
    /// store's ([`crate::store::StoreError::is_store_fault`]: one chunk's
    /// records, a lease lost, a newer process) count as neither.
    pub fn report<T>(&self, work: StoreWork, result: &Result<T, crate::store::StoreError>) {
        match result {
            Ok(_) => self.store_ok(work),
            Err(e) => self.store_error(work, e),
        }
    }

    /// A store operation for `work` failed ([`Self::report`]'s rule).
    pub fn store_error(&self, work: StoreWork, error: &crate::store::StoreError) {
        if error.is_store_fault() {
            self.store_failed(work);
        }
    }

    /// A store operation for `work` failed, the store's fault.
    pub fn store_failed(&self, work: StoreWork) {
        self.store_failed_at(work, clock_ms());
    }

    fn store_failed_at(&self, work: StoreWork, now_ms: u64) {
        let kept = self.kept_ms(work);
        let mut run = self.run(work);
        if run.since == 0 || now_ms.saturating_sub(run.last) >= kept {
            // The first failure since a success, or after a quiet spell.
            run.since = now_ms;
        }
        run.last = now_ms;
    }

    /// A store operation for `work` succeeded: its run of failures ends.
    pub fn store_ok(&self, work: StoreWork) {
        self.run(work).since = 0;
    }

    pub fn set_accepting(&self, on: bool) {
        self.accepting.store(on, Ordering::Release);
    }

    /// The engine thread ended; the server is not ready again.
    pub fn engine_stopped(&self) {
        self.engine_stopped.store(true, Ordering::Release);
    }

    /// The engine finished a tick.
    pub fn ticked(&self) {
        self.ticked_at(clock_ms());
    }

    fn ticked_at(&self, now_ms: u64) {
        self.ticked_ms.store(now_ms, Ordering::Release);
    }

    /// How long ago the engine last finished a tick; `None` before its
    /// first.
    pub fn since_tick(&self) -> Option<Duration> {
        let ticked = self.ticked_ms.load(Ordering::Acquire);
        (ticked > 0).then(|| Duration::from_millis(clock_ms().saturating_sub(ticked)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_engine_that_stops_ticking_is_not_ready() {
        let h = Health::default();
        h.set_accepting(true);
        assert_eq!(h.check_at(5), Ok(()), "before the first tick");
        h.ticked_at(1_000);
        let stall = ENGINE_STALL.as_millis() as u64;
        assert_eq!(h.check_at(1_000 + stall), Ok(()));
        assert!(h.check_at(1_001 + stall).unwrap_err().contains("stalled"));
        h.ticked_at(1_001 + stall);
        assert_eq!(h.check_at(1_001 + stall), Ok(()));
        h.engine_stopped();
        assert_eq!(h.check_at(1_001 + stall), Err("engine stopped"));
    }

    #[test]
    fn a_store_that_keeps_failing_is_not_ready() {
        let h = Health::default();
        h.set_accepting(true);
        let engine = StoreWork::Engine;
        let window = STORE_FAILING.as_millis() as u64;
        h.store_failed_at(engine, 1_000);
        assert_eq!(h.check_at(1_000 + window), Ok(()), "one failure is a blip");
        h.store_failed_at(engine, 1_000 + window - 1);
        assert_eq!(
            h.check_at(1_000 + window),
            Ok(()),
            "not a window's span yet"
        );
        h.store_failed_at(engine, 1_000 + window);
        let why = h.check_at(1_000 + window).unwrap_err();
        assert!(why.contains("engine's reads"), "{why}");
        // One success: ready again, and a later failure starts anew.
        h.store_ok(engine);
        assert_eq!(h.check_at(1_000 + window), Ok(()));
        for t in [2_000 + window, 2_000 + window * 3 / 2, 2_000 + 2 * window] {
            h.store_failed_at(engine, t);
        }
        assert!(h.check_at(2_000 + 2 * window).is_err());
        // Failures that stop (nothing tries the store): ready after the window.
        assert!(h.check_at(2_000 + 3 * window - 1).is_err());
        assert_eq!(h.check_at(2_000 + 3 * window), Ok(()));
        // A failure after that quiet spell is a blip of its own.
        h.store_failed_at(engine, 2_000 + 3 * window);
        assert_eq!(h.check_at(2_000 + 3 * window), Ok(()));
        // Position saves and reads come with traffic too: a window.
        let saves = StoreWork::PositionSaves;
        for t in [50_000, 50_000 + window / 2, 50_000 + window] {
            h.store_failed_at(saves, t);
        }
        assert!(h.check_at(50_000 + 2 * window - 1).is_err());
        assert_eq!(h.check_at(50_000 + 2 * window), Ok(()));
    }

    #[test]
    fn background_work_fails_on_until_it_succeeds_itself() {
        let h = Health::default();
        h.set_accepting(true);
        let (cp, zones) = (StoreWork::Checkpoint, StoreWork::Zones);
        let window = STORE_FAILING.as_millis() as u64;
        let kept = FAILURE_KEPT.as_millis() as u64;
        // Slow failures, further apart than the window: unready from the
        // second on, between them too.
        h.store_failed_at(cp, 1_000);
        assert_eq!(h.check_at(1_000 + 2 * window - 1), Ok(()), "one is a blip");
        for t in (1..5).map(|i| 1_000 + i * 2 * window) {
            h.store_failed_at(cp, t);
        }
        for t in [
            1_000 + 2 * window,
            1_000 + 3 * window,
            1_000 + 9 * window - 1,
        ] {
            let why = h.check_at(t).unwrap_err();
            assert!(why.contains("checkpoints"), "{why}");
        }
        // Another kind's success ends nothing; its own does.
        h.store_ok(zones);
        assert!(h.check_at(1_000 + 9 * window).is_err());
        h.store_ok(cp);
        assert_eq!(h.check_at(1_000 + 9 * window), Ok(()));
        // One failure long after an old one starts a run of its own.
        h.store_failed_at(zones, 100_000);
        h.store_failed_at(zones, 100_000 + kept);
        assert_eq!(h.check_at(100_000 + kept + 1), Ok(()));
        // A failure counts `FAILURE_KEPT` plus two periods.
        h.store_failed_at(zones, 100_000 + kept + window);
        assert!(h.check_at(100_000 + 2 * kept + window - 1).is_err());
        assert_eq!(h.check_at(100_000 + 2 * kept + window), Ok(()));
        h.expect_every(zones, Duration::from_secs(60));
        assert!(h.check_at(100_000 + 2 * kept + window).is_err());
        assert_eq!(h.check_at(100_000 + 2 * kept + window + 120_000), Ok(()));
    }
}
