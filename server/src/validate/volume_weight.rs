//! What an edit costs from a player's volume bucket: its box's voxels
//! times its kind's weight, so a kind that does more work per voxel
//! drains the bucket faster.

use serde::{Deserialize, Serialize};
use strata_terrain::EditKind;

/// Largest weight `[validation.volume_weight]` accepts for a kind.
pub const MAX_VOLUME_WEIGHT: u64 = 1_000;

/// Smooth's default weight: it reads 27 voxels for each it writes and
/// costs about 3× Mine per voxel of its box (BENCHMARKS, session 54).
pub const DEFAULT_SMOOTH_VOLUME_WEIGHT: u64 = 3;

/// Voxels of the volume bucket charged per voxel of an edit's box, by kind
/// (`[validation.volume_weight]`, lowercase kind names; 1 unless given).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VolumeWeights {
    pub mine: u64,
    pub explode: u64,
    pub build: u64,
    pub fill_box: u64,
    pub clear_box: u64,
    pub place_structure: u64,
    pub smooth: u64,
}

impl Default for VolumeWeights {
    fn default() -> Self {
        Self {
            mine: 1,
            explode: 1,
            build: 1,
            fill_box: 1,
            clear_box: 1,
            place_structure: 1,
            smooth: DEFAULT_SMOOTH_VOLUME_WEIGHT,
        }
    }
}

impl VolumeWeights {
    /// The weight of one kind.
    pub fn of(&self, kind: EditKind) -> u64 {
        match kind {
            EditKind::Mine => self.mine,
            EditKind::Explode => self.explode,
            EditKind::Build => self.build,
            EditKind::FillBox => self.fill_box,
            EditKind::ClearBox => self.clear_box,
            EditKind::PlaceStructure => self.place_structure,
            EditKind::Smooth => self.smooth,
        }
    }

    /// What an edit of `kind` whose box holds `voxels` takes from a bucket
    /// of `capacity`: capped at the capacity, so any legal edit can pass.
    pub fn charge(&self, kind: EditKind, voxels: u64, capacity: u64) -> u64 {
        voxels.saturating_mul(self.of(kind)).min(capacity)
    }

    /// Each kind's weight with its config key, for range checks.
    pub fn fields(&self) -> [(&'static str, u64); 7] {
        EditKind::ALL.map(|k| (key(k), self.of(k)))
    }
}

/// A kind's weight's full config key.
const fn key(kind: EditKind) -> &'static str {
    match kind {
        EditKind::Mine => "validation.volume_weight.mine",
        EditKind::Explode => "validation.volume_weight.explode",
        EditKind::Build => "validation.volume_weight.build",
        EditKind::FillBox => "validation.volume_weight.fill_box",
        EditKind::ClearBox => "validation.volume_weight.clear_box",
        EditKind::PlaceStructure => "validation.volume_weight.place_structure",
        EditKind::Smooth => "validation.volume_weight.smooth",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_kind_is_charged_its_weight_per_voxel_up_to_the_capacity() {
        let w = VolumeWeights::default();
        assert_eq!(w.charge(EditKind::Mine, 27, 100), 27);
        assert_eq!(w.charge(EditKind::Smooth, 27, 100), 81);
        assert_eq!(w.charge(EditKind::Smooth, 125, 100), 100);
        assert_eq!(w.charge(EditKind::Smooth, u64::MAX, 100), 100);
    }

    #[test]
    fn weights_are_read_by_kind_name_and_default_to_one() {
        let w: VolumeWeights = toml::from_str("explode = 2").unwrap();
        assert_eq!(w.of(EditKind::Explode), 2);
        assert_eq!(w.of(EditKind::Mine), 1);
        assert_eq!(w.of(EditKind::Smooth), DEFAULT_SMOOTH_VOLUME_WEIGHT);
        assert!(toml::from_str::<VolumeWeights>("dig = 2").is_err());
        // Every key names its kind as the TOML table spells it.
        for (k, (key, weight)) in EditKind::ALL.into_iter().zip(w.fields()) {
            assert_eq!(key, format!("validation.volume_weight.{}", k.name()));
            assert_eq!(weight, w.of(k));
        }
    }
}
