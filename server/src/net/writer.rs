//! One bounded writer task per outgoing stream. The sequencer only ever
//! `try_send`s encoded frames here; it never touches a socket.

use std::time::Duration;

use bytes::Bytes;
use tokio::sync::mpsc;
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

/// The producer side of a writer queue. Cheap to clone.
#[derive(Debug, Clone)]
pub struct FrameSender(mpsc::Sender<Bytes>);

impl FrameSender {
    /// A queue of `capacity` frames whose other end is not a stream (the
    /// in-process pipeline bench reads it directly).
    pub fn channel(capacity: usize) -> (FrameSender, mpsc::Receiver<Bytes>) {
        let (tx, rx) = mpsc::channel(capacity.max(1));
        (FrameSender(tx), rx)
    }

    /// Queues a frame without waiting.
    pub fn try_send(&self, frame: Bytes) -> Result<(), SendRefused> {
        self.0.try_send(frame).map_err(|e| match e {
            mpsc::error::TrySendError::Full(_) => SendRefused::Full,
            mpsc::error::TrySendError::Closed(_) => SendRefused::Closed,
        })
    }

    /// Free slots in the queue.
    pub fn capacity(&self) -> usize {
        self.0.capacity()
    }

    /// Whether every queued frame has been taken by the writer.
    pub fn is_idle(&self) -> bool {
        self.0.capacity() == self.0.max_capacity()
    }

    pub fn is_closed(&self) -> bool {
        self.0.is_closed()
    }
}

/// Spawns a task that writes queued frames to `stream` in order, waiting
/// `interval` after each write (zero: none) so that the frames queued
/// meanwhile share packets; then finishes the stream when every sender is
/// dropped and ends once the peer has acknowledged all of it.
pub fn spawn_writer(
    mut stream: quinn::SendStream,
    capacity: usize,
    interval: Duration,
    name: &'static str,
) -> (FrameSender, JoinHandle<()>) {
    let (tx, mut rx) = mpsc::channel::<Bytes>(capacity);
    let task = tokio::spawn(
        async move {
            // Frames queued together go out in one write, so QUIC packs them
            // into as few packets as their size allows.
            let mut batch: Vec<Bytes> = Vec::with_capacity(WRITE_BATCH_FRAMES);
            let bytes_sent = metrics::counter!(BYTES_SENT);
            while rx.recv_many(&mut batch, WRITE_BATCH_FRAMES).await > 0 {
                let bytes: usize = batch.iter().map(Bytes::len).sum();
                if let Err(e) = stream.write_all_chunks(&mut batch).await {
                    debug!(error = %e, "write failed; writer stops");
                    return;
                }
                batch.clear();
                bytes_sent.increment(bytes as u64);
                if !interval.is_zero() {
                    // Frames queued meanwhile go out together next time.
                    tokio::time::sleep(interval).await;
                }
            }
            // Finished: wait (bounded by whoever awaits this task) until the
            // peer has every byte, so a close that follows cannot drop the
            // last frames (a refusal's Error) still in QUIC's send buffer.
            if stream.finish().is_ok() {
                let _ = stream.stopped().await;
            }
        }
        .instrument(tracing::debug_span!("writer", stream = name)),
    );
    (FrameSender(tx), task)
}
