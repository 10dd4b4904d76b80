//! Strata's wire protocol. Filled by the server issue (#4): messages,
//! the bincode codec and framing. Nothing about game rules lives here.

/// ALPN protocol id for QUIC connections.
pub const ALPN: &[u8] = b"strata/1";
