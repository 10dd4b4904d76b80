//! Async frame reading over any tokio reader (QUIC streams included).

use serde::de::DeserializeOwned;
use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt};

use crate::frame::{FrameBuffer, FrameError};

/// Bytes read per call; a frame larger than this arrives in several reads.
const READ_CHUNK: usize = 16 * 1024;

#[derive(Debug, Error)]
pub enum ReadError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error("stream ended in the middle of a frame ({0} bytes pending)")]
    Truncated(usize),
    #[error("stream read failed: {0}")]
    Io(#[from] std::io::Error),
}

/// Reads framed messages from one stream.
#[derive(Debug)]
pub struct FramedReader<R> {
    inner: R,
    buf: FrameBuffer,
    scratch: Vec<u8>,
    total: u64,
}

impl<R: AsyncRead + Unpin> FramedReader<R> {
    pub fn new(inner: R, buf: FrameBuffer) -> Self {
        Self {
            inner,
            buf,
            scratch: vec![0; READ_CHUNK],
            total: 0,
        }
    }

    /// The next message, or `None` when the stream ends cleanly between frames.
    pub async fn next<T: DeserializeOwned>(&mut self) -> Result<Option<T>, ReadError> {
        loop {
            if let Some(m) = self.buf.next_message()? {
                return Ok(Some(m));
            }
            let n = self.inner.read(&mut self.scratch).await?;
            if n == 0 {
                return match self.buf.pending() {
                    0 => Ok(None),
                    p => Err(ReadError::Truncated(p)),
                };
            }
            self.total += n as u64;
            self.buf.extend(&self.scratch[..n]);
        }
    }

    /// Bytes read from the stream so far.
    pub fn bytes_read(&self) -> u64 {
        self.total
    }

    pub fn into_inner(self) -> R {
        self.inner
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{encode_frame, ClientMessage, Direction};

    #[tokio::test]
    async fn reads_frames_then_clean_end() {
        let mut bytes = Vec::new();
        for n in 0..3 {
            bytes.extend(
                encode_frame(&ClientMessage::Ping { nonce: n }, Direction::ClientToServer).unwrap(),
            );
        }
        let mut r = FramedReader::new(&bytes[..], FrameBuffer::new(Direction::ClientToServer));
        for n in 0..3 {
            assert_eq!(
                r.next::<ClientMessage>().await.unwrap(),
                Some(ClientMessage::Ping { nonce: n })
            );
        }
        assert!(r.next::<ClientMessage>().await.unwrap().is_none());
        let cut = &bytes[..bytes.len() - 1];
        let mut r = FramedReader::new(cut, FrameBuffer::new(Direction::ClientToServer));
        r.next::<ClientMessage>().await.unwrap();
        r.next::<ClientMessage>().await.unwrap();
        assert!(matches!(
            r.next::<ClientMessage>().await,
            Err(ReadError::Truncated(_))
        ));
    }
}
