//! Unsigned LEB128 varints, capped at three bytes.

use super::DeltaError;

/// Longest varint the format allows: 3 bytes hold 21 bits, enough for every
/// offset (at most 65536) and body length (at most 131072).
pub const MAX_VARINT_BYTES: usize = 3;

pub(super) fn write_varint(out: &mut Vec<u8>, mut v: usize) {
    while v >= 0x80 {
        out.push((v as u8 & 0x7f) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Reads a varint at `*at`, advancing it; values above `max` are refused.
pub(super) fn read_varint(bytes: &[u8], at: &mut usize, max: usize) -> Result<usize, DeltaError> {
    let mut v = 0usize;
    for k in 0..MAX_VARINT_BYTES {
        let Some(&b) = bytes.get(*at) else {
            return Err(DeltaError::Truncated("varint cut short"));
        };
        *at += 1;
        v |= ((b & 0x7f) as usize) << (7 * k);
        if b & 0x80 == 0 {
            if v > max {
                return Err(DeltaError::VarintTooLarge { value: v, max });
            }
            return Ok(v);
        }
    }
    Err(DeltaError::BadVarint("longer than 3 bytes"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_at_the_limits() {
        for v in [0usize, 1, 127, 128, 16383, 16384, 65535, 65536, 131072] {
            let mut buf = Vec::new();
            write_varint(&mut buf, v);
            assert!(buf.len() <= MAX_VARINT_BYTES);
            let mut at = 0;
            assert_eq!(read_varint(&buf, &mut at, 131072), Ok(v));
            assert_eq!(at, buf.len());
        }
    }

    #[test]
    fn golden_bytes() {
        let mut buf = Vec::new();
        write_varint(&mut buf, 32968);
        assert_eq!(buf, [0xc8, 0x81, 0x02]);
    }

    #[test]
    fn malformed_varints_are_refused() {
        let mut at = 0;
        assert!(matches!(
            read_varint(&[0x80], &mut at, 10),
            Err(DeltaError::Truncated(_))
        ));
        let mut at = 0;
        let e = read_varint(&[0x80, 0x80, 0x80, 0x01], &mut at, 1 << 20);
        assert!(matches!(e, Err(DeltaError::BadVarint(_))));
        let mut at = 0;
        assert_eq!(
            read_varint(&[0x0b], &mut at, 10),
            Err(DeltaError::VarintTooLarge { value: 11, max: 10 })
        );
    }
}
