//! Strata's bearer tokens: HMAC-signed, minted by `strata-admin token
//! issue` (or a studio's own service, with this crate) and checked by the
//! server on `Hello`. No server code, no file formats beyond the secret's
//! hex text.
//!
//! # Token format (version 1)
//!
//! A token is ASCII text of three dot-separated parts:
//!
//! ```text
//! v1.<base64url-no-pad(payload)>.<base64url-no-pad(tag)>
//! ```
//!
//! `payload` is 34 + n bytes (integers big-endian):
//!
//! | offset | size | field                                              |
//! |--------|------|----------------------------------------------------|
//! | 0      | 1    | role: 0 = player, 1 = admin                        |
//! | 1      | 8    | issued_at, unix seconds (u64)                      |
//! | 9      | 8    | expires_at, unix seconds (u64), > issued_at        |
//! | 17     | 16   | nonce, random bytes                                |
//! | 33     | 1    | n, player name length, 1..=32                      |
//! | 34     | n    | player name, ASCII `[A-Za-z0-9_-]`                 |
//!
//! `tag` is HMAC-SHA256 (32 bytes) keyed with the server's 32-byte secret over
//! the ASCII bytes of `v1.<base64url-no-pad(payload)>`, i.e. everything before
//! the second dot. Base64 is the URL-safe alphabet without padding and with
//! canonical trailing bits, so each token has exactly one spelling. A token is
//! at most [`MAX_TOKEN_LEN`] bytes (the longest valid one is 135).
//!
//! A token is valid at time `now` iff the tag verifies, the payload parses,
//! `now < expires_at` and `issued_at <= now + MAX_CLOCK_SKEW_SECS`.

mod duration;
mod secret;
mod token;

pub use duration::{format_duration, parse_duration, DurationError, HumanDuration, MAX_DURATION};
pub use secret::{Secret, SecretError, SECRET_LEN};
pub use token::{
    issue, issue_with_max_ttl, unix_now, validate_player_name, verify, verify_within, AuthError,
    Claims, MAX_CLOCK_SKEW_SECS, MAX_PLAYER_NAME_LEN, MAX_TOKEN_LEN, MAX_TOKEN_TTL, NONCE_LEN,
    TOKEN_VERSION,
};
