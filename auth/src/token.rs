//! Issuing and verifying version-1 tokens (format in the module docs above).

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use base64::Engine as _;
use ring::hmac;
use ring::rand::{SecureRandom, SystemRandom};
use strata_protocol::Role;
use thiserror::Error;

use crate::secret::Secret;

/// Version prefix of every token this module mints.
pub const TOKEN_VERSION: &str = "v1";
/// Longest token text accepted; anything longer is refused before parsing.
pub const MAX_TOKEN_LEN: usize = 512;
/// Longest player name, in bytes (names are ASCII).
pub const MAX_PLAYER_NAME_LEN: usize = 32;
/// Random bytes per token, so two tokens for the same player differ.
pub const NONCE_LEN: usize = 16;
/// How far in the future `issued_at` may be before a token is refused:
/// tolerates clock drift between the admin host and the server.
pub const MAX_CLOCK_SKEW_SECS: u64 = 300;
/// Hard cap on a token's lifetime, whatever the config says.
pub const MAX_TOKEN_TTL: Duration = Duration::from_secs(365 * 24 * 3600);

/// HMAC-SHA256 output length.
const TAG_LEN: usize = 32;
/// Payload bytes before the name: role, issued_at, expires_at, nonce, length.
const FIXED_PAYLOAD_LEN: usize = 1 + 8 + 8 + NONCE_LEN + 1;
const ROLE_PLAYER: u8 = 0;
const ROLE_ADMIN: u8 = 1;

/// What a verified token says about its bearer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Claims {
    pub player: String,
    pub role: Role,
    /// Unix seconds.
    pub issued_at: u64,
    /// Unix seconds; the token is refused from this instant on.
    pub expires_at: u64,
    pub nonce: [u8; NONCE_LEN],
}

/// Why a token could not be issued or was refused.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum AuthError {
    #[error("token is malformed: {0}")]
    Malformed(&'static str),
    #[error("token signature does not verify (forged, altered or another server's secret)")]
    BadSignature,
    #[error("token expired at {expired_at} (unix seconds)")]
    Expired { expired_at: u64 },
    #[error(
        "token issued at {issued_at} (unix seconds), in the future beyond the allowed clock skew"
    )]
    NotYetValid { issued_at: u64 },
    #[error("bad player name: {0}")]
    BadPlayerName(&'static str),
    #[error("token is {len} bytes, over the {max}-byte cap")]
    TooLong { len: usize, max: usize },
    #[error("token lifetime {ttl_secs}s is out of range (1..={max_secs}s)")]
    BadTtl { ttl_secs: u64, max_secs: u64 },
    #[error("the system random number generator failed")]
    Rng,
}

/// Current time in unix seconds (0 if the clock is before 1970).
pub fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Checks a player name: 1..=32 ASCII letters, digits, `_` or `-`.
pub fn validate_player_name(name: &str) -> Result<(), AuthError> {
    if name.is_empty() {
        return Err(AuthError::BadPlayerName("empty"));
    }
    if name.len() > MAX_PLAYER_NAME_LEN {
        return Err(AuthError::BadPlayerName("longer than 32 characters"));
    }
    if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        return Err(AuthError::BadPlayerName(
            "only ASCII letters, digits, '_' and '-' are allowed",
        ));
    }
    Ok(())
}

/// Mints a token valid from `now` (unix seconds) for `ttl`, capped at
/// [`MAX_TOKEN_TTL`].
pub fn issue(
    secret: &Secret,
    player: &str,
    role: Role,
    ttl: Duration,
    now: u64,
) -> Result<String, AuthError> {
    issue_with_max_ttl(secret, player, role, ttl, MAX_TOKEN_TTL, now)
}

/// Like [`issue`] but with a tighter lifetime cap, e.g. the config's
/// `auth.token_max_ttl`. `max_ttl` is itself clamped to [`MAX_TOKEN_TTL`].
pub fn issue_with_max_ttl(
    secret: &Secret,
    player: &str,
    role: Role,
    ttl: Duration,
    max_ttl: Duration,
    now: u64,
) -> Result<String, AuthError> {
    validate_player_name(player)?;
    let max_secs = max_ttl.min(MAX_TOKEN_TTL).as_secs();
    let ttl_secs = ttl.as_secs();
    if ttl_secs == 0 || ttl_secs > max_secs {
        return Err(AuthError::BadTtl { ttl_secs, max_secs });
    }
    let expires_at = now
        .checked_add(ttl_secs)
        .ok_or(AuthError::BadTtl { ttl_secs, max_secs })?;
    let mut nonce = [0u8; NONCE_LEN];
    SystemRandom::new()
        .fill(&mut nonce)
        .map_err(|_| AuthError::Rng)?;
    let claims = Claims {
        player: player.to_owned(),
        role,
        issued_at: now,
        expires_at,
        nonce,
    };
    Ok(sign(secret, &claims))
}

/// Encodes and signs `claims` (already validated).
fn sign(secret: &Secret, claims: &Claims) -> String {
    let mut payload = Vec::with_capacity(FIXED_PAYLOAD_LEN + claims.player.len());
    payload.push(match claims.role {
        Role::Player => ROLE_PLAYER,
        Role::Admin => ROLE_ADMIN,
    });
    payload.extend_from_slice(&claims.issued_at.to_be_bytes());
    payload.extend_from_slice(&claims.expires_at.to_be_bytes());
    payload.extend_from_slice(&claims.nonce);
    // Validated names are at most 32 bytes, so the length fits in a u8.
    payload.push(claims.player.len() as u8);
    payload.extend_from_slice(claims.player.as_bytes());

    let mut token = format!("{TOKEN_VERSION}.{}", URL_SAFE_NO_PAD.encode(&payload));
    let tag = hmac::sign(secret.key(), token.as_bytes());
    token.push('.');
    token.push_str(&URL_SAFE_NO_PAD.encode(tag.as_ref()));
    token
}

/// [`verify`] for a server whose `auth.token_max_ttl` is `max_ttl`: a
/// token lives at most that long from its `issued_at`, whatever its
/// `expires_at` says (the returned claims carry the earlier expiry). So
/// lowering the setting shortens the tokens already out, such as those of
/// an issuer that leaked, and not only those issued next.
pub fn verify_within(
    secret: &Secret,
    token: &str,
    now: u64,
    max_ttl: Duration,
) -> Result<Claims, AuthError> {
    let mut claims = verify(secret, token, now)?;
    let cap = claims
        .issued_at
        .saturating_add(max_ttl.min(MAX_TOKEN_TTL).as_secs());
    if cap < claims.expires_at {
        claims.expires_at = cap;
        if now >= cap {
            return Err(AuthError::Expired { expired_at: cap });
        }
    }
    Ok(claims)
}

/// Verifies `token` at `now` (unix seconds) and returns its claims.
/// The signature is checked (in constant time) before the payload is parsed,
/// so unauthenticated bytes never reach the parser.
pub fn verify(secret: &Secret, token: &str, now: u64) -> Result<Claims, AuthError> {
    if token.len() > MAX_TOKEN_LEN {
        return Err(AuthError::TooLong {
            len: token.len(),
            max: MAX_TOKEN_LEN,
        });
    }
    let (signed, tag_b64) = token
        .rsplit_once('.')
        .ok_or(AuthError::Malformed("expected three '.'-separated parts"))?;
    let (version, payload_b64) = signed
        .split_once('.')
        .ok_or(AuthError::Malformed("expected three '.'-separated parts"))?;
    if payload_b64.contains('.') {
        return Err(AuthError::Malformed("expected three '.'-separated parts"));
    }
    if version != TOKEN_VERSION {
        return Err(AuthError::Malformed("unknown token version"));
    }
    let tag = URL_SAFE_NO_PAD
        .decode(tag_b64)
        .map_err(|_| AuthError::Malformed("signature is not base64url without padding"))?;
    if tag.len() != TAG_LEN {
        return Err(AuthError::Malformed("signature is not 32 bytes"));
    }
    hmac::verify(secret.key(), signed.as_bytes(), &tag).map_err(|_| AuthError::BadSignature)?;

    let payload = URL_SAFE_NO_PAD
        .decode(payload_b64)
        .map_err(|_| AuthError::Malformed("payload is not base64url without padding"))?;
    let claims = parse_payload(&payload)?;
    if now >= claims.expires_at {
        return Err(AuthError::Expired {
            expired_at: claims.expires_at,
        });
    }
    if claims.issued_at > now.saturating_add(MAX_CLOCK_SKEW_SECS) {
        return Err(AuthError::NotYetValid {
            issued_at: claims.issued_at,
        });
    }
    Ok(claims)
}

fn parse_payload(payload: &[u8]) -> Result<Claims, AuthError> {
    if payload.len() < FIXED_PAYLOAD_LEN {
        return Err(AuthError::Malformed("payload too short"));
    }
    let (fixed, name) = payload.split_at(FIXED_PAYLOAD_LEN);
    let role = match fixed[0] {
        ROLE_PLAYER => Role::Player,
        ROLE_ADMIN => Role::Admin,
        _ => return Err(AuthError::Malformed("unknown role")),
    };
    let u64_at = |at: usize| {
        let mut b = [0u8; 8];
        b.copy_from_slice(&fixed[at..at + 8]);
        u64::from_be_bytes(b)
    };
    let issued_at = u64_at(1);
    let expires_at = u64_at(9);
    let mut nonce = [0u8; NONCE_LEN];
    nonce.copy_from_slice(&fixed[17..17 + NONCE_LEN]);
    let name_len = usize::from(fixed[FIXED_PAYLOAD_LEN - 1]);
    if name.len() != name_len {
        return Err(AuthError::Malformed(
            "player name length does not match payload",
        ));
    }
    if expires_at <= issued_at {
        return Err(AuthError::Malformed("expires_at is not after issued_at"));
    }
    let player = std::str::from_utf8(name).map_err(|_| AuthError::BadPlayerName("not ASCII"))?;
    validate_player_name(player)?;
    Ok(Claims {
        player: player.to_owned(),
        role,
        issued_at,
        expires_at,
        nonce,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lowered_max_ttl_shortens_tokens_already_issued() {
        let secret = Secret::from_bytes([7; 32]);
        let day = 24 * 3600;
        let t = issue(
            &secret,
            "ann",
            Role::Player,
            Duration::from_secs(90 * day),
            1_000,
        )
        .unwrap();
        let thirty = Duration::from_secs(30 * day);
        // Within the cap: good, with the capped expiry.
        let c = verify_within(&secret, &t, 1_000 + 29 * day, thirty).unwrap();
        assert_eq!(c.expires_at, 1_000 + 30 * day);
        // Past it, though the token itself runs 90 days.
        assert_eq!(
            verify_within(&secret, &t, 1_000 + 30 * day, thirty),
            Err(AuthError::Expired {
                expired_at: 1_000 + 30 * day
            })
        );
        assert!(verify(&secret, &t, 1_000 + 30 * day).is_ok());
        // A cap above the token's own life changes nothing.
        let c = verify_within(&secret, &t, 1_000, MAX_TOKEN_TTL).unwrap();
        assert_eq!(c.expires_at, 1_000 + 90 * day);
    }

    // `sign` bypasses `issue`'s checks, so these tokens carry a valid
    // signature over payloads the parser must still refuse.
    #[test]
    fn signed_bad_payloads_are_refused_after_the_signature() {
        let secret = Secret::from_bytes([7; 32]);
        let mut claims = Claims {
            player: "ok".into(),
            role: Role::Player,
            issued_at: 100,
            expires_at: 100,
            nonce: [0; NONCE_LEN],
        };
        let t = sign(&secret, &claims);
        assert_eq!(
            verify(&secret, &t, 50),
            Err(AuthError::Malformed("expires_at is not after issued_at"))
        );
        claims.expires_at = 200;
        claims.player = "bad name".into();
        let t = sign(&secret, &claims);
        assert!(matches!(
            verify(&secret, &t, 150),
            Err(AuthError::BadPlayerName(_))
        ));
    }

    #[test]
    fn longest_token_fits_the_cap() {
        let secret = Secret::from_bytes([1; 32]);
        let name = "a".repeat(MAX_PLAYER_NAME_LEN);
        let t = issue(&secret, &name, Role::Admin, MAX_TOKEN_TTL, u64::MAX / 2).unwrap();
        assert_eq!(t.len(), 135);
        assert!(t.len() <= MAX_TOKEN_LEN);
    }
}
