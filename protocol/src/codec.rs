//! The one place that knows the message encoding: bincode 2.0.1, standard
//! config (little-endian, varint integers), with an explicit size limit.

use bincode::config::{self, Configuration, Limit, LittleEndian, Varint};
use serde::de::DeserializeOwned;
use serde::Serialize;
use thiserror::Error;

use crate::limits::{MAX_CLIENT_FRAME, MAX_SERVER_FRAME};

type Config<const N: usize> = Configuration<LittleEndian, Varint, Limit<N>>;

const fn cfg<const N: usize>() -> Config<N> {
    config::standard().with_limit::<N>()
}

#[derive(Debug, Error)]
pub enum CodecError {
    #[error("message does not encode: {0}")]
    Encode(String),
    #[error("message does not decode: {0}")]
    Decode(String),
    #[error("message has {0} trailing bytes")]
    Trailing(usize),
    #[error("encoded message is {len} bytes, over the {max}-byte cap")]
    TooLarge { len: usize, max: usize },
}

/// Direction of a message, which sets its size cap.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    ClientToServer,
    ServerToClient,
}

impl Direction {
    pub const fn cap(self) -> usize {
        match self {
            Direction::ClientToServer => MAX_CLIENT_FRAME,
            Direction::ServerToClient => MAX_SERVER_FRAME,
        }
    }
}

/// Encodes a message for `dir`, refusing one over the direction's cap.
pub fn encode<T: Serialize>(msg: &T, dir: Direction) -> Result<Vec<u8>, CodecError> {
    let bytes = match dir {
        Direction::ClientToServer => bincode::serde::encode_to_vec(msg, cfg::<MAX_CLIENT_FRAME>()),
        Direction::ServerToClient => bincode::serde::encode_to_vec(msg, cfg::<MAX_SERVER_FRAME>()),
    }
    .map_err(|e| CodecError::Encode(e.to_string()))?;
    if bytes.len() > dir.cap() {
        return Err(CodecError::TooLarge {
            len: bytes.len(),
            max: dir.cap(),
        });
    }
    Ok(bytes)
}

/// Decodes exactly one message; trailing bytes are an error.
pub fn decode<T: DeserializeOwned>(bytes: &[u8], dir: Direction) -> Result<T, CodecError> {
    if bytes.len() > dir.cap() {
        return Err(CodecError::TooLarge {
            len: bytes.len(),
            max: dir.cap(),
        });
    }
    let (msg, used) = match dir {
        Direction::ClientToServer => {
            bincode::serde::decode_from_slice(bytes, cfg::<MAX_CLIENT_FRAME>())
        }
        Direction::ServerToClient => {
            bincode::serde::decode_from_slice(bytes, cfg::<MAX_SERVER_FRAME>())
        }
    }
    .map_err(|e| CodecError::Decode(e.to_string()))?;
    if used != bytes.len() {
        return Err(CodecError::Trailing(bytes.len() - used));
    }
    Ok(msg)
}
