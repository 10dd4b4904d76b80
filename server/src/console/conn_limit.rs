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

use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use std::future::Future;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};

/// Pause after a failed accept (e.g. out of file descriptors).
const ACCEPT_RETRY: std::time::Duration = std::time::Duration::from_millis(50);

/// How long a connection may stay silent, and a request unanswered.
#[derive(Debug, Clone, Copy)]
pub struct Deadlines {
    pub idle: Duration,
    pub request: Duration,
}

/// [`TcpListener`] with a connection cap, for `axum::serve`.
#[derive(Debug)]
pub struct LimitedListener {
    inner: TcpListener,
    slots: Arc<Semaphore>,
    deadlines: Deadlines,
}

impl LimitedListener {
    pub fn new(inner: TcpListener, max: usize, deadlines: Deadlines) -> Self {
        Self {
            inner,
            slots: Arc::new(Semaphore::new(max)),
            deadlines,
        }
    }
}

/// A connection, its slot and its deadlines.
#[derive(Debug)]
pub struct LimitedStream {
    stream: TcpStream,
    _slot: OwnedSemaphorePermit,
    deadlines: Deadlines,
    last_active: Instant,
    /// When the first byte of a request not answered yet arrived.
    request_since: Option<Instant>,
    deadline: Pin<Box<Sleep>>,
}

impl LimitedStream {
    fn new(stream: TcpStream, slot: OwnedSemaphorePermit, deadlines: Deadlines) -> Self {
        let now = Instant::now();
        Self {
            stream,
            _slot: slot,
            deadlines,
            last_active: now,
            request_since: None,
            deadline: Box::pin(tokio::time::sleep_until(now + deadlines.idle)),
        }
    }

    /// An error once nothing moved for the idle time, or a request went
    /// unanswered for the request time; else arms the timer.
    fn check_deadlines(&mut self, cx: &mut Context<'_>) -> io::Result<()> {
        let idle = self.last_active + self.deadlines.idle;
        let request = self.request_since.map(|t| t + self.deadlines.request);
        let due = request.map_or(idle, |r| r.min(idle));
        if self.deadline.deadline() != due {
            self.deadline.as_mut().reset(due);
        }
        match self.deadline.as_mut().poll(cx) {
            Poll::Ready(()) => Err(io::Error::new(
                io::ErrorKind::TimedOut,
                if request == Some(due) {
                    "console request too slow"
                } else {
                    "console connection idle"
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
            let Ok(slot) = self.slots.clone().acquire_owned().await else {
                // The semaphore is never closed; wait as if it were full.
                std::future::pending::<()>().await;
                continue;
            };
            match self.inner.accept().await {
                Ok((stream, addr)) => {
                    let _ = stream.set_nodelay(true);
                    return (LimitedStream::new(stream, slot, self.deadlines), addr);
                }
                Err(e) => {
                    tracing::debug!(error = %e, "console accept failed");
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
        let before = buf.filled().len();
        match Pin::new(&mut self.stream).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                if buf.filled().len() > before {
                    let now = Instant::now();
                    self.last_active = now;
                    self.request_since.get_or_insert(now);
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
        let r = Pin::new(&mut self.stream).poll_write(cx, buf);
        match r {
            Poll::Ready(Ok(n)) if n > 0 => {
                self.last_active = Instant::now();
                // Answered: the next byte read starts the next request.
                self.request_since = None;
            }
            // A client that does not read fills the socket: time it out.
            Poll::Pending => return self.pending_or_timeout(cx),
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
