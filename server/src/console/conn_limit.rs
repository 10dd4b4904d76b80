//! A TCP listener that holds at most `[console] max_connections`
//! connections: each accepted stream carries a semaphore permit, released
//! when the connection closes, and accepting waits while none is free.
//! A connection that neither sends nor receives a byte for
//! `[console] idle_timeout_ms` is closed, so idle or stalled clients cannot
//! keep the slots (an open event stream is never idle: it gets a
//! keep-alive comment every half of the timeout at least). Nor may a request
//! take longer than `[console] request_timeout_ms` from its first byte to
//! its answer's first byte, so a client trickling a byte now and then
//! cannot keep a slot either. Both deadlines hold while a write waits on a
//! full socket too, so a client that sends requests but never reads the
//! answers cannot keep a slot.
//!
//! With [`Deadlines::unadmitted`] set (the console; the metrics listener,
//! which admits none, so each of its connections may be closed alike), a connection is
//! unadmitted until a request on it passed the token check
//! ([`ConnState::admit`]): it may stay silent only that long, and when
//! every slot is taken a new connection closes the oldest unadmitted one
//! past its grace ([`REQUEST_GRACE`] from its acceptance, the start of a
//! request it is still sending, or of an answer its reader holds up;
//! none between requests, nor once it is open as long as
//! [`Deadlines::unadmitted`]), those between requests first, so anonymous
//! connections can never lock the operators out. An
//! admission lasts only while the token that made it stays good
//! (unexpired, unrevoked, its admin not banned): with no unadmitted
//! connection to close, a new one closes those whose admission lapsed, so
//! a former admin's connections cannot keep the slots either.

use std::collections::VecDeque;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use std::future::Future;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// How long an unadmitted connection is safe from eviction after it was
/// accepted, after the first byte of a request it is sending, and after
/// the first byte of an answer its reader holds up: an operator's (or a
/// readiness probe's) new connection gets this long to deliver its request
/// while anonymous ones crowd in, and an answer this long to be read.
/// Between requests it has none, however often they come.
const REQUEST_GRACE: Duration = Duration::from_secs(1);

/// Pause after a failed accept (e.g. out of file descriptors).
const ACCEPT_RETRY: std::time::Duration = std::time::Duration::from_millis(50);

/// How long a connection may stay silent, and a request unanswered.
#[derive(Debug, Clone, Copy)]
pub struct Deadlines {
    pub idle: Duration,
    pub request: Duration,
    /// How long a connection not admitted yet may stay silent, and whether
    /// a new connection may close the oldest of those when every slot is
    /// taken (`None`: every connection is alike).
    pub unadmitted: Option<Duration>,
}

/// A connection not admitted yet.
const NEW: u8 = 0;
/// A request on it passed the token check.
const ADMITTED: u8 = 1;
/// Closed for a new connection (it was never admitted).
const EVICTED: u8 = 2;

/// Whether the admission a token made still holds.
pub type StillGood = Box<dyn Fn() -> bool + Send + Sync>;

/// What a connection's handlers and its listener share.
#[derive(Default)]
pub struct ConnState {
    /// [`NEW`], then [`ADMITTED`] or [`EVICTED`]; an admitted connection
    /// is evicted only once its admission lapsed.
    state: AtomicU8,
    /// The task waiting on the connection, woken to close it.
    waker: Mutex<Option<Waker>>,
    /// The newest admission's check.
    still: Mutex<Option<StillGood>>,
    /// When the request being received began, while one is.
    request_since: Mutex<Option<Instant>>,
    /// Its acceptance and the answer being written.
    times: Mutex<Times>,
}

/// When a connection was accepted, and its answer's progress.
#[derive(Debug, Default, Clone, Copy)]
struct Times {
    accepted: Option<Instant>,
    /// When the last answer's first byte was written.
    answer: Option<Instant>,
    /// Whether its last write waited for a full socket (the answer is
    /// still being written).
    blocked: bool,
}

impl std::fmt::Debug for ConnState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ConnState")
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

impl ConnState {
    /// A request on this connection passed the token check: it is not
    /// evicted from now on (unless it already was) while `still` holds,
    /// the newest admission's check replacing the one before.
    pub fn admit(&self, still: StillGood) {
        *self.still.lock().unwrap_or_else(|p| p.into_inner()) = Some(still);
        let _ = self
            .state
            .compare_exchange(NEW, ADMITTED, Ordering::AcqRel, Ordering::Acquire);
    }

    /// Whether it may be closed for a new connection now: never admitted,
    /// accepted [`REQUEST_GRACE`] ago or more, and between requests, or
    /// sending one for that long, or writing an answer (held up by the
    /// client's reading) begun that long ago; or, whatever it does, open
    /// `max_age` or more. Requests that come and go keep no slot, nor do
    /// requests trickled one after another for long.
    fn evictable(&self, now: Instant, max_age: Duration) -> bool {
        let since = *self.request_since.lock().unwrap_or_else(|p| p.into_inner());
        let t = self.times();
        let past = |t: Option<Instant>, d: Duration| t.is_none_or(|t| now.duration_since(t) >= d);
        self.state.load(Ordering::Acquire) == NEW
            && past(t.accepted, REQUEST_GRACE)
            && (past(t.accepted, max_age)
                || match since {
                    Some(_) => past(since, REQUEST_GRACE),
                    None => !t.blocked || past(t.answer, REQUEST_GRACE),
                })
    }

    fn times(&self) -> std::sync::MutexGuard<'_, Times> {
        self.times.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether a request on it is being received or an answer written:
    /// such connections go after the idle ones.
    fn is_busy(&self) -> bool {
        self.request_since
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .is_some()
            || self.times().blocked
    }

    fn set_request_since(&self, since: Option<Instant>) {
        *self.request_since.lock().unwrap_or_else(|p| p.into_inner()) = since;
    }

    /// Closes it if it is admitted by a token no longer good. The check
    /// and the eviction hold the admission's lock: a request admitting it
    /// with a good token meanwhile is seen, or comes after the eviction.
    fn evict_if_lapsed(&self) {
        let still = self.still.lock().unwrap_or_else(|p| p.into_inner());
        if self.is_admitted() && still.as_ref().is_some_and(|still| !still()) {
            self.evict(ADMITTED);
        }
    }

    fn is_admitted(&self) -> bool {
        self.state.load(Ordering::Acquire) == ADMITTED
    }

    fn is_evicted(&self) -> bool {
        self.state.load(Ordering::Acquire) == EVICTED
    }

    /// Closes the connection at its next poll (woken now), unless it
    /// left state `from` meanwhile; true if it was evicted.
    fn evict(&self, from: u8) -> bool {
        let evicted = self
            .state
            .compare_exchange(from, EVICTED, Ordering::AcqRel, Ordering::Acquire)
            .is_ok();
        if evicted {
            if let Some(w) = self.waker.lock().unwrap_or_else(|p| p.into_inner()).take() {
                w.wake();
            }
        }
        evicted
    }
}

/// The connection a request came on, for `axum`'s `ConnectInfo`.
#[derive(Debug, Clone)]
pub struct ConnMark(pub Arc<ConnState>);

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, LimitedListener>>
    for ConnMark
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, LimitedListener>) -> Self {
        ConnMark(stream.io().state.clone())
    }
}

/// [`TcpListener`] with a connection cap, for `axum::serve`.
#[derive(Debug)]
pub struct LimitedListener {
    inner: TcpListener,
    slots: Arc<Semaphore>,
    deadlines: Deadlines,
    /// Open connections, oldest first (some gone since: skipped when met,
    /// dropped when tracking). At most one entry per slot is kept.
    conns: VecDeque<Weak<ConnState>>,
    max: usize,
}

impl LimitedListener {
    pub fn new(inner: TcpListener, max: usize, deadlines: Deadlines) -> Self {
        Self {
            inner,
            slots: Arc::new(Semaphore::new(max)),
            deadlines,
            conns: VecDeque::new(),
            max,
        }
    }

    /// A free slot; when none is (and eviction is on), closes the oldest
    /// evictable unadmitted connection ([`ConnState::evictable`]) or, with
    /// none, every one whose admission lapsed, and waits for a slot,
    /// looking again every [`REQUEST_GRACE`].
    async fn slot(&mut self) -> OwnedSemaphorePermit {
        loop {
            if let Ok(slot) = self.slots.clone().try_acquire_owned() {
                return slot;
            }
            if self.deadlines.unadmitted.is_none() {
                break;
            }
            self.evict_one();
            let acquired =
                tokio::time::timeout(REQUEST_GRACE, self.slots.clone().acquire_owned()).await;
            match acquired {
                Ok(Ok(slot)) => return slot,
                // The semaphore is never closed; wait as if it were full.
                Ok(Err(_)) => std::future::pending::<()>().await,
                Err(_) => {}
            }
        }
        match self.slots.clone().acquire_owned().await {
            Ok(slot) => slot,
            Err(_) => std::future::pending().await,
        }
    }

    /// Closes the oldest evictable unadmitted connection, silent ones
    /// before those still sending a request (an operator's slow one), or
    /// with none, every one whose admission lapsed.
    fn evict_one(&self) {
        let now = Instant::now();
        // Set whenever eviction is on.
        let max_age = self.deadlines.unadmitted.unwrap_or(Duration::MAX);
        let live = || self.conns.iter().filter_map(Weak::upgrade);
        let evict = |busy: bool| {
            live().any(|c| c.evictable(now, max_age) && c.is_busy() == busy && c.evict(NEW))
        };
        if !evict(false) && !evict(true) {
            for c in live() {
                c.evict_if_lapsed();
            }
        }
    }

    fn track(&mut self, state: &Arc<ConnState>) {
        if self.deadlines.unadmitted.is_none() {
            return;
        }
        self.conns
            .retain(|w| w.upgrade().is_some_and(|c| !c.is_evicted()));
        // Bounded by the slots: every live entry holds one.
        if self.conns.len() < self.max {
            self.conns.push_back(Arc::downgrade(state));
        }
    }
}

/// A connection, its slot and its deadlines.
#[derive(Debug)]
pub struct LimitedStream {
    stream: TcpStream,
    _slot: OwnedSemaphorePermit,
    deadlines: Deadlines,
    state: Arc<ConnState>,
    last_active: Instant,
    /// When the first byte of a request not answered yet arrived.
    request_since: Option<Instant>,
    deadline: Pin<Box<Sleep>>,
}

impl LimitedStream {
    fn new(stream: TcpStream, slot: OwnedSemaphorePermit, deadlines: Deadlines) -> Self {
        let now = Instant::now();
        let idle = deadlines
            .unadmitted
            .map_or(deadlines.idle, |u| u.min(deadlines.idle));
        let state = ConnState::default();
        state.times().accepted = Some(now);
        Self {
            stream,
            _slot: slot,
            deadlines,
            state: Arc::new(state),
            last_active: now,
            request_since: None,
            deadline: Box::pin(tokio::time::sleep_until(now + idle)),
        }
    }

    /// An error once the connection was evicted, nothing moved for the
    /// idle time, or a request went unanswered for the request time; else
    /// arms the timer (and keeps the waker, for an eviction).
    fn check_deadlines(&mut self, cx: &mut Context<'_>) -> io::Result<()> {
        if self.state.is_evicted() {
            return Err(io::Error::new(
                io::ErrorKind::ConnectionAborted,
                "connection closed for a new one (never admitted)",
            ));
        }
        if self.deadlines.unadmitted.is_some() {
            *self.state.waker.lock().unwrap_or_else(|p| p.into_inner()) = Some(cx.waker().clone());
        }
        // The short silence only between requests: one being answered
        // (a render, say) is bounded by the request deadline.
        let idle_for = match self.deadlines.unadmitted {
            Some(u) if !self.state.is_admitted() && self.request_since.is_none() => {
                u.min(self.deadlines.idle)
            }
            _ => self.deadlines.idle,
        };
        let idle = self.last_active + idle_for;
        let request = self.request_since.map(|t| t + self.deadlines.request);
        let due = request.map_or(idle, |r| r.min(idle));
        if self.deadline.deadline() != due {
            self.deadline.as_mut().reset(due);
        }
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Err(io::Error::new(
                io::ErrorKind::TimedOut,
                if request == Some(due) {
                    "request too slow"
                } else {
                    "connection idle"
                },
            )),
            Poll::Pending => Ok(()),
        }
    }

    /// `Pending`, or the timeout error once a deadline has passed.
    fn pending_or_timeout<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        match self.check_deadlines(cx) {
            Ok(()) => Poll::Pending,
            Err(e) => Poll::Ready(Err(e)),
        }
    }
}

impl axum::serve::Listener for LimitedListener {
    type Io = LimitedStream;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        loop {
            // Without eviction a slot comes first: a connection waits in
            // the kernel's queue. With it, the new connection is what may
            // close an unadmitted one.
            let early = match self.deadlines.unadmitted {
                None => Some(self.slot().await),
                Some(_) => None,
            };
            match self.inner.accept().await {
                Ok((stream, addr)) => {
                    let slot = match early {
                        Some(slot) => slot,
                        None => self.slot().await,
                    };
                    let _ = stream.set_nodelay(true);
                    let conn = LimitedStream::new(stream, slot, self.deadlines);
                    self.track(&conn.state);
                    return (conn, addr);
                }
                Err(e) => {
                    tracing::debug!(error = %e, "accept failed");
                    tokio::time::sleep(ACCEPT_RETRY).await;
                }
            }
        }
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

impl AsyncRead for LimitedStream {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.state.is_evicted() {
            return self.pending_or_timeout(cx);
        }
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                if buf.filled().len() > before {
                    let now = Instant::now();
                    self.last_active = now;
                    if self.request_since.is_none() {
                        self.request_since = Some(now);
                        self.state.set_request_since(Some(now));
                    }
                }
                Poll::Ready(Ok(()))
            }
            Poll::Pending => self.pending_or_timeout(cx),
            other => other,
        }
    }
}

impl AsyncWrite for LimitedStream {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        if self.state.is_evicted() {
            return self.pending_or_timeout(cx);
        }
        let r = Pin::new(&mut self.stream).poll_write(cx, buf);
        match r {
            Poll::Ready(Ok(n)) if n > 0 => {
                let now = Instant::now();
                self.last_active = now;
                // Answered: the next byte read starts the next request. The
                // answer's grace runs from its first byte only: a client
                // reading it slowly keeps its slot no longer than that.
                let answered = self.request_since.take().is_some();
                if answered {
                    self.state.set_request_since(None);
                }
                let mut t = self.state.times();
                t.blocked = false;
                if answered {
                    t.answer = Some(now);
                }
            }
            // A client that does not read fills the socket: time it out.
            Poll::Pending => {
                self.state.times().blocked = true;
                return self.pending_or_timeout(cx);
            }
            _ => {}
        }
        r
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match Pin::new(&mut self.stream).poll_flush(cx) {
            Poll::Pending => self.pending_or_timeout(cx),
            other => other,
        }
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A connection never admitted may be closed for a new one only past
    /// its grace: not just accepted (a probe not read yet), not in the
    /// first second of a request, not in the first second of an answer
    /// its reader holds up; but between requests at once, however often
    /// they come, and a request trickled or an answer read slowly for
    /// longer.
    #[test]
    fn an_unadmitted_connection_is_evictable_only_past_its_grace() {
        let grace = REQUEST_GRACE;
        let long = Duration::from_secs(3600);
        let c = ConnState::default();
        let t0 = Instant::now();
        c.times().accepted = Some(t0);
        assert!(!c.evictable(t0 + grace / 2, long), "just accepted");
        assert!(c.evictable(t0 + grace, long), "silent since accepted");
        let t1 = t0 + grace * 2;
        c.set_request_since(Some(t1));
        assert!(!c.evictable(t1 + grace / 2, long), "a request just begun");
        assert!(c.is_busy());
        assert!(c.evictable(t1 + grace, long), "trickling past its grace");
        // Answered at once: between requests it may go, though the next
        // comes within the second.
        let t2 = t1 + grace / 4;
        c.set_request_since(None);
        c.times().answer = Some(t2);
        assert!(!c.is_busy());
        assert!(c.evictable(t2 + grace / 8, long), "between requests");
        // An answer held up by its reader keeps it from its first byte.
        c.times().blocked = true;
        assert!(c.is_busy());
        assert!(
            !c.evictable(t2 + grace / 2, long),
            "an answer being written"
        );
        assert!(
            c.evictable(t2 + grace, long),
            "a slow reader past its grace"
        );
        // Whatever it does, past its age.
        c.set_request_since(Some(t2 + grace * 3));
        assert!(!c.evictable(t2 + grace * 3, long));
        assert!(c.evictable(t2 + grace * 3, grace * 2), "open past its age");
        c.admit(Box::new(|| true));
        assert!(!c.evictable(t2 + grace * 9, long), "admitted");
        assert!(
            !c.evictable(t2 + grace * 9, grace),
            "admitted, past its age"
        );
    }
}
