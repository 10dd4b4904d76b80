//! The sled store's record of a player's last position.

use strata_terrain::edit::{Fixed, FixedVec3};

use super::types::StoredPosition;

/// A player's record: feet x, y, z (i32 each), then `known_ms` (u64), big
/// endian. Records of 12 bytes (no time) were written before the time was
/// kept, and read with `known_ms` 0.
pub(super) fn encode_position(p: &StoredPosition) -> [u8; 20] {
    let mut v = [0u8; 20];
    for (i, c) in [p.feet.x, p.feet.y, p.feet.z].iter().enumerate() {
        v[i * 4..i * 4 + 4].copy_from_slice(&c.0.to_be_bytes());
    }
    v[12..].copy_from_slice(&p.known_ms.to_be_bytes());
    v
}

pub(super) fn decode_position(v: &[u8]) -> Option<StoredPosition> {
    if v.len() != 12 && v.len() != 20 {
        return None;
    }
    let c = |i: usize| Some(Fixed(i32::from_be_bytes(v.get(i..i + 4)?.try_into().ok()?)));
    let feet = FixedVec3::new(c(0)?, c(4)?, c(8)?);
    let known_ms = match v.get(12..20) {
        Some(t) => u64::from_be_bytes(t.try_into().ok()?),
        None => 0,
    };
    Some(StoredPosition { feet, known_ms })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_old_ones_read_without_a_time() {
        let p = StoredPosition {
            feet: FixedVec3::new(Fixed(-5), Fixed(1 << 20), Fixed(i32::MIN)),
            known_ms: 1_790_000_000_123,
        };
        assert_eq!(decode_position(&encode_position(&p)), Some(p));
        let old = &encode_position(&p)[..12];
        assert_eq!(
            decode_position(old),
            Some(StoredPosition { known_ms: 0, ..p })
        );
        for bad in [&[][..], &[0u8; 11], &[0u8; 13], &[0u8; 21]] {
            assert_eq!(decode_position(bad), None, "{} bytes", bad.len());
        }
    }
}
