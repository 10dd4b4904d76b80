//! `--duration` values: `500ms`, or anything `strata_auth::parse_duration`
//! accepts (`30s`, `2m`, `1h`).

use std::time::Duration;

use strata_auth::{parse_duration, DurationError};
use thiserror::Error;

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum RunDurationError {
    #[error("duration {0:?}: milliseconds must be a whole number above zero")]
    BadMillis(String),
    #[error(transparent)]
    Other(#[from] DurationError),
}

/// Parses a run length such as `500ms`, `30s` or `2m`.
pub fn parse_run_duration(s: &str) -> Result<Duration, RunDurationError> {
    match s.trim().strip_suffix("ms") {
        Some(n) => match n.parse::<u64>() {
            Ok(ms) if ms > 0 => Ok(Duration::from_millis(ms)),
            _ => Err(RunDurationError::BadMillis(s.to_string())),
        },
        None => Ok(parse_duration(s)?),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn millis_seconds_minutes_and_junk() {
        assert_eq!(parse_run_duration("500ms"), Ok(Duration::from_millis(500)));
        assert_eq!(parse_run_duration("30s"), Ok(Duration::from_secs(30)));
        assert_eq!(parse_run_duration("2m"), Ok(Duration::from_secs(120)));
        assert!(parse_run_duration("0ms").is_err());
        assert!(parse_run_duration("xms").is_err());
        assert!(parse_run_duration("30").is_err());
        assert!(parse_run_duration("3w").is_err());
    }
}
