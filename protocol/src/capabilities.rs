//! Capability bits a client sets in `Hello::capabilities`: what the server
//! may change about how it sends the world to this session.
//!
//! Bits are untrusted input: the server keeps only the bits it knows
//! ([`KNOWN`]) and ignores the rest, so a newer client can offer a bit an
//! older server of the same protocol version does not have.

/// Send every chunk as `WorldUpdate::Snapshot` (chunk codec, with hash and
/// mesh hash) instead of `Generated` or `Patched`: for clients without the
/// world generator. Deltas (or ops) still flow as usual.
pub const CAP_SNAPSHOTS: u32 = 1 << 0;

/// Send an accepted edit as one `WorldUpdate::Op` (the edit, and per held
/// chunk its new version and hashes) instead of one `Delta` per chunk, for
/// clients that run the terrain core's edits. The server still sends
/// `Delta`s for edits it cannot express as ops (`PlaceStructure`).
pub const CAP_OP_REPLAY: u32 = 1 << 1;

/// Every bit this protocol version defines.
pub const KNOWN: u32 = CAP_SNAPSHOTS | CAP_OP_REPLAY;

/// The bits of `bits` the server acts on (unknown ones dropped).
pub const fn known(bits: u32) -> u32 {
    bits & KNOWN
}

/// Whether `caps` has every bit of `cap`.
pub const fn has(caps: u32, cap: u32) -> bool {
    caps & cap == cap
}
