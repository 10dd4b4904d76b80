//! A UDP socket whose sends reach the wire a fixed time late: a simulated
//! one-way link delay, for load tests at a real network's round-trip time
//! on loopback (where `tc netem` is not available).
//!
//! Every datagram quinn hands to [`DelayedSocket::try_send`] is copied to
//! a FIFO and sent by a background task once `delay` has passed. Receives
//! are not delayed, so the connection's RTT grows by `delay`. The FIFO
//! holds at most [`LINK_QUEUE_LIMIT`] datagrams; past that a send is
//! dropped, as a full router queue would, and QUIC's loss recovery resends.

use std::collections::VecDeque;
use std::fmt;
use std::future::poll_fn;
use std::io::{self, IoSliceMut};
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use quinn::udp::{EcnCodepoint, RecvMeta, Transmit};
use quinn::{AsyncUdpSocket, UdpPoller};
use tokio::sync::Notify;
use tokio::time::Instant;

/// Datagrams one delayed socket holds in flight before it drops sends.
pub const LINK_QUEUE_LIMIT: usize = 4096;

/// Wraps `inner` so that every send leaves `delay` late. Must be called
/// inside a tokio runtime: it spawns the task that sends.
pub fn delayed(inner: Arc<dyn AsyncUdpSocket>, delay: Duration) -> Arc<DelayedSocket> {
    let link = Arc::new(Link {
        held: Mutex::new(VecDeque::new()),
        wake: Notify::new(),
        closed: AtomicBool::new(false),
        dropped: AtomicU64::new(0),
    });
    tokio::spawn(send_when_due(inner.clone(), link.clone()));
    Arc::new(DelayedSocket { inner, link, delay })
}

/// A socket from [`delayed`].
pub struct DelayedSocket {
    inner: Arc<dyn AsyncUdpSocket>,
    link: Arc<Link>,
    delay: Duration,
}

impl DelayedSocket {
    /// Sends dropped because the FIFO was full.
    pub fn dropped(&self) -> u64 {
        self.link.dropped.load(Ordering::Relaxed)
    }
}

/// The FIFO shared with the sending task.
struct Link {
    held: Mutex<VecDeque<Held>>,
    wake: Notify,
    closed: AtomicBool,
    dropped: AtomicU64,
}

/// One datagram (or GSO batch) waiting for its time.
struct Held {
    due: Instant,
    destination: SocketAddr,
    ecn: Option<EcnCodepoint>,
    contents: Vec<u8>,
    segment_size: Option<usize>,
    src_ip: Option<IpAddr>,
}

impl Drop for DelayedSocket {
    fn drop(&mut self) {
        self.link.closed.store(true, Ordering::Release);
        self.link.wake.notify_one();
    }
}

impl fmt::Debug for DelayedSocket {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("DelayedSocket")
            .field("inner", &self.inner)
            .field("delay", &self.delay)
            .finish()
    }
}

/// Sends never wait: they only queue.
#[derive(Debug)]
struct AlwaysWritable;

impl UdpPoller for AlwaysWritable {
    fn poll_writable(self: Pin<&mut Self>, _cx: &mut Context) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

impl AsyncUdpSocket for DelayedSocket {
    fn create_io_poller(self: Arc<Self>) -> Pin<Box<dyn UdpPoller>> {
        Box::pin(AlwaysWritable)
    }

    fn try_send(&self, transmit: &Transmit) -> io::Result<()> {
        let mut held = self.link.held.lock().unwrap_or_else(|p| p.into_inner());
        if held.len() >= LINK_QUEUE_LIMIT {
            self.link.dropped.fetch_add(1, Ordering::Relaxed);
            return Ok(());
        }
        held.push_back(Held {
            due: Instant::now() + self.delay,
            destination: transmit.destination,
            ecn: transmit.ecn,
            contents: transmit.contents.to_vec(),
            segment_size: transmit.segment_size,
            src_ip: transmit.src_ip,
        });
        drop(held);
        self.link.wake.notify_one();
        Ok(())
    }

    fn poll_recv(
        &self,
        cx: &mut Context,
        bufs: &mut [IoSliceMut<'_>],
        meta: &mut [RecvMeta],
    ) -> Poll<io::Result<usize>> {
        self.inner.poll_recv(cx, bufs, meta)
    }

    fn local_addr(&self) -> io::Result<SocketAddr> {
        self.inner.local_addr()
    }

    fn max_transmit_segments(&self) -> usize {
        self.inner.max_transmit_segments()
    }

    fn max_receive_segments(&self) -> usize {
        self.inner.max_receive_segments()
    }

    fn may_fragment(&self) -> bool {
        self.inner.may_fragment()
    }
}

/// Sends each held datagram when it falls due, in order (one fixed delay
/// keeps the FIFO sorted by due time). Ends once the socket is dropped.
async fn send_when_due(inner: Arc<dyn AsyncUdpSocket>, link: Arc<Link>) {
    let mut poller = inner.clone().create_io_poller();
    loop {
        let next = {
            let held = link.held.lock().unwrap_or_else(|p| p.into_inner());
            held.front().map(|h| h.due)
        };
        if link.closed.load(Ordering::Acquire) {
            return;
        }
        let Some(due) = next else {
            link.wake.notified().await;
            continue;
        };
        tokio::time::sleep_until(due).await;
        let Some(h) = link
            .held
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .pop_front()
        else {
            continue;
        };
        let transmit = Transmit {
            destination: h.destination,
            ecn: h.ecn,
            contents: &h.contents,
            segment_size: h.segment_size,
            src_ip: h.src_ip,
        };
        loop {
            match inner.try_send(&transmit) {
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                    if poll_fn(|cx| poller.as_mut().poll_writable(cx))
                        .await
                        .is_err()
                    {
                        break;
                    }
                }
                // Sent, or lost as a real link would lose it.
                _ => break,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn transmit(to: SocketAddr, contents: &[u8]) -> Transmit<'_> {
        Transmit {
            destination: to,
            ecn: None,
            contents,
            segment_size: None,
            src_ip: None,
        }
    }

    fn wrapped(delay: Duration) -> Arc<DelayedSocket> {
        let sock = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let runtime = quinn::TokioRuntime;
        let inner = quinn::Runtime::wrap_udp_socket(&runtime, sock).unwrap();
        delayed(inner, delay)
    }

    #[tokio::test]
    async fn sends_leave_late_and_in_order() {
        let delay = Duration::from_millis(80);
        let socket = wrapped(delay);
        let peer = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let to = peer.local_addr().unwrap();
        let start = Instant::now();
        for i in 0..10u8 {
            socket.try_send(&transmit(to, &[i; 32])).unwrap();
        }
        let mut buf = [0u8; 64];
        for i in 0..10u8 {
            let n = tokio::time::timeout(Duration::from_secs(10), peer.recv(&mut buf))
                .await
                .expect("the datagram arrives")
                .unwrap();
            assert_eq!(&buf[..n], &[i; 32], "datagram {i} in order");
            assert!(start.elapsed() >= delay, "datagram {i} left early");
        }
        assert_eq!(socket.dropped(), 0);
    }

    #[tokio::test]
    async fn a_full_link_drops_sends_past_its_limit() {
        let socket = wrapped(Duration::from_secs(3600));
        let to: SocketAddr = "127.0.0.1:9".parse().unwrap();
        for _ in 0..LINK_QUEUE_LIMIT + 5 {
            socket.try_send(&transmit(to, b"x")).unwrap();
        }
        assert_eq!(socket.dropped(), 5);
    }
}
