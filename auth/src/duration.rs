//! Human durations like `30s`, `15m`, `12h`, `7d` for `--ttl` and config.

use std::fmt;
use std::time::Duration;

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use thiserror::Error;

/// Longest duration accepted (100 years): far beyond any sane token lifetime,
/// and small enough that adding it to a unix time never overflows.
pub const MAX_DURATION: Duration = Duration::from_secs(100 * 365 * 24 * 3600);

/// Unit suffixes and their length in seconds, largest first (for formatting).
const UNITS: [(char, u64); 4] = [('d', 86_400), ('h', 3_600), ('m', 60), ('s', 1)];

/// Why a duration string was refused.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DurationError {
    #[error("empty duration; expected a number and a unit, e.g. 30s, 15m, 12h, 7d")]
    Empty,
    #[error("duration {0:?} has no unit; expected s, m, h or d (e.g. 15m)")]
    MissingUnit(String),
    #[error("duration {input:?} has unknown unit {unit:?}; expected s, m, h or d")]
    UnknownUnit { input: String, unit: String },
    #[error("duration {0:?} does not start with a whole number")]
    BadNumber(String),
    #[error("duration must be greater than zero")]
    Zero,
    #[error("duration {0:?} is longer than the 100-year cap")]
    TooLong(String),
}

/// Parses `<whole number><unit>` with unit `s`, `m`, `h` or `d`. Zero and
/// durations over [`MAX_DURATION`] are refused.
pub fn parse_duration(input: &str) -> Result<Duration, DurationError> {
    let s = input.trim();
    if s.is_empty() {
        return Err(DurationError::Empty);
    }
    let digits_end = s.find(|c: char| !c.is_ascii_digit()).unwrap_or(s.len());
    let (number, unit) = s.split_at(digits_end);
    if number.is_empty() {
        return Err(DurationError::BadNumber(input.to_owned()));
    }
    if unit.is_empty() {
        return Err(DurationError::MissingUnit(input.to_owned()));
    }
    let unit_secs = UNITS
        .iter()
        .find(|(c, _)| unit.len() == 1 && unit.starts_with(*c))
        .map(|&(_, secs)| secs)
        .ok_or_else(|| DurationError::UnknownUnit {
            input: input.to_owned(),
            unit: unit.to_owned(),
        })?;
    let too_long = || DurationError::TooLong(input.to_owned());
    // Digits only, so the sole parse failure is overflow.
    let n: u64 = number.parse().map_err(|_| too_long())?;
    let secs = n.checked_mul(unit_secs).ok_or_else(too_long)?;
    if secs == 0 {
        return Err(DurationError::Zero);
    }
    if secs > MAX_DURATION.as_secs() {
        return Err(too_long());
    }
    Ok(Duration::from_secs(secs))
}

/// Formats whole seconds with the largest unit that divides them exactly, so
/// `parse_duration(&format_duration(d)) == d` for every whole-second `d > 0`.
pub fn format_duration(d: Duration) -> String {
    let secs = d.as_secs();
    let (unit, len) = UNITS
        .iter()
        .copied()
        .find(|&(_, len)| secs % len == 0 && secs > 0)
        .unwrap_or(('s', 1));
    format!("{}{unit}", secs / len)
}

/// A [`Duration`] written in config files as a human string (`"30d"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct HumanDuration(pub Duration);

impl fmt::Display for HumanDuration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&format_duration(self.0))
    }
}

impl Serialize for HumanDuration {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&format_duration(self.0))
    }
}

impl<'de> Deserialize<'de> for HumanDuration {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        parse_duration(&text)
            .map(HumanDuration)
            .map_err(serde::de::Error::custom)
    }
}
