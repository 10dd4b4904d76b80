//! Player authentication: tokens (format and code in the `strata-auth`
//! crate, re-exported here), the secret's file, and the access list.

pub mod access;
mod secret_file;

pub use access::{AccessError, AccessList, Denied, ACCESS_BLOB, MAX_ACCESS_ENTRIES};
pub use secret_file::SecretFile;
pub use strata_auth::{
    format_duration, parse_duration, DurationError, HumanDuration, MAX_DURATION,
};
pub use strata_auth::{
    issue, issue_with_max_ttl, unix_now, validate_player_name, verify, verify_within, AuthError,
    Claims, Secret, SecretError, MAX_CLOCK_SKEW_SECS, MAX_PLAYER_NAME_LEN, MAX_TOKEN_LEN,
    MAX_TOKEN_TTL, NONCE_LEN, SECRET_LEN, TOKEN_VERSION,
};
