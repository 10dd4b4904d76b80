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
    /// Bytes of `buf` already taken as frames. Moving the rest down after
    /// every frame copied a 16 KiB read of small frames hundreds of times;
    /// it moves only once the taken part is at least half of `buf`.
    taken: usize,
}

impl FrameBuffer {
    /// A buffer for frames travelling in `dir` (which sets the size cap).
    pub fn new(dir: Direction) -> Self {
        Self {
            dir,
            buf: Vec::new(),
            taken: 0,
        }
    }

    pub fn extend(&mut self, bytes: &[u8]) {
        if self.taken > 0 && self.taken * 2 >= self.buf.len() {
            self.buf.drain(..self.taken);
            self.taken = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held that do not yet form a frame.
    pub fn pending(&self) -> usize {
        self.buf.len() - self.taken
    }

    /// The next whole frame's payload. An oversized or empty length is an
    /// error as soon as its header arrives, before the body is buffered.
    pub fn next_frame(&mut self) -> Result<Option<Vec<u8>>, FrameError> {
        let rest = &self.buf[self.taken..];
        if rest.len() < FRAME_HEADER {
            return Ok(None);
        }
        let len = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]) as usize;
        if len == 0 {
            return Err(FrameError::Empty);
        }
        if len > self.dir.cap() {
            return Err(FrameError::Oversized {
                len,
                max: self.dir.cap(),
            });
        }
        if rest.len() < FRAME_HEADER + len {
            return Ok(None);
        }
        let payload = rest[FRAME_HEADER..FRAME_HEADER + len].to_vec();
        self.taken += FRAME_HEADER + len;
        if self.taken == self.buf.len() {
            self.buf.clear();
            self.taken = 0;
        }
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
