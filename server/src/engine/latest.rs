//! One pending position per session. A datagram's update replaces any
//! older one (lower seq) the engine has not taken yet; a late datagram
//! older than the pending one is dropped, so reordering on the network
//! cannot make the engine see an old position after a newer one was sent.
//! Only an update that found
//! the slot empty queues a command: a flood of datagrams costs the engine's
//! queue one slot per session, and the engine sees only the newest.

use std::sync::Mutex;

use strata_protocol::PositionUpdate;

#[derive(Debug, Default)]
pub struct LatestPosition(Mutex<Option<PositionUpdate>>);

impl LatestPosition {
    /// Stores `update` over any pending one with a lower seq (one with a
    /// higher seq stays). True when the engine must be told (nothing was
    /// pending, so no command is queued for this slot).
    pub fn offer(&self, update: PositionUpdate) -> bool {
        let mut slot = self.lock();
        match slot.as_ref() {
            None => {
                *slot = Some(update);
                true
            }
            Some(pending) => {
                if update.seq > pending.seq {
                    *slot = Some(update);
                }
                false
            }
        }
    }

    /// The pending update, leaving the slot empty.
    pub fn take(&self) -> Option<PositionUpdate> {
        self.lock().take()
    }

    /// Drops the pending update, when its command could not be queued (the
    /// next datagram tries again).
    pub fn clear(&self) {
        self.lock().take();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Option<PositionUpdate>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::edit::FixedVec3;

    fn at(seq: u32) -> PositionUpdate {
        PositionUpdate {
            seq,
            pos: FixedVec3::from_voxels(seq as i32, 0, 0),
        }
    }

    #[test]
    fn only_an_update_into_an_empty_slot_asks_for_a_command() {
        let slot = LatestPosition::default();
        assert!(slot.offer(at(1)));
        assert!(!slot.offer(at(2)));
        assert!(!slot.offer(at(3)));
        assert_eq!(slot.take().map(|u| u.seq), Some(3));
        assert_eq!(slot.take(), None);
        assert!(slot.offer(at(4)));
        slot.clear();
        assert!(slot.offer(at(5)), "a cleared slot asks again");
    }

    #[test]
    fn a_late_older_datagram_does_not_replace_a_newer_pending_one() {
        let slot = LatestPosition::default();
        assert!(slot.offer(at(7)));
        assert!(!slot.offer(at(6)));
        assert!(!slot.offer(at(7)));
        assert_eq!(slot.take().map(|u| u.seq), Some(7));
    }
}
