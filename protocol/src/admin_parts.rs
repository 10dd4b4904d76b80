//! List answers larger than one frame. A `Players` or `Access` answer whose
//! entries would pass [`LIST_PART_BYTES`] is sent as leading parts
//! (`PlayersPart`, `AccessPart`), each under that size, then the usual
//! message with the last entries. Small answers are one message, exactly as
//! in admin protocol 1's first servers. A client joins the parts
//! ([`Joiner`]); one that stops at the first message sees a prefix.

use thiserror::Error;

use crate::admin::{AccessSpec, AdminResponse, PlayerInfo};
use crate::limits::MAX_SERVER_FRAME;

/// Most estimated bytes of entries in one part: a quarter of a frame, so
/// the estimate's slack never reaches [`MAX_SERVER_FRAME`].
pub const LIST_PART_BYTES: usize = MAX_SERVER_FRAME / 4;
/// Most entries a client joins into one answer (a server's lists are
/// bounded far below: 65,536 sessions, 100,000 access entries).
pub const MAX_JOINED_ENTRIES: usize = 1 << 20;

/// Upper bounds of an entry's encoding (bincode varints: 9 bytes per u64
/// or length at most, 1 per tag).
fn player_bytes(p: &PlayerInfo) -> usize {
    p.player.len() + 48
}

fn access_entry_bytes(name: &str) -> usize {
    name.len() + 24
}

/// Cuts `items` into runs whose estimated size stays within the budget
/// (a run holds at least one entry).
fn runs<T>(items: Vec<T>, size: impl Fn(&T) -> usize) -> Vec<Vec<T>> {
    let mut out = vec![Vec::new()];
    let mut bytes = 0;
    for item in items {
        let b = size(&item);
        let last = out.last_mut().expect("one run at least");
        if !last.is_empty() && bytes + b > LIST_PART_BYTES {
            out.push(Vec::new());
            bytes = 0;
        }
        bytes += b;
        out.last_mut().expect("one run at least").push(item);
    }
    out
}

impl AdminResponse {
    /// The frames that carry this answer: itself, or leading parts and a
    /// last message of its own kind.
    pub fn into_parts(self) -> Vec<AdminResponse> {
        match self {
            AdminResponse::Players(list) => {
                let mut runs = runs(list, player_bytes);
                let last = runs.pop().unwrap_or_default();
                runs.into_iter()
                    .map(AdminResponse::PlayersPart)
                    .chain([AdminResponse::Players(last)])
                    .collect()
            }
            AdminResponse::Access(spec) => {
                // Bans first, then revocations; each part holds either.
                let bans = runs(spec.bans, |(p, _)| access_entry_bytes(p));
                let revoked = runs(spec.revoked_before, |(p, _)| access_entry_bytes(p));
                let mut parts: Vec<AccessSpec> = bans
                    .into_iter()
                    .filter(|r| !r.is_empty())
                    .map(|bans| AccessSpec {
                        bans,
                        revoked_before: Vec::new(),
                        kicked: 0,
                    })
                    .chain(
                        revoked
                            .into_iter()
                            .filter(|r| !r.is_empty())
                            .map(|r| AccessSpec {
                                bans: Vec::new(),
                                revoked_before: r,
                                kicked: 0,
                            }),
                    )
                    .collect();
                let mut last = parts.pop().unwrap_or(AccessSpec {
                    bans: Vec::new(),
                    revoked_before: Vec::new(),
                    kicked: 0,
                });
                last.kicked = spec.kicked;
                parts
                    .into_iter()
                    .map(AdminResponse::AccessPart)
                    .chain([AdminResponse::Access(last)])
                    .collect()
            }
            other => vec![other],
        }
    }
}

/// Why parts could not be joined.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum JoinError {
    #[error("{got} arrived inside a {within} answer")]
    Interleaved {
        within: &'static str,
        got: &'static str,
    },
    #[error("a {within} answer passed {MAX_JOINED_ENTRIES} entries")]
    TooLong { within: &'static str },
}

/// Joins an answer's parts, message by message.
#[derive(Debug, Default)]
pub struct Joiner {
    players: Option<Vec<PlayerInfo>>,
    access: Option<AccessSpec>,
}

fn name(r: &AdminResponse) -> &'static str {
    match r {
        AdminResponse::Players(_) => "Players",
        AdminResponse::PlayersPart(_) => "PlayersPart",
        AdminResponse::Access(_) => "Access",
        AdminResponse::AccessPart(_) => "AccessPart",
        _ => "another message",
    }
}

impl Joiner {
    /// Takes the next message: `Some` once an answer is whole.
    pub fn push(&mut self, msg: AdminResponse) -> Result<Option<AdminResponse>, JoinError> {
        if let Some(acc) = self.players.as_mut() {
            let (list, done) = match msg {
                AdminResponse::PlayersPart(l) => (l, false),
                AdminResponse::Players(l) => (l, true),
                other => return Err(interleaved("Players", &other)),
            };
            if acc.len() + list.len() > MAX_JOINED_ENTRIES {
                return Err(JoinError::TooLong { within: "Players" });
            }
            acc.extend(list);
            return Ok(
                done.then(|| AdminResponse::Players(self.players.take().unwrap_or_default()))
            );
        }
        if let Some(acc) = self.access.as_mut() {
            let (part, done) = match msg {
                AdminResponse::AccessPart(p) => (p, false),
                AdminResponse::Access(p) => (p, true),
                other => return Err(interleaved("Access", &other)),
            };
            let len = acc.bans.len() + acc.revoked_before.len();
            if len + part.bans.len() + part.revoked_before.len() > MAX_JOINED_ENTRIES {
                return Err(JoinError::TooLong { within: "Access" });
            }
            acc.bans.extend(part.bans);
            acc.revoked_before.extend(part.revoked_before);
            acc.kicked = part.kicked;
            return Ok(
                done.then(|| AdminResponse::Access(self.access.take().unwrap_or_else(empty)))
            );
        }
        match msg {
            AdminResponse::PlayersPart(l) => {
                self.players = Some(l);
                Ok(None)
            }
            AdminResponse::AccessPart(p) => {
                self.access = Some(p);
                Ok(None)
            }
            whole => Ok(Some(whole)),
        }
    }
}

fn empty() -> AccessSpec {
    AccessSpec {
        bans: Vec::new(),
        revoked_before: Vec::new(),
        kicked: 0,
    }
}

fn interleaved(within: &'static str, got: &AdminResponse) -> JoinError {
    JoinError::Interleaved {
        within,
        got: name(got),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::encode_frame;
    use crate::messages::Role;
    use crate::Direction;
    use strata_terrain::{Fixed, FixedVec3};

    fn players(n: usize) -> Vec<PlayerInfo> {
        (0..n)
            .map(|i| PlayerInfo {
                session: u64::MAX - i as u64,
                player: format!("{i:0>32}"),
                role: Role::Player,
                position: Some(FixedVec3 {
                    x: Fixed(i32::MIN),
                    y: Fixed(i32::MAX),
                    z: Fixed(-(i as i32)),
                }),
            })
            .collect()
    }

    fn join(parts: Vec<AdminResponse>) -> AdminResponse {
        let mut j = Joiner::default();
        let n = parts.len();
        for (i, p) in parts.into_iter().enumerate() {
            let whole = j.push(p).unwrap();
            assert_eq!(whole.is_some(), i + 1 == n, "whole only at the last part");
            if let Some(w) = whole {
                return w;
            }
        }
        panic!("no whole answer")
    }

    /// Every part fits a server frame, and the parts join to the answer.
    fn round_trip(answer: AdminResponse) -> usize {
        let parts = answer.clone().into_parts();
        for p in &parts {
            let frame = encode_frame(p, Direction::ServerToClient).expect("a part fits a frame");
            assert!(frame.len() <= LIST_PART_BYTES + 64, "{} bytes", frame.len());
        }
        let n = parts.len();
        assert_eq!(join(parts), answer);
        n
    }

    #[test]
    fn a_long_players_answer_goes_in_parts_that_each_fit_a_frame() {
        let all = AdminResponse::Players(players(65_536));
        assert!(
            encode_frame(&all, Direction::ServerToClient).is_err(),
            "the whole answer is over a frame"
        );
        assert!(round_trip(all) > 4);
    }

    #[test]
    fn a_long_access_answer_goes_in_parts_and_keeps_its_kicked_count() {
        let bans: Vec<_> = (0..60_000)
            .map(|i| (format!("{i:0>32}"), (i % 2 == 0).then_some(u64::MAX)))
            .collect();
        let revoked: Vec<_> = (0..40_000)
            .map(|i| (format!("r{i:0>31}"), u64::MAX))
            .collect();
        let all = AdminResponse::Access(AccessSpec {
            bans,
            revoked_before: revoked,
            kicked: 7,
        });
        assert!(encode_frame(&all, Direction::ServerToClient).is_err());
        assert!(round_trip(all) > 4);
    }

    #[test]
    fn short_answers_are_one_message_as_before() {
        for answer in [
            AdminResponse::Players(players(3)),
            AdminResponse::Players(Vec::new()),
            AdminResponse::Access(AccessSpec {
                bans: vec![("eve".into(), None)],
                revoked_before: Vec::new(),
                kicked: 1,
            }),
            AdminResponse::Access(empty()),
            AdminResponse::Kicked { sessions: 2 },
        ] {
            assert_eq!(answer.clone().into_parts(), vec![answer.clone()]);
            assert_eq!(round_trip(answer), 1);
        }
    }

    #[test]
    fn parts_of_another_answer_or_too_many_entries_are_refused() {
        let mut j = Joiner::default();
        assert_eq!(j.push(AdminResponse::PlayersPart(players(1))), Ok(None));
        assert_eq!(
            j.push(AdminResponse::Kicked { sessions: 0 }),
            Err(JoinError::Interleaved {
                within: "Players",
                got: "another message"
            })
        );
        let mut j = Joiner::default();
        j.push(AdminResponse::AccessPart(empty())).unwrap();
        assert!(matches!(
            j.push(AdminResponse::Players(Vec::new())),
            Err(JoinError::Interleaved { .. })
        ));
        let mut j = Joiner::default();
        let big = AccessSpec {
            bans: vec![(String::new(), None); MAX_JOINED_ENTRIES],
            revoked_before: Vec::new(),
            kicked: 0,
        };
        j.push(AdminResponse::AccessPart(big)).unwrap();
        assert_eq!(
            j.push(AdminResponse::AccessPart(AccessSpec {
                bans: vec![(String::new(), None)],
                ..empty()
            })),
            Err(JoinError::TooLong { within: "Access" })
        );
    }
}
