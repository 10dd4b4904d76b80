//! One bounded writer task per outgoing stream. The sequencer only ever
//! `try_send`s encoded frames here; it never touches a socket. The fan-out
//! workers may also write a batch straight into the stream's QUIC buffer
//! ([`FrameSender::send_now`]) when nothing is queued before it, which
//! saves waking the writer task: the frames' order on the stream is the
//! order they were handed over either way.

use std::future::Future;
use std::pin::pin;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use bytes::Bytes;
use tokio::sync::{mpsc, Mutex};
use tokio::task::JoinHandle;
use tracing::{debug, Instrument};

use crate::metrics::BYTES_SENT;

/// Most queued frames one write takes.
pub const WRITE_BATCH_FRAMES: usize = 64;

/// Why a frame was not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SendRefused {
    /// The peer is slow: the queue is at capacity.
    Full,
    /// The writer has stopped (connection gone).
    Closed,
}

/// Where [`FrameSender::send_now`] put a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handed {
    /// Whole, into the stream's QUIC buffer.
    Written = 0,
    /// Its start into the stream; the rest goes next, by the writer.
    Begun = 1,
    /// Into the queue, as [`FrameSender::try_send`] would.
    Queued = 2,
}

/// The producer side of a writer queue. Cheap to clone.
#[derive(Debug, Clone)]
pub struct FrameSender {
    queue: mpsc::Sender<Bytes>,
    /// The stream, shared with its writer task, where frames may skip the
    /// queue (writers with no send interval).
    direct: Option<Arc<Direct>>,
    /// Bytes queued and not yet written, with their bound.
    bytes: Arc<ByteBound>,
}

/// The bytes of the frames in a writer's queue, or taken by the writer and
/// not yet written (`[net] writer_queue_bytes`): a session that stops
/// reading holds at most that much, whatever the frames' count (and the
/// rest of one frame [`FrameSender::send_now`] began).
#[derive(Debug)]
struct ByteBound {
    queued: AtomicUsize,
    max: usize,
}

impl ByteBound {
    /// Counts `len` more bytes, or none when they would pass the bound
    /// (a frame into an empty queue always fits: it is never refused for
    /// its size alone).
    fn take(&self, len: usize) -> bool {
        let before = self.queued.fetch_add(len, Ordering::AcqRel);
        if before > 0 && before.saturating_add(len) > self.max {
            self.queued.fetch_sub(len, Ordering::AcqRel);
            return false;
        }
        true
    }

    fn give_back(&self, len: usize) {
        self.queued.fetch_sub(len, Ordering::AcqRel);
    }
}

/// A stream both its writer task and [`FrameSender::send_now`] write to.
struct Direct {
    stream: Mutex<Locked>,
    /// Frames handed to the queue and not yet written (in the queue or in
    /// the writer's hands). A frame skips the queue only when this is 0.
    queued: AtomicUsize,
    bytes_sent: metrics::Counter,
}

/// What the stream's lock guards.
struct Locked {
    stream: quinn::SendStream,
    /// The unwritten end of a frame `send_now` began: written before
    /// anything else, so that no frame lands inside another.
    rest: Option<Bytes>,
}

impl std::fmt::Debug for Direct {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Direct")
            .field("queued", &self.queued.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

impl FrameSender {
    /// A queue of `capacity` frames whose other end is not a stream (the
    /// in-process pipeline bench reads it directly).
    pub fn channel(capacity: usize) -> (FrameSender, mpsc::Receiver<Bytes>) {
        let (tx, rx) = mpsc::channel(capacity.max(1));
        let sender = FrameSender {
            queue: tx,
            direct: None,
            bytes: Arc::new(ByteBound {
                queued: AtomicUsize::new(0),
                max: usize::MAX,
            }),
        };
        (sender, rx)
    }

    /// Queues a frame without waiting: `Full` when the queue holds its
    /// count of frames or its bytes.
    pub fn try_send(&self, frame: Bytes) -> Result<(), SendRefused> {
        // A writer gone leaves its bytes counted: `Closed`, not `Full`.
        if self.queue.is_closed() {
            return Err(SendRefused::Closed);
        }
        let len = frame.len();
        if !self.bytes.take(len) {
            return Err(SendRefused::Full);
        }
        // Counted before the writer can see it, so that it never counts
        // below zero.
        if let Some(d) = &self.direct {
            d.queued.fetch_add(1, Ordering::AcqRel);
        }
        self.queue.try_send(frame).map_err(|e| {
            self.bytes.give_back(len);
            if let Some(d) = &self.direct {
                d.queued.fetch_sub(1, Ordering::AcqRel);
            }
            match e {
                mpsc::error::TrySendError::Full(_) => SendRefused::Full,
                mpsc::error::TrySendError::Closed(_) => SendRefused::Closed,
            }
        })
    }

    /// Writes a frame into the stream's QUIC buffer at once when nothing
    /// queued is waiting to go before it and QUIC takes it; else queues it
    /// as [`try_send`](Self::try_send) does. Never waits: if the writer
    /// holds the stream, the frame is queued. Meant for threads outside
    /// the async runtime with many streams to feed (the fan-out workers),
    /// where waking one writer task per stream costs more than the write.
    pub fn send_now(&self, frame: Bytes) -> Result<Handed, SendRefused> {
        let queue = |frame| self.try_send(frame).map(|()| Handed::Queued);
        let Some(d) = &self.direct else {
            return queue(frame);
        };
        let Ok(mut locked) = d.stream.try_lock() else {
            return queue(frame);
        };
        // Under the lock: a frame queued from now on is written after the
        // writer takes the lock, so after this one.
        if d.queued.load(Ordering::Acquire) != 0 {
            drop(locked);
            return queue(frame);
        }
        // A slot held first: a frame begun must be finished, and its rest
        // needs a queue entry to wake the writer.
        let permit = self.queue.try_reserve().map_err(|e| match e {
            mpsc::error::TrySendError::Full(()) => SendRefused::Full,
            mpsc::error::TrySendError::Closed(()) => SendRefused::Closed,
        })?;
        let mut bufs = [frame];
        let written = {
            let write = pin!(locked.stream.write_chunks(&mut bufs));
            // Cancel-safe: a write that does not resolve wrote nothing.
            match write.poll(&mut Context::from_waker(Waker::noop())) {
                Poll::Ready(Ok(w)) => w.bytes,
                Poll::Ready(Err(e)) => {
                    debug!(error = %e, "write failed");
                    return Err(SendRefused::Closed);
                }
                // Blocked by flow control: the writer will wait for QUIC.
                Poll::Pending => 0,
            }
        };
        d.bytes_sent.increment(written as u64);
        let [rest] = bufs;
        if rest.is_empty() {
            return Ok(Handed::Written);
        }
        // The writer writes `rest` first when it takes this wake-up.
        locked.rest = Some(rest);
        d.queued.fetch_add(1, Ordering::AcqRel);
        permit.send(Bytes::new());
        Ok(if written == 0 {
            Handed::Queued
        } else {
            Handed::Begun
        })
    }

    /// Whether a small frame would be queued now: the writer there, a free
    /// slot, and bytes under the bound.
    pub fn has_room(&self) -> bool {
        self.has_room_for(1)
    }

    /// Whether a frame of `len` bytes would be queued now (as
    /// [`Self::try_send`] decides): the writer there, a free slot, and the
    /// bytes within the bound (or none queued).
    pub fn has_room_for(&self, len: usize) -> bool {
        let queued = self.bytes.queued.load(Ordering::Acquire);
        !self.queue.is_closed()
            && self.queue.capacity() > 0
            && (queued == 0 || queued.saturating_add(len) <= self.bytes.max)
    }

    /// Free slots in the queue.
    pub fn capacity(&self) -> usize {
        self.queue.capacity()
    }

    /// Batches queued and not yet taken by the writer.
    pub fn queued(&self) -> usize {
        self.queue.max_capacity() - self.queue.capacity()
    }

    /// Whether every queued frame has been taken by the writer.
    pub fn is_idle(&self) -> bool {
        self.queue.capacity() == self.queue.max_capacity()
    }

    pub fn is_closed(&self) -> bool {
        self.queue.is_closed()
    }
}

/// How long a finished writer waits for the peer to acknowledge the
/// stream's last bytes: a peer that never does holds no task longer.
pub const FINISH_WAIT: Duration = Duration::from_secs(5);

/// Spawns a task that writes queued frames to `stream` in order, waiting
/// `interval` after each write (zero: none) so that the frames queued
/// meanwhile share packets; then finishes the stream when every sender is
/// dropped and ends once the peer has acknowledged all of it (at most
/// [`FINISH_WAIT`]). With no interval, [`FrameSender::send_now`] may write
/// to the stream too.
pub fn spawn_writer(
    stream: quinn::SendStream,
    (capacity, max_bytes): (usize, usize),
    interval: Duration,
    name: &'static str,
) -> (FrameSender, JoinHandle<()>) {
    let (tx, mut rx) = mpsc::channel::<Bytes>(capacity);
    let bound = Arc::new(ByteBound {
        queued: AtomicUsize::new(0),
        max: max_bytes,
    });
    let written = bound.clone();
    let bytes_sent = metrics::counter!(BYTES_SENT);
    let direct = Arc::new(Direct {
        stream: Mutex::new(Locked { stream, rest: None }),
        queued: AtomicUsize::new(0),
        bytes_sent: bytes_sent.clone(),
    });
    let shared = direct.clone();
    // Without an interval, senders count what they queue.
    let counted = interval.is_zero();
    let task = tokio::spawn(
        async move {
            // Frames queued together go out in one write, so QUIC packs them
            // into as few packets as their size allows.
            let mut batch: Vec<Bytes> = Vec::with_capacity(WRITE_BATCH_FRAMES + 1);
            loop {
                let taken = rx.recv_many(&mut batch, WRITE_BATCH_FRAMES).await;
                let mut guard = shared.stream.lock().await;
                if taken == 0 {
                    // Finished: wait (bounded by whoever awaits this task)
                    // until the peer has every byte, so a close that
                    // follows cannot drop the last frames (a refusal's
                    // Error) still in QUIC's send buffer.
                    if guard.stream.finish().is_ok() {
                        let acked = guard.stream.stopped();
                        let _ = tokio::time::timeout(FINISH_WAIT, acked).await;
                    }
                    return;
                }
                // The queue's bytes, counted until written.
                let queued: usize = batch.iter().map(Bytes::len).sum();
                let Locked { stream, rest } = &mut *guard;
                if let Some(rest) = rest.take() {
                    batch.insert(0, rest);
                }
                // Empty entries only wake the writer for a `rest`.
                batch.retain(|b| !b.is_empty());
                let bytes: usize = batch.iter().map(Bytes::len).sum();
                if let Err(e) = stream.write_all_chunks(&mut batch).await {
                    debug!(error = %e, "write failed; writer stops");
                    return;
                }
                if counted {
                    shared.queued.fetch_sub(taken, Ordering::AcqRel);
                }
                written.give_back(queued);
                drop(guard);
                batch.clear();
                bytes_sent.increment(bytes as u64);
                if !interval.is_zero() {
                    // Frames queued meanwhile go out together next time.
                    tokio::time::sleep(interval).await;
                }
            }
        }
        .instrument(tracing::debug_span!("writer", stream = name)),
    );
    let sender = FrameSender {
        queue: tx,
        direct: counted.then_some(direct),
        bytes: bound,
    };
    (sender, task)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A queue holds at most its bytes (an empty one takes any frame);
    /// a refused frame counts nothing, and written ones make room.
    #[test]
    fn a_queue_holds_at_most_its_bytes() {
        let (tx, _rx) = mpsc::channel(16);
        let bytes = Arc::new(ByteBound {
            queued: AtomicUsize::new(0),
            max: 100,
        });
        let sender = FrameSender {
            queue: tx,
            direct: None,
            bytes: bytes.clone(),
        };
        let frame = |n: usize| Bytes::from(vec![7u8; n]);
        assert_eq!(sender.try_send(frame(60)), Ok(()));
        assert_eq!(sender.try_send(frame(40)), Ok(()));
        assert_eq!(sender.try_send(frame(1)), Err(SendRefused::Full));
        assert_eq!(bytes.queued.load(Ordering::Acquire), 100);
        // Written by the writer: room again, and an empty queue takes a
        // frame larger than the bound.
        bytes.give_back(100);
        assert_eq!(sender.try_send(frame(500)), Ok(()));
        assert_eq!(sender.try_send(frame(1)), Err(SendRefused::Full));
    }

    /// A frame: its length (4 bytes), producer, index (4 bytes), then
    /// filler, so that a frame cut or landing inside another shows.
    fn frame(producer: u8, index: u32, len: usize) -> Bytes {
        let mut f = Vec::with_capacity(len);
        f.extend_from_slice(&(len as u32).to_le_bytes());
        f.push(producer);
        f.extend_from_slice(&index.to_le_bytes());
        f.resize(len, (index as u8) ^ producer);
        Bytes::from(f)
    }

    /// Parses a stream of [`frame`]s into (producer, index) pairs,
    /// checking each frame's filler.
    fn parse(mut bytes: &[u8]) -> Vec<(u8, u32)> {
        let mut out = Vec::new();
        while !bytes.is_empty() {
            let len = u32::from_le_bytes(bytes[..4].try_into().unwrap()) as usize;
            let (f, rest) = bytes.split_at(len);
            let (producer, index) = (f[4], u32::from_le_bytes(f[5..9].try_into().unwrap()));
            assert!(
                f[9..].iter().all(|&b| b == (index as u8) ^ producer),
                "frame {producer}/{index} was cut or overwritten"
            );
            out.push((producer, index));
            bytes = rest;
        }
        out
    }

    /// A server-side writer on a real QUIC stream to a client on
    /// loopback whose receive windows are `window` bytes (small windows
    /// make writes block and split), and the client's task that reads it
    /// all once `go` fires.
    async fn writer_to_client(
        window: u32,
        interval: Duration,
    ) -> (
        FrameSender,
        JoinHandle<()>,
        (tokio::sync::oneshot::Sender<()>, JoinHandle<Vec<u8>>),
        quinn::Endpoint,
    ) {
        let mut transport = quinn::TransportConfig::default();
        transport
            .stream_receive_window(quinn::VarInt::from_u32(window))
            .receive_window(quinn::VarInt::from_u32(window));
        let (server_conn, conn, (server, _client)) =
            crate::net::loopback::pair(Some(transport)).await;
        let (go, wait) = tokio::sync::oneshot::channel::<()>();
        let reader = tokio::spawn(async move {
            let _ = wait.await;
            let mut recv = conn.accept_uni().await.unwrap();
            let all = recv.read_to_end(64 << 20).await.unwrap();
            conn.close(0u32.into(), b"done");
            all
        });
        let uni = server_conn.open_uni().await.unwrap();
        let (tx, task) = spawn_writer(uni, (64, usize::MAX), interval, "test");
        (tx, task, (go, reader), server)
    }

    /// Drops the last sender, lets the writer finish the stream, and
    /// parses what the client read.
    async fn received(
        tx: FrameSender,
        task: JoinHandle<()>,
        reader: JoinHandle<Vec<u8>>,
    ) -> Vec<(u8, u32)> {
        drop(tx);
        task.await.unwrap();
        parse(&reader.await.unwrap())
    }

    /// Sends `f` until it is taken: every frame must go.
    fn send_retrying(tx: &FrameSender, f: Bytes, now: bool) -> Handed {
        loop {
            let sent = if now {
                tx.send_now(f.clone())
            } else {
                tx.try_send(f.clone()).map(|()| Handed::Queued)
            };
            match sent {
                Ok(h) => return h,
                Err(SendRefused::Full) => std::thread::yield_now(),
                Err(SendRefused::Closed) => panic!("the writer stopped"),
            }
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn frames_written_at_once_or_queued_arrive_whole_and_in_order() {
        tokio::time::timeout(Duration::from_secs(60), async {
            // 16 KiB of credit and a client that does not read yet.
            let (tx, task, (go, reader), _server) =
                writer_to_client(16 << 10, Duration::ZERO).await;
            let sender = tx.clone();
            tokio::task::spawn_blocking(move || {
                // Fits the credit; then only its first 6,384 bytes do, and
                // the next frame must wait behind the rest.
                assert_eq!(sender.send_now(frame(0, 0, 10_000)), Ok(Handed::Written));
                assert_eq!(sender.send_now(frame(0, 1, 10_000)), Ok(Handed::Begun));
                assert_eq!(sender.send_now(frame(0, 2, 500)), Ok(Handed::Queued));
                assert_eq!(sender.try_send(frame(0, 3, 500)), Ok(()));
            })
            .await
            .unwrap();
            let _ = go.send(());
            // Then a stream of both kinds, writes blocking and splitting
            // as the client reads.
            let sender = tx.clone();
            tokio::task::spawn_blocking(move || {
                for i in 4..400u32 {
                    let f = frame(0, i, 16 + (i as usize * 997) % 9_000);
                    send_retrying(&sender, f, i % 3 != 2);
                }
            })
            .await
            .unwrap();
            let want: Vec<(u8, u32)> = (0..400).map(|i| (0, i)).collect();
            let bytes = tx.bytes.clone();
            assert_eq!(received(tx, task, reader).await, want);
            // Every queued byte was given back once written.
            assert_eq!(bytes.queued.load(Ordering::Acquire), 0);
        })
        .await
        .expect("bounded");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn two_threads_writing_at_once_never_cut_each_others_frames() {
        tokio::time::timeout(Duration::from_secs(60), async {
            let (tx, task, (go, reader), _server) =
                writer_to_client(24 << 10, Duration::ZERO).await;
            let _ = go.send(());
            let producers: Vec<_> = (0..2u8)
                .map(|producer| {
                    let sender = tx.clone();
                    tokio::task::spawn_blocking(move || {
                        for i in 0..300u32 {
                            let f = frame(producer, i, 16 + (i as usize * 1_231) % 7_000);
                            send_retrying(&sender, f, producer == 0);
                        }
                    })
                })
                .collect();
            for p in producers {
                p.await.unwrap();
            }
            let got = received(tx, task, reader).await;
            for producer in 0..2u8 {
                let mine: Vec<u32> = got
                    .iter()
                    .filter(|(p, _)| *p == producer)
                    .map(|&(_, i)| i)
                    .collect();
                assert_eq!(mine, (0..300).collect::<Vec<_>>(), "producer {producer}");
            }
        })
        .await
        .expect("bounded");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn with_a_send_interval_every_frame_is_queued() {
        tokio::time::timeout(Duration::from_secs(30), async {
            let (tx, task, (go, reader), _server) =
                writer_to_client(1 << 20, Duration::from_millis(5)).await;
            let _ = go.send(());
            for i in 0..20u32 {
                assert_eq!(tx.send_now(frame(0, i, 100)), Ok(Handed::Queued));
            }
            let want: Vec<(u8, u32)> = (0..20).map(|i| (0, i)).collect();
            assert_eq!(received(tx, task, reader).await, want);
        })
        .await
        .expect("bounded");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_closed_connection_refuses_frames_sent_at_once() {
        tokio::time::timeout(Duration::from_secs(30), async {
            let (tx, _task, (_go, reader), server) =
                writer_to_client(1 << 20, Duration::ZERO).await;
            assert_eq!(tx.send_now(frame(0, 0, 100)), Ok(Handed::Written));
            server.close(0u32.into(), b"bye");
            server.wait_idle().await;
            let refused = tx.send_now(frame(0, 1, 100));
            assert_eq!(refused, Err(SendRefused::Closed));
            drop(reader);
        })
        .await
        .expect("bounded");
    }
}
