//! One bounded writer task per outgoing stream. The sequencer only ever
//! `try_send`s encoded frames here; it never touches a socket.

use bytes::Bytes;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tracing::{debug, Instrument};

use crate::metrics::BYTES_SENT;

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

    pub fn is_closed(&self) -> bool {
        self.0.is_closed()
    }
}

/// Spawns a task that writes queued frames to `stream` in order, then
/// finishes the stream when every sender is dropped.
pub fn spawn_writer(
    mut stream: quinn::SendStream,
    capacity: usize,
    name: &'static str,
) -> (FrameSender, JoinHandle<()>) {
    let (tx, mut rx) = mpsc::channel::<Bytes>(capacity);
    let task = tokio::spawn(
        async move {
            while let Some(frame) = rx.recv().await {
                if let Err(e) = stream.write_all(&frame).await {
                    debug!(error = %e, "write failed; writer stops");
                    return;
                }
                metrics::counter!(BYTES_SENT).increment(frame.len() as u64);
            }
            let _ = stream.finish();
        }
        .instrument(tracing::debug_span!("writer", stream = name)),
    );
    (FrameSender(tx), task)
}
