//! The sled store's records of a player's last position: the feet in
//! tree `players` (x, y, z: i32 each, big endian, 12 bytes, the layout
//! every build reads), and when the player was last seen there in tree
//! `player_times` (u64 ms, big endian), which builds before it ignore, so
//! they still open the store. A player with no time reads with 0.

use strata_terrain::edit::{Fixed, FixedVec3};

use super::types::StoredPosition;

/// Tree of the times players were last seen at their stored positions.
pub const TREE_PLAYER_TIMES: &str = "player_times";

pub(super) fn encode_feet(p: &StoredPosition) -> [u8; 12] {
    let mut v = [0u8; 12];
    for (i, c) in [p.feet.x, p.feet.y, p.feet.z].iter().enumerate() {
        v[i * 4..i * 4 + 4].copy_from_slice(&c.0.to_be_bytes());
    }
    v
}

/// A position from its feet record and its time record, if any. Feet
/// records of 20 bytes (the time inside, written by one development build)
/// read too.
pub(super) fn decode_position(feet: &[u8], time: Option<&[u8]>) -> Option<StoredPosition> {
    if feet.len() != 12 && feet.len() != 20 {
        return None;
    }
    let c = |i: usize| {
        Some(Fixed(i32::from_be_bytes(
            feet.get(i..i + 4)?.try_into().ok()?,
        )))
    };
    let at = FixedVec3::new(c(0)?, c(4)?, c(8)?);
    let known_ms = match (time, feet.get(12..20)) {
        (Some(t), _) | (None, Some(t)) => u64::from_be_bytes(t.try_into().ok()?),
        (None, None) => 0,
    };
    Some(StoredPosition { feet: at, known_ms })
}

/// The `max` positions known most recently of those offered (ties by
/// name), holding no more than `max` at once: a store read at start
/// costs memory for what the server remembers, not for every player
/// ever saved.
pub(super) struct Newest {
    max: usize,
    /// The worst kept on top: oldest known, then last by name.
    heap: std::collections::BinaryHeap<Ranked>,
}

struct Ranked(String, StoredPosition);

impl Ranked {
    /// Greater is worse: known longer ago, then later by name.
    fn key(&self) -> (std::cmp::Reverse<u64>, &str) {
        (std::cmp::Reverse(self.1.known_ms), &self.0)
    }
}

impl PartialEq for Ranked {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}

impl Eq for Ranked {}

impl PartialOrd for Ranked {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Ranked {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.key().cmp(&other.key())
    }
}

impl Newest {
    pub(super) fn new(max: usize) -> Self {
        Self {
            max,
            heap: std::collections::BinaryHeap::new(),
        }
    }

    pub(super) fn offer(&mut self, name: String, pos: StoredPosition) {
        if self.max == 0 {
            return;
        }
        self.heap.push(Ranked(name, pos));
        if self.heap.len() > self.max {
            self.heap.pop();
        }
    }

    /// Newest first, ties by name.
    pub(super) fn into_sorted(self) -> Vec<(String, StoredPosition)> {
        self.heap
            .into_sorted_vec()
            .into_iter()
            .map(|Ranked(name, pos)| (name, pos))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_ones_without_a_time_read_as_0() {
        let p = StoredPosition {
            feet: FixedVec3::new(Fixed(-5), Fixed(1 << 20), Fixed(i32::MIN)),
            known_ms: 1_790_000_000_123,
        };
        let time = p.known_ms.to_be_bytes();
        assert_eq!(decode_position(&encode_feet(&p), Some(&time)), Some(p));
        assert_eq!(
            decode_position(&encode_feet(&p), None),
            Some(StoredPosition { known_ms: 0, ..p })
        );
        let mut inline = encode_feet(&p).to_vec();
        inline.extend_from_slice(&time);
        assert_eq!(decode_position(&inline, None), Some(p));
        for bad in [&[][..], &[0u8; 11], &[0u8; 13], &[0u8; 21]] {
            assert_eq!(decode_position(bad, None), None, "{} bytes", bad.len());
        }
        assert_eq!(decode_position(&encode_feet(&p), Some(&[1, 2])), None);
    }
}
