//! Version constants. A client whose `protocol_version` differs is refused.

/// ALPN protocol id for QUIC connections.
pub const ALPN: &[u8] = b"strata/1";
/// Wire protocol version carried in `Hello` (2 added `WorldUpdate::Patched`,
/// 3 added `Welcome::start`, 4 added `Hello::capabilities`,
/// `WorldUpdate::Op`, `PositionRefused`, `Forget` and `InterestComplete`,
/// 5 added `RegionElsewhere`, 6 added `RegionOwners`, `Arrive` and
/// `Arrived`, 7 added `RejectReason::NodeFull`, 8 added
/// `TicketRefusal::NotClustered` and `RegionOwners::node`; tickets are
/// bound to their world; 9 added `PositionRefused::at` and
/// `PositionRefusal::PathBlocked`, 10 added `PositionRefusal::TooHigh`,
/// 11 made a sphere edit's box open: voxels a whole radius away along an
/// axis are outside it, which decides `OutOfBounds`, the volume charged
/// and the chunks an op replay reads).
pub const PROTOCOL_VERSION: u32 = 11;
