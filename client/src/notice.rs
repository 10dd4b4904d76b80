//! What the server tells a client about its session besides verdicts and
//! chunks, kept in a bounded queue for the game to take.

use std::collections::VecDeque;

use strata_protocol::PositionRefusal;
use strata_terrain::edit::FixedVec3;
use strata_terrain::ChunkPos;

/// Notices a client keeps untaken; past it the oldest goes.
pub const MAX_NOTICES: usize = 1024;

/// One notice from the server.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Notice {
    /// Position report `seq` was refused; the server keeps the previous
    /// position, `at` (none before the first). Not every refused report is
    /// answered (the server bounds the rate), and stale ones never are. A
    /// client whose reports go on being refused moves the player back to
    /// `at`, or the server refuses every report as it walks on.
    PositionRefused {
        seq: u32,
        reason: PositionRefusal,
        at: Option<FixedVec3>,
    },
    /// Every chunk of the view around `center` (chunk coordinates) at
    /// `radius` has arrived, except those the client forgot.
    ViewLoaded { center: ChunkPos, radius: u8 },
}

/// The untaken notices, oldest first, at most [`MAX_NOTICES`].
#[derive(Debug, Default)]
pub(crate) struct Notices(VecDeque<Notice>);

impl Notices {
    pub(crate) fn push(&mut self, n: Notice) {
        // The newest refusal says where the server holds the player now:
        // older ones would move it back further.
        if matches!(n, Notice::PositionRefused { .. }) {
            self.0
                .retain(|m| !matches!(m, Notice::PositionRefused { .. }));
        }
        if self.0.len() >= MAX_NOTICES {
            self.0.pop_front();
        }
        self.0.push_back(n);
    }

    pub(crate) fn pop(&mut self) -> Option<Notice> {
        self.0.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_protocol::PositionRefusal;

    fn refused(seq: u32) -> Notice {
        Notice::PositionRefused {
            seq,
            reason: PositionRefusal::OutOfBounds,
            at: Some(FixedVec3::from_voxels(seq as i32, 0, 0)),
        }
    }

    /// Of refusals not yet taken only the newest is kept: an older one
    /// would move the player back further than the server holds it.
    #[test]
    fn a_newer_refusal_replaces_an_older_one() {
        let mut n = Notices::default();
        let loaded = Notice::ViewLoaded {
            center: ChunkPos::new(0, 0, 0),
            radius: 2,
        };
        n.push(refused(1));
        n.push(loaded);
        n.push(refused(2));
        assert_eq!(n.pop(), Some(loaded));
        assert_eq!(n.pop(), Some(refused(2)));
        assert_eq!(n.pop(), None);
    }
}
