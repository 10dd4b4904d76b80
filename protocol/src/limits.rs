//! Frame and message size caps, fixed by the protocol.

/// Largest frame payload a client may send (16 KiB).
pub const MAX_CLIENT_FRAME: usize = 16 * 1024;
/// Largest frame payload the server may send (1 MiB).
pub const MAX_SERVER_FRAME: usize = 1024 * 1024;
/// Largest datagram payload: QUIC's 1200-byte initial MTU minus headers.
pub const MAX_DATAGRAM: usize = 1100;
/// Bytes of the frame length prefix.
pub const FRAME_HEADER: usize = 4;
/// Most chunks in one `UnsubscribedMany` (12 bytes each: 48 KiB at most);
/// a larger re-centring is split over several.
pub const MAX_UNSUBSCRIBED_PER_UPDATE: usize = 4096;
/// Most chunks in one `Forget` (at most 15 bytes each, so a full one
/// still fits a client frame); a larger one is refused as a whole.
pub const MAX_FORGET_CHUNKS: usize = 1024;
/// Most regions in one `RegionOwners` (a view of radius 32 chunks spans at
/// most 10 x 10 regions of 8 chunks).
pub const MAX_REGION_OWNERS: usize = 256;
/// Longest node id a `RegionOwners` names (`[cluster] node_id`'s limit):
/// a client keeps none longer.
pub const MAX_NODE_ID_BYTES: usize = 64;
/// How long an `Arrive` ticket is accepted after it was issued (ms).
pub const TICKET_TTL_MS: u64 = 30_000;
/// How far in the future a ticket's `issued_ms` may be (clock skew, ms).
pub const TICKET_SKEW_MS: u64 = 2_000;
