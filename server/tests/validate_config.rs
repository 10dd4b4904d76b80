//! The three config sections parse from TOML, partially or fully, with
//! defaults for everything left out.

use serde::Deserialize;
use strata_protocol::Role;
use strata_server::interest::{InterestConfig, DEFAULT_VIEW_RADIUS};
use strata_server::sequencer::{SequencerConfig, DEFAULT_QUEUE_CAPACITY};
use strata_server::validate::permissions;
use strata_server::validate::ValidationConfig;
use strata_terrain::EditKind;

#[derive(Debug, Deserialize)]
struct File {
    #[serde(default)]
    sequencer: SequencerConfig,
    #[serde(default)]
    validation: ValidationConfig,
    #[serde(default)]
    interest: InterestConfig,
}

#[test]
fn sections_parse_with_defaults() {
    let f: File = toml::from_str(
        r#"
        [sequencer]
        max_edits_per_tick = 64

        [validation]
        player_kinds = ["mine", "fill_box"]
        reach = 6.5
        edit_rate = { capacity = 3, per_second = 1 }

        [interest]
        hysteresis = 4
        "#,
    )
    .unwrap();
    assert_eq!(f.sequencer.max_edits_per_tick, 64);
    assert_eq!(f.sequencer.queue_capacity, DEFAULT_QUEUE_CAPACITY);
    assert_eq!(f.validation.reach, 6.5);
    assert_eq!(f.validation.edit_rate.capacity, 3);
    assert!(
        permissions::check(Role::Player, EditKind::FillBox, &f.validation.player_kinds).is_ok()
    );
    assert!(permissions::check(Role::Player, EditKind::Build, &f.validation.player_kinds).is_err());
    assert_eq!(f.interest.view_radius, DEFAULT_VIEW_RADIUS);
    assert_eq!(f.interest.hysteresis, 4);

    let empty: File = toml::from_str("").unwrap();
    assert_eq!(empty.validation, ValidationConfig::default());
    let back = toml::to_string(&ValidationConfig::default()).unwrap();
    assert_eq!(
        toml::from_str::<ValidationConfig>(&back).unwrap(),
        ValidationConfig::default()
    );
    assert!(toml::from_str::<File>("[validation]\nplayer_kinds = [\"nuke\"]").is_err());
}
