//! Who may not join although their token verifies: banned players (until a
//! time, or for good) and revoked tokens (every token of a player issued at
//! or before a time). Checked at every Hello, players' and admins' (and
//! by admin sessions again before each request); stored in the world's
//! store as the blob [`ACCESS_BLOB`] (JSON), so bans and revocations
//! survive restarts and work on a stopped server too. Every server reads it
//! again from the store periodically, so a cluster's nodes share it.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use thiserror::Error;

use strata_auth::{Claims, MAX_CLOCK_SKEW_SECS, MAX_TOKEN_TTL};

/// Blob name under which the access list is stored.
pub const ACCESS_BLOB: &str = "access";
/// Most bans plus revocations kept (an operator's list; far above need).
pub const MAX_ACCESS_ENTRIES: usize = 100_000;

/// Bans and revocations by player name.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccessList {
    /// Player → unix second the ban ends (`None`: never).
    pub bans: BTreeMap<String, Option<u64>>,
    /// Player → unix second: tokens issued at or before it are refused.
    pub revoked_before: BTreeMap<String, u64>,
}

/// Why a verified token may not join.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum Denied {
    #[error("{player} is banned{}", until.map(|u| format!(" until unix time {u}")).unwrap_or_default())]
    Banned { player: String, until: Option<u64> },
    #[error(
        "{player}'s tokens issued at or before unix time {before} were revoked; ask for a new one after then"
    )]
    Revoked { player: String, before: u64 },
}

/// Why the list could not be changed or read.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AccessError {
    #[error("the access list holds {MAX_ACCESS_ENTRIES} entries, its limit")]
    Full,
    /// No token could name this player, so there is nothing to ban.
    #[error("not a player name: {0}")]
    BadName(String),
    #[error("the stored access list does not parse: {0}")]
    Corrupt(String),
}

impl AccessList {
    /// The list stored as `bytes` (none stored: empty).
    pub fn from_blob(bytes: Option<&[u8]>) -> Result<Self, AccessError> {
        match bytes {
            None => Ok(Self::default()),
            Some(b) => serde_json::from_slice(b).map_err(|e| AccessError::Corrupt(e.to_string())),
        }
    }

    pub fn to_blob(&self) -> Vec<u8> {
        serde_json::to_vec(self).expect("maps of strings and numbers serialize")
    }

    /// Whether `claims` may join at unix second `now`.
    pub fn check(&self, claims: &Claims, now: u64) -> Result<(), Denied> {
        if let Some(until) = self.bans.get(&claims.player) {
            if until.is_none_or(|u| now < u) {
                return Err(Denied::Banned {
                    player: claims.player.clone(),
                    until: *until,
                });
            }
        }
        match self.revoked_before.get(&claims.player) {
            Some(&before) if claims.issued_at <= before => Err(Denied::Revoked {
                player: claims.player.clone(),
                before,
            }),
            _ => Ok(()),
        }
    }

    /// Bans `player` until `until` (`None`: for good), replacing any ban.
    /// What no longer refuses anyone is dropped first ([`Self::prune`]).
    pub fn ban(&mut self, player: &str, until: Option<u64>, now: u64) -> Result<(), AccessError> {
        valid_name(player)?;
        self.prune(now);
        if !self.bans.contains_key(player) && self.len() >= MAX_ACCESS_ENTRIES {
            return Err(AccessError::Full);
        }
        self.bans.insert(player.to_string(), until);
        Ok(())
    }

    /// Lifts a ban; whether there was one.
    pub fn unban(&mut self, player: &str) -> bool {
        self.bans.remove(player).is_some()
    }

    /// Refuses every token of `player` issued at or before `now` plus
    /// [`MAX_CLOCK_SKEW_SECS`]: verification accepts an `issued_at` that far
    /// ahead, so a token minted on a host whose clock runs fast is refused
    /// too. New tokens for the player are refused until the server's clock
    /// passes that time. A later revocation never shortens an earlier one.
    pub fn revoke(&mut self, player: &str, now: u64) -> Result<(), AccessError> {
        valid_name(player)?;
        self.prune(now);
        if !self.revoked_before.contains_key(player) && self.len() >= MAX_ACCESS_ENTRIES {
            return Err(AccessError::Full);
        }
        let before = now.saturating_add(MAX_CLOCK_SKEW_SECS);
        let entry = self.revoked_before.entry(player.to_string()).or_default();
        *entry = (*entry).max(before);
        Ok(())
    }

    /// Drops what no longer refuses anyone at `now`: bans that ended, and
    /// revocations older than the longest life a server gives a token
    /// ([`MAX_TOKEN_TTL`] from its `issued_at`, `strata_auth::verify_within`):
    /// every token they cover has expired. Else the list only grows, until
    /// it is full and refuses every ban.
    fn prune(&mut self, now: u64) {
        self.bans.retain(|_, u| u.is_none_or(|u| u > now));
        let life = MAX_TOKEN_TTL.as_secs();
        self.revoked_before
            .retain(|_, before| before.saturating_add(life) > now);
    }

    fn len(&self) -> usize {
        self.bans.len() + self.revoked_before.len()
    }
}

/// A name a token may carry (`strata_auth::validate_player_name`): the
/// list's entries stay as short as player names.
fn valid_name(player: &str) -> Result<(), AccessError> {
    strata_auth::validate_player_name(player).map_err(|e| AccessError::BadName(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_protocol::Role;

    fn claims(player: &str, issued_at: u64) -> Claims {
        Claims {
            player: player.into(),
            role: Role::Player,
            issued_at,
            expires_at: issued_at + 3600,
            nonce: [0; strata_auth::NONCE_LEN],
        }
    }

    #[test]
    fn only_player_names_are_banned_or_revoked() {
        let mut a = AccessList::default();
        let long = "a".repeat(strata_auth::MAX_PLAYER_NAME_LEN + 1);
        for bad in [long.as_str(), "", "two words", "ève"] {
            assert!(matches!(a.ban(bad, None, 0), Err(AccessError::BadName(_))));
            assert!(matches!(a.revoke(bad, 0), Err(AccessError::BadName(_))));
        }
        assert_eq!(a.len(), 0, "nothing was added");
        a.ban(&"a".repeat(strata_auth::MAX_PLAYER_NAME_LEN), None, 0)
            .unwrap();
    }

    #[test]
    fn a_revocation_covers_tokens_minted_by_a_fast_clock() {
        let mut a = AccessList::default();
        let now = 10_000;
        a.revoke("eve", now).unwrap();
        let fast = now + MAX_CLOCK_SKEW_SECS;
        assert_eq!(a.revoked_before["eve"], fast);
        // As far ahead as verification accepts: refused at once.
        assert!(matches!(
            a.check(&claims("eve", fast), now),
            Err(Denied::Revoked { .. })
        ));
        assert_eq!(a.check(&claims("eve", fast + 1), now + 1), Ok(()));
        // An earlier revocation time (a clock stepped back) keeps the later one.
        a.revoke("eve", now - 60).unwrap();
        assert_eq!(a.revoked_before["eve"], fast);
        // Once every token it covers has expired, the next change drops it.
        let later = fast + MAX_TOKEN_TTL.as_secs();
        a.revoke("bob", later - 1).unwrap();
        assert!(a.revoked_before.contains_key("eve"), "still covers tokens");
        a.revoke("bob", later).unwrap();
        assert!(!a.revoked_before.contains_key("eve"));
        assert!(a.revoked_before.contains_key("bob"));
        // Near the end of time it saturates instead of wrapping.
        a.revoke("max", u64::MAX - 1).unwrap();
        assert_eq!(a.revoked_before["max"], u64::MAX);
    }

    #[test]
    fn bans_end_when_they_say_and_revocations_spare_newer_tokens() {
        let mut a = AccessList::default();
        a.ban("eve", Some(1000), 0).unwrap();
        a.ban("mal", None, 0).unwrap();
        a.revoke("bob", 500 - MAX_CLOCK_SKEW_SECS).unwrap();
        assert!(matches!(
            a.check(&claims("eve", 10), 999),
            Err(Denied::Banned { .. })
        ));
        assert_eq!(a.check(&claims("eve", 10), 1000), Ok(()));
        assert!(a.check(&claims("mal", 10), u64::MAX - 1).is_err());
        assert!(matches!(
            a.check(&claims("bob", 500), 600),
            Err(Denied::Revoked { .. })
        ));
        assert_eq!(a.check(&claims("bob", 501), 600), Ok(()));
        assert_eq!(a.check(&claims("ana", 1), 600), Ok(()));
        assert!(a.unban("mal") && !a.unban("mal"));
        assert_eq!(a.check(&claims("mal", 10), 600), Ok(()));
        // Round trip through the stored form; an expired ban is dropped on the next ban.
        let back = AccessList::from_blob(Some(&a.to_blob())).unwrap();
        assert_eq!(back, a);
        a.ban("zed", None, 2000).unwrap();
        assert!(!a.bans.contains_key("eve"));
        assert_eq!(AccessList::from_blob(None).unwrap(), AccessList::default());
        assert!(AccessList::from_blob(Some(b"{nope")).is_err());
    }
}
