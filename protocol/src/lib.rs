//! Strata's wire protocol: messages, the codec, framing and version
//! constants. Nothing about game rules lives here. PROTOCOL.md documents the
//! byte layout for clients in other languages.

pub mod ack;
pub mod admin;
pub mod admin_parts;
pub mod capabilities;
mod cautious;
pub mod codec;
pub mod frame;
pub mod limits;
pub mod messages;
mod reject;
pub mod version;

pub use capabilities::{CAP_OP_REPLAY, CAP_SNAPSHOTS};
pub use codec::{decode, encode, CodecError, Direction};
pub use frame::{encode_frame, FrameBuffer, FrameError};
pub use messages::*;
pub use reject::{refusal_label, reject_label};
pub use version::{ALPN, PROTOCOL_VERSION};
#[cfg(feature = "quic")]
pub mod client_tls;
#[cfg(feature = "tokio")]
pub mod io;
