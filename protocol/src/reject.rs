//! Short stable names for edit rejection reasons and position refusals:
//! the server's metric labels and the load tester's counters use the same
//! words.

use crate::{PositionRefusal, RejectReason};

/// Metric label for a position refusal.
pub fn refusal_label(r: &PositionRefusal) -> &'static str {
    match r {
        PositionRefusal::TooFast { .. } => "too_fast",
        PositionRefusal::InsideSolid { .. } => "inside_solid",
        PositionRefusal::OutsideSpawn { .. } => "outside_spawn",
        PositionRefusal::OutOfBounds => "bounds",
        PositionRefusal::PathBlocked { .. } => "path_blocked",
        PositionRefusal::TooHigh { .. } => "too_high",
    }
}

/// Metric label for a rejection reason.
pub fn reject_label(r: &RejectReason) -> &'static str {
    use RejectReason::*;
    match r {
        NotPermitted { .. } => "not_permitted",
        RadiusTooLarge { .. } => "radius",
        PowerTooLarge { .. } => "power",
        OutOfReach { .. } => "reach",
        NoLineOfSight => "line_of_sight",
        RateLimited => "rate",
        VolumeRateLimited => "volume_rate",
        OutOfBounds => "bounds",
        ProtectedZone { .. } => "protected_zone",
        NoPosition => "no_position",
        Invalid { .. } => "invalid",
        Busy => "busy",
        RegionElsewhere { .. } => "region_elsewhere",
        NodeFull { .. } => "node_full",
    }
}
