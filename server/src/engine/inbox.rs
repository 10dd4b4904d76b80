//! The engine's two bounded queues. Players' traffic (edits, positions,
//! subscriptions, resyncs) goes in one; joins, leaves, admin requests and
//! `Stop` in the other, which the engine always empties first, so no amount
//! of player traffic delays them.
//!
//! std's channels cannot wait on two queues at once: the engine blocks on
//! the player queue, and a sender of a control command also queues one
//! `Wake` there (at most one is ever pending) so the engine looks. The
//! commit thread wakes it the same way through a [`Waker`], which holds
//! the player lane only weakly: the queues still disconnect once every
//! handle is gone.
//!
//! A session's commands on the player lane hold a slot of its
//! [`SessionShare`] until the engine takes them (`session_share.rs`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Weak};
use std::time::Duration;

use super::session_share::{QueueSlot, SessionShare, DEFAULT_SESSION_COMMANDS};
use super::Command;

/// A command on the player lane and the slot of its session's share it
/// holds until the engine takes it (none for position notices and wakes).
#[derive(Debug)]
pub struct Queued {
    cmd: Command,
    /// Given back when this is dropped: when the engine takes the command.
    _slot: Option<QueueSlot>,
}

impl Queued {
    /// A command counted against its session's share.
    pub fn held(cmd: Command, slot: QueueSlot) -> Self {
        Self {
            cmd,
            _slot: Some(slot),
        }
    }

    fn free(cmd: Command) -> Self {
        Self { cmd, _slot: None }
    }

    /// The command, its slot given back.
    pub fn into_command(self) -> Command {
        self.cmd
    }
}

/// `e` with its payload mapped by `f`.
fn map_refused<T, U>(e: TrySendError<T>, f: impl FnOnce(T) -> U) -> TrySendError<U> {
    match e {
        TrySendError::Full(t) => TrySendError::Full(f(t)),
        TrySendError::Disconnected(t) => TrySendError::Disconnected(f(t)),
    }
}

/// Handle for sending commands to a running engine.
#[derive(Debug, Clone)]
pub struct EngineHandle {
    /// Shared by the clones; the [`Waker`] holds it weakly.
    player: Arc<SyncSender<Queued>>,
    control: SyncSender<Command>,
    /// A `Wake` is queued on the player lane and not yet taken.
    wake_pending: Arc<AtomicBool>,
    /// The player lane's capacity.
    lane: usize,
    /// Commands one session may have on the player lane (`[engine]
    /// session_commands`, at most the lane's capacity).
    session_commands: usize,
}

/// The engine's end of both queues.
#[derive(Debug)]
pub struct Inbox {
    player: Receiver<Queued>,
    control: Receiver<Command>,
    wake_pending: Arc<AtomicBool>,
    waker: Waker,
}

/// Wakes a waiting engine without keeping its queues open.
#[derive(Debug, Clone)]
pub struct Waker {
    player: Weak<SyncSender<Queued>>,
    wake_pending: Arc<AtomicBool>,
}

impl Waker {
    /// Queues a `Wake` unless one is pending or every handle is gone.
    pub fn wake(&self) {
        if let Some(player) = self.player.upgrade() {
            wake(&player, &self.wake_pending);
        }
    }
}

/// Queues one `Wake` on `player` unless one is pending. A full player
/// queue needs no wake: the engine is busy draining it and looks at the
/// control lane (and a running commit) between commands.
fn wake(player: &SyncSender<Queued>, pending: &AtomicBool) {
    if !pending.swap(true, Ordering::AcqRel)
        && player.try_send(Queued::free(Command::Wake)).is_err()
    {
        pending.store(false, Ordering::Release);
    }
}

/// A handle and inbox with room for `player` and `control` commands; each
/// session may have [`DEFAULT_SESSION_COMMANDS`] of the player commands
/// (see [`EngineHandle::with_session_commands`]).
pub fn channel(player: usize, control: usize) -> (EngineHandle, Inbox) {
    let (ptx, prx) = sync_channel(player);
    let (ctx, crx) = sync_channel(control);
    let wake_pending = Arc::new(AtomicBool::new(false));
    let ptx = Arc::new(ptx);
    let waker = Waker {
        player: Arc::downgrade(&ptx),
        wake_pending: wake_pending.clone(),
    };
    let handle = EngineHandle {
        player: ptx,
        control: ctx,
        wake_pending: wake_pending.clone(),
        lane: player,
        session_commands: DEFAULT_SESSION_COMMANDS.clamp(1, player.max(1)),
    };
    let inbox = Inbox {
        player: prx,
        control: crx,
        wake_pending,
        waker,
    };
    (handle, inbox)
}

/// Whether `c` travels on the control lane.
fn is_control(c: &Command) -> bool {
    matches!(
        c,
        Command::Join { .. } | Command::Leave { .. } | Command::Admin(_) | Command::Stop
    )
}

impl EngineHandle {
    /// Lets each session have `n` commands on the player lane (at least
    /// one, at most the lane's capacity).
    pub fn with_session_commands(mut self, n: usize) -> Self {
        self.session_commands = n.clamp(1, self.lane.max(1));
        self
    }

    /// A new session's share of the player lane.
    pub fn session_share(&self) -> SessionShare {
        SessionShare::new(self.session_commands)
    }

    /// Queues a command without waiting; false if its queue is full or the
    /// engine is gone.
    pub fn try_send(&self, c: Command) -> bool {
        self.offer(c).is_ok()
    }

    /// Queues a command without waiting, handing it back when its queue is
    /// full (or `Disconnected` when the engine is gone). A player command
    /// sent this way holds no slot of a session's share: sessions send
    /// only position notices so. (The refused command comes back whole,
    /// as the channel hands it: no box for a path that is not hot.)
    #[allow(clippy::result_large_err)]
    pub fn offer(&self, c: Command) -> Result<(), TrySendError<Command>> {
        if !is_control(&c) {
            let sent = self.player.try_send(Queued::free(c));
            return sent.map_err(|e| map_refused(e, Queued::into_command));
        }
        self.control.try_send(c)?;
        self.wake();
        Ok(())
    }

    /// Queues a command holding its session's slot without waiting,
    /// handing it back (slot and all) when the queue is full.
    // The refusal hands the command back to be offered again: boxing it
    // would allocate at every full queue.
    #[allow(clippy::result_large_err)]
    pub fn offer_queued(&self, q: Queued) -> Result<(), TrySendError<Queued>> {
        if is_control(&q.cmd) {
            return self.offer(q.cmd).map_err(|e| map_refused(e, Queued::free));
        }
        self.player.try_send(q)
    }

    /// Asks the engine to finish and stop, waiting for queue space (blocking).
    pub fn stop(&self) {
        if self.control.send(Command::Stop).is_ok() {
            self.wake();
        }
    }

    fn wake(&self) {
        wake(&self.player, &self.wake_pending);
    }
}

impl Inbox {
    /// The next command, control lane first, waiting at most `wait`.
    /// `Disconnected` once every handle is gone.
    pub fn recv_timeout(&self, wait: Duration) -> Result<Command, RecvTimeoutError> {
        let deadline = std::time::Instant::now() + wait;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.recv_or_wake(left) {
                Ok(Some(c)) => return Ok(c),
                Ok(None) if left.is_zero() => return Err(RecvTimeoutError::Timeout),
                Ok(None) => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// The next command, control lane first; `None` when woken (by a
    /// [`Waker`] or a control sender) or after `wait`.
    pub fn recv_or_wake(&self, wait: Duration) -> Result<Option<Command>, RecvTimeoutError> {
        if let Ok(c) = self.control.try_recv() {
            return Ok(Some(c));
        }
        // Taken off the queue: the session's slot is given back here.
        match self.player.recv_timeout(wait).map(Queued::into_command) {
            Ok(Command::Wake) => {
                self.wake_pending.store(false, Ordering::Release);
                // A control sender wakes after queueing its command.
                Ok(self.control.try_recv().ok())
            }
            Ok(c) => Ok(Some(c)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => self
                .control
                .try_recv()
                .map(Some)
                .map_err(|_| RecvTimeoutError::Disconnected),
        }
    }

    /// A waker for this inbox's engine.
    pub fn waker(&self) -> Waker {
        self.waker.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leave(session: u64) -> Command {
        Command::Leave { session }
    }

    #[test]
    fn control_commands_pass_a_full_player_queue() {
        let (handle, inbox) = channel(2, 4);
        let pos = |session| Command::Position { session };
        assert!(handle.try_send(pos(1)));
        assert!(handle.try_send(pos(2)));
        assert!(!handle.try_send(pos(3)), "the player lane is full");
        assert!(handle.try_send(leave(7)), "a leave still gets in");
        let order: Vec<String> = (0..3)
            .map(
                |_| match inbox.recv_timeout(Duration::from_secs(1)).unwrap() {
                    Command::Leave { session } => format!("leave {session}"),
                    Command::Position { session } => format!("pos {session}"),
                    other => panic!("{other:?}"),
                },
            )
            .collect();
        assert_eq!(order, ["leave 7", "pos 1", "pos 2"]);
    }

    #[test]
    fn a_sessions_slot_comes_back_when_the_engine_takes_its_command() {
        let (handle, inbox) = channel(4, 4);
        let share = handle.clone().with_session_commands(1).session_share();
        let forget = Command::Forget {
            session: 1,
            chunks: Vec::new(),
        };
        let slot = share.try_take().expect("a free slot");
        assert!(handle.offer_queued(Queued::held(forget, slot)).is_ok());
        assert!(share.try_take().is_none(), "held while queued");
        let taken = inbox.recv_timeout(Duration::from_secs(1));
        assert!(matches!(taken, Ok(Command::Forget { session: 1, .. })));
        assert!(share.try_take().is_some(), "given back once taken");
        // A share is never larger than the lane.
        let big = handle.with_session_commands(100).session_share();
        let held: Vec<_> = (0..10).filter_map(|_| big.try_take()).collect();
        assert_eq!(held.len(), 4);
    }

    #[test]
    fn a_control_command_wakes_a_waiting_engine_once() {
        let (handle, inbox) = channel(8, 8);
        let engine = std::thread::spawn(move || {
            let first = inbox.recv_timeout(Duration::from_secs(5));
            let second = inbox.recv_timeout(Duration::from_secs(5));
            (first.is_ok(), second.is_ok(), inbox)
        });
        std::thread::sleep(Duration::from_millis(50));
        assert!(handle.try_send(leave(1)));
        assert!(handle.try_send(leave(2)));
        let (a, b, inbox) = engine.join().unwrap();
        assert!(a && b);
        // No stray wakes are left behind: the queue is empty now.
        assert_eq!(
            inbox.recv_timeout(Duration::from_millis(20)).err(),
            Some(RecvTimeoutError::Timeout)
        );
        drop(handle);
        assert_eq!(
            inbox.recv_timeout(Duration::from_millis(20)).err(),
            Some(RecvTimeoutError::Disconnected)
        );
    }

    #[test]
    fn a_waker_wakes_a_waiting_engine_but_keeps_no_queue_open() {
        let (handle, inbox) = channel(8, 8);
        let waker = inbox.waker();
        let engine = std::thread::spawn(move || {
            let started = std::time::Instant::now();
            let woke = inbox.recv_or_wake(Duration::from_secs(10));
            (woke, started.elapsed(), inbox)
        });
        std::thread::sleep(Duration::from_millis(50));
        waker.wake();
        let (woke, took, inbox) = engine.join().unwrap();
        assert!(matches!(woke, Ok(None)), "woken with no command");
        assert!(took < Duration::from_secs(5), "woken, not timed out");
        // Once every handle is gone the waker neither wakes nor holds the
        // queue open.
        drop(handle);
        waker.wake();
        assert_eq!(
            inbox.recv_timeout(Duration::from_millis(20)).err(),
            Some(RecvTimeoutError::Disconnected)
        );
    }
}
