//! Framing: a u32 little-endian payload length, then the payload.
//!
//! [`FrameBuffer`] is sans-I/O: feed it received bytes, take out whole
//! frames. The async reader in each peer only moves bytes into it.

use thiserror::Error;

use crate::codec::{self, CodecError, Direction};
use crate::limits::FRAME_HEADER;

#[derive(Debug, Error)]
pub enum FrameError {
    #[error("frame of {len} bytes is over the {max}-byte cap")]
    Oversized { len: usize, max: usize },
    #[error("empty frame")]
    Empty,
    #[error(transparent)]
    Codec(#[from] CodecError),
}

/// Encodes `msg` and prefixes its length.
pub fn encode_frame<T: serde::Serialize>(msg: &T, dir: Direction) -> Result<Vec<u8>, FrameError> {
    let payload = codec::encode(msg, dir)?;
    let mut out = Vec::with_capacity(FRAME_HEADER + payload.len());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Accumulates bytes of one stream and splits them into frames.
#[derive(Debug)]
pub struct FrameBuffer {
    dir: Direction,
    buf: Vec<u8>,
}

impl FrameBuffer {
    /// A buffer for frames travelling in `dir` (which sets the size cap).
    pub fn new(dir: Direction) -> Self {
        Self {
            dir,
            buf: Vec::new(),
        }
    }

    pub fn extend(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held that do not yet form a frame.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// The next whole frame's payload. An oversized or empty length is an
    /// error as soon as its header arrives, before the body is buffered.
    pub fn next_frame(&mut self) -> Result<Option<Vec<u8>>, FrameError> {
        if self.buf.len() < FRAME_HEADER {
            return Ok(None);
        }
        let len = u32::from_le_bytes([self.buf[0], self.buf[1], self.buf[2], self.buf[3]]) as usize;
        if len == 0 {
            return Err(FrameError::Empty);
        }
        if len > self.dir.cap() {
            return Err(FrameError::Oversized {
                len,
                max: self.dir.cap(),
            });
        }
        if self.buf.len() < FRAME_HEADER + len {
            return Ok(None);
        }
        let payload = self.buf[FRAME_HEADER..FRAME_HEADER + len].to_vec();
        self.buf.drain(..FRAME_HEADER + len);
        Ok(Some(payload))
    }

    /// The next whole frame, decoded as a message.
    pub fn next_message<T: serde::de::DeserializeOwned>(
        &mut self,
    ) -> Result<Option<T>, FrameError> {
        match self.next_frame()? {
            Some(p) => Ok(Some(codec::decode(&p, self.dir)?)),
            None => Ok(None),
        }
    }
}
