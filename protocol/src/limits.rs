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
/// Most chunk versions one `EditAccepted` lists. Every edit spans at most
/// 130 voxels on an axis (a 64-voxel radius, a 128-voxel box or structure,
/// plus a smoothing margin), so it writes at most 6 x 6 x 6 chunks: a
/// server listing more is broken or hostile.
pub const MAX_EDIT_CHANGES: usize = 512;
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

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::edit::structure::MAX_STRUCTURE_EDGE;
    use strata_terrain::edit::{MAX_BOX_EDGE, MAX_RADIUS};

    /// The largest edit of any kind, placed anywhere, writes no more chunks
    /// than an `EditAccepted` may list.
    #[test]
    fn the_largest_edit_fits_an_accepted_list() {
        let side = strata_terrain::pos::CHUNK_SIZE as i64;
        // A sphere's box: both radii, the voxel at the centre, a rounding
        // voxel each side, and Smooth's read margin of 1 each side.
        let one = strata_terrain::edit::fixed::ONE as i64;
        let sphere = 2 * ((MAX_RADIUS.0 as i64 + one - 1) / one) + 1 + 2 + 2;
        let edge = sphere
            .max(MAX_BOX_EDGE as i64 + 1)
            .max(MAX_STRUCTURE_EDGE as i64);
        // Misaligned, a span of `edge` voxels touches one chunk more.
        let per_axis = (edge + side - 2) / side + 1;
        assert!(
            (per_axis.pow(3) as usize) <= MAX_EDIT_CHANGES,
            "{per_axis} per axis"
        );
    }
}
