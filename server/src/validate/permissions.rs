//! Which edit kinds a role may use.

use std::collections::BTreeSet;

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use strata_protocol::{RejectReason, Role};
use strata_terrain::EditKind;

/// Kinds a player may use by default: everyday digging and building.
/// Boxes and structures are world-building tools reserved for admins.
pub const DEFAULT_PLAYER_KINDS: [EditKind; 4] = [
    EditKind::Mine,
    EditKind::Build,
    EditKind::Smooth,
    EditKind::Explode,
];

/// The set of kinds players may use; admins may use every kind.
/// Serialized as lowercase kind names (`"mine"`, `"fill_box"`...).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlayerKinds(pub BTreeSet<EditKind>);

impl Default for PlayerKinds {
    fn default() -> Self {
        Self(DEFAULT_PLAYER_KINDS.into_iter().collect())
    }
}

impl Serialize for PlayerKinds {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.0.iter().map(|k| k.name()))
    }
}

impl<'de> Deserialize<'de> for PlayerKinds {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let names = Vec::<String>::deserialize(d)?;
        names
            .iter()
            .map(|n| {
                EditKind::from_name(n)
                    .ok_or_else(|| serde::de::Error::custom(format!("unknown edit kind {n:?}")))
            })
            .collect::<Result<_, _>>()
            .map(Self)
    }
}

/// Rejects a kind the role may not use.
pub fn check(role: Role, kind: EditKind, player_kinds: &PlayerKinds) -> Result<(), RejectReason> {
    match role {
        Role::Admin => Ok(()),
        Role::Player if player_kinds.0.contains(&kind) => Ok(()),
        Role::Player => Err(RejectReason::NotPermitted { kind }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn players_limited_admins_not() {
        let k = PlayerKinds::default();
        assert!(check(Role::Player, EditKind::Mine, &k).is_ok());
        assert_eq!(
            check(Role::Player, EditKind::FillBox, &k),
            Err(RejectReason::NotPermitted {
                kind: EditKind::FillBox
            })
        );
        assert!(check(Role::Admin, EditKind::FillBox, &k).is_ok());
    }

    #[test]
    fn kinds_round_trip_as_names() {
        let json = serde_json::to_string(&PlayerKinds::default()).unwrap();
        assert_eq!(json, r#"["mine","explode","build","smooth"]"#);
        let back: PlayerKinds = serde_json::from_str(&json).unwrap();
        assert_eq!(back, PlayerKinds::default());
        assert!(serde_json::from_str::<PlayerKinds>(r#"["nuke"]"#).is_err());
    }
}
