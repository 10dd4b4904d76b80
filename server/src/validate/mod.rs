//! Edit and position validation, one file per rule family.
//!
//! Every rule is a pure function of its inputs: a rejected edit or position
//! changes nothing. The sequencer runs the rules in a fixed order (see
//! `sequencer::submit`) so the first failing rule names the reason.

pub mod bounds;
pub mod caps;
pub mod config;
pub mod gravity;
pub mod line_of_sight;
pub mod permissions;
pub mod position;
pub mod ratelimit;
pub mod reach;
pub mod spawn;
pub mod sweep;
pub mod volume_weight;
pub mod zones;

pub use bounds::WorldBounds;
pub use config::ValidationConfig;
pub use position::{PositionReject, ValidatedPosition};
pub use ratelimit::TokenBucket;
pub use spawn::SpawnArea;
pub use volume_weight::VolumeWeights;
pub use zones::{Zone, ZoneError};
