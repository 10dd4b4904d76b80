//! Short stable names for edit rejection reasons: the server's metric
//! labels and the load tester's counters use the same words.

use crate::RejectReason;

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
