//! Token issue/verify: round trips, the documented byte layout, and every
//! refusal (expired, forged, malformed, wrong secret, bad names and TTLs).

use std::time::Duration;

use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use base64::Engine as _;
use strata_protocol::Role;
use strata_server::auth::{
    issue, issue_with_max_ttl, verify, AuthError, Secret, MAX_CLOCK_SKEW_SECS, MAX_TOKEN_LEN,
    MAX_TOKEN_TTL,
};

const NOW: u64 = 1_800_000_000;
const HOUR: Duration = Duration::from_secs(3600);

fn secret() -> Secret {
    Secret::from_bytes([0x42; 32])
}

fn token(player: &str, role: Role) -> String {
    issue(&secret(), player, role, HOUR, NOW).expect("issue")
}

#[test]
fn issued_token_verifies_with_its_claims() {
    for role in [Role::Player, Role::Admin] {
        let t = token("alice_01-x", role);
        let c = verify(&secret(), &t, NOW + 10).expect("verify");
        assert_eq!(c.player, "alice_01-x");
        assert_eq!(c.role, role);
        assert_eq!(c.issued_at, NOW);
        assert_eq!(c.expires_at, NOW + 3600);
    }
}

#[test]
fn tokens_differ_by_nonce() {
    let a = token("bob", Role::Player);
    let b = token("bob", Role::Player);
    assert_ne!(a, b);
    let (ca, cb) = (
        verify(&secret(), &a, NOW).unwrap(),
        verify(&secret(), &b, NOW).unwrap(),
    );
    assert_ne!(ca.nonce, cb.nonce);
}

#[test]
fn wire_layout_matches_the_documented_format() {
    let t = token("carol", Role::Admin);
    let parts: Vec<&str> = t.split('.').collect();
    assert_eq!(parts.len(), 3);
    assert_eq!(parts[0], "v1");
    let payload = URL_SAFE_NO_PAD.decode(parts[1]).unwrap();
    assert_eq!(payload.len(), 34 + 5);
    assert_eq!(payload[0], 1, "admin role byte");
    assert_eq!(payload[1..9], NOW.to_be_bytes());
    assert_eq!(payload[9..17], (NOW + 3600).to_be_bytes());
    assert_eq!(payload[33], 5);
    assert_eq!(&payload[34..], b"carol");
    // The tag is HMAC-SHA256 over "v1.<payload b64>".
    let key = ring::hmac::Key::new(ring::hmac::HMAC_SHA256, &[0x42; 32]);
    let expected = ring::hmac::sign(&key, format!("v1.{}", parts[1]).as_bytes());
    assert_eq!(URL_SAFE_NO_PAD.decode(parts[2]).unwrap(), expected.as_ref());
}

#[test]
fn expiry_is_exclusive() {
    let t = token("dave", Role::Player);
    assert!(verify(&secret(), &t, NOW + 3599).is_ok());
    assert_eq!(
        verify(&secret(), &t, NOW + 3600),
        Err(AuthError::Expired {
            expired_at: NOW + 3600
        })
    );
    assert_eq!(
        verify(&secret(), &t, u64::MAX),
        Err(AuthError::Expired {
            expired_at: NOW + 3600
        })
    );
}

#[test]
fn token_from_the_future_is_refused_beyond_the_skew() {
    let t = token("erin", Role::Player);
    assert!(verify(&secret(), &t, NOW - MAX_CLOCK_SKEW_SECS).is_ok());
    assert_eq!(
        verify(&secret(), &t, NOW - MAX_CLOCK_SKEW_SECS - 1),
        Err(AuthError::NotYetValid { issued_at: NOW })
    );
}

#[test]
fn wrong_secret_is_a_bad_signature() {
    let t = token("frank", Role::Player);
    let other = Secret::from_bytes([0x43; 32]);
    assert_eq!(verify(&other, &t, NOW), Err(AuthError::BadSignature));
}

#[test]
fn forged_payload_is_a_bad_signature() {
    // Promote a player token to admin while keeping the original tag.
    let t = token("mallory", Role::Player);
    let parts: Vec<&str> = t.split('.').collect();
    let mut payload = URL_SAFE_NO_PAD.decode(parts[1]).unwrap();
    payload[0] = 1;
    let forged = format!("v1.{}.{}", URL_SAFE_NO_PAD.encode(&payload), parts[2]);
    assert_eq!(
        verify(&secret(), &forged, NOW),
        Err(AuthError::BadSignature)
    );

    // Extend the expiry.
    let mut payload = URL_SAFE_NO_PAD.decode(parts[1]).unwrap();
    payload[9..17].copy_from_slice(&u64::MAX.to_be_bytes());
    let forged = format!("v1.{}.{}", URL_SAFE_NO_PAD.encode(&payload), parts[2]);
    assert_eq!(
        verify(&secret(), &forged, NOW),
        Err(AuthError::BadSignature)
    );

    // Alter the tag itself (same length, different bytes).
    let mut tag = URL_SAFE_NO_PAD.decode(parts[2]).unwrap();
    tag[0] ^= 1;
    let forged = format!("v1.{}.{}", parts[1], URL_SAFE_NO_PAD.encode(&tag));
    assert_eq!(
        verify(&secret(), &forged, NOW),
        Err(AuthError::BadSignature)
    );
}

#[test]
fn malformed_tokens_name_the_reason() {
    let good = token("gina", Role::Player);
    let parts: Vec<&str> = good.split('.').collect();
    let cases: Vec<(String, &str)> = vec![
        (String::new(), "expected three '.'-separated parts"),
        ("v1".into(), "expected three '.'-separated parts"),
        ("v1.abc".into(), "expected three '.'-separated parts"),
        (format!("{good}.x"), "expected three '.'-separated parts"),
        (
            format!("v2.{}.{}", parts[1], parts[2]),
            "unknown token version",
        ),
        (
            format!("v1.{}.{}=", parts[1], parts[2]),
            "signature is not base64url without padding",
        ),
        (
            format!("v1.{}.a+b/", parts[1]),
            "signature is not base64url without padding",
        ),
        (
            format!("v1.{}.{}", parts[1], &parts[2][..40]),
            "signature is not 32 bytes",
        ),
    ];
    for (t, reason) in cases {
        assert_eq!(
            verify(&secret(), &t, NOW),
            Err(AuthError::Malformed(reason)),
            "token {t:?}"
        );
    }
}

#[test]
fn non_canonical_base64_is_refused() {
    // The last character of a 43-char tag carries 2 spare bits; setting them
    // must not give a second valid spelling of the same token.
    let t = token("hank", Role::Player);
    let last = t.chars().last().unwrap();
    let alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";
    let idx = alphabet.find(last).unwrap();
    let twin = alphabet.as_bytes()[idx ^ 1] as char;
    let mut altered = t[..t.len() - 1].to_owned();
    altered.push(twin);
    assert_eq!(
        verify(&secret(), &altered, NOW),
        Err(AuthError::Malformed(
            "signature is not base64url without padding"
        ))
    );
}

#[test]
fn overlong_token_is_refused_before_parsing() {
    let long = format!("v1.{}", "A".repeat(MAX_TOKEN_LEN));
    assert_eq!(
        verify(&secret(), &long, NOW),
        Err(AuthError::TooLong {
            len: MAX_TOKEN_LEN + 3,
            max: MAX_TOKEN_LEN
        })
    );
}

#[test]
fn bad_player_names_are_refused_at_issue() {
    let too_long = "x".repeat(33);
    for name in ["", too_long.as_str(), "a b", "é", "semi;colon", "dot.name"] {
        assert!(
            matches!(
                issue(&secret(), name, Role::Player, HOUR, NOW),
                Err(AuthError::BadPlayerName(_))
            ),
            "name {name:?}"
        );
    }
    assert!(issue(&secret(), &"x".repeat(32), Role::Player, HOUR, NOW).is_ok());
}

#[test]
fn ttl_must_be_positive_and_within_the_cap() {
    assert_eq!(
        issue(&secret(), "ivan", Role::Player, Duration::ZERO, NOW),
        Err(AuthError::BadTtl {
            ttl_secs: 0,
            max_secs: MAX_TOKEN_TTL.as_secs()
        })
    );
    let over = MAX_TOKEN_TTL + Duration::from_secs(1);
    assert!(matches!(
        issue(&secret(), "ivan", Role::Player, over, NOW),
        Err(AuthError::BadTtl { .. })
    ));
    let day = Duration::from_secs(86_400);
    assert_eq!(
        issue_with_max_ttl(&secret(), "ivan", Role::Player, 2 * day, day, NOW),
        Err(AuthError::BadTtl {
            ttl_secs: 2 * 86_400,
            max_secs: 86_400
        })
    );
    assert!(issue_with_max_ttl(&secret(), "ivan", Role::Player, day, day, NOW).is_ok());
    // Expiry past u64::MAX is refused rather than wrapped.
    assert!(matches!(
        issue(&secret(), "ivan", Role::Player, HOUR, u64::MAX - 10),
        Err(AuthError::BadTtl { .. })
    ));
}

#[test]
fn garbage_never_panics() {
    let t = token("judy", Role::Player);
    for cut in 0..t.len() {
        assert!(verify(&secret(), &t[..cut], NOW).is_err());
    }
    for s in ["...", "v1..", "v1.\u{0}.\u{0}", "v1.é.é", ".v1.a.b"] {
        assert!(verify(&secret(), s, NOW).is_err(), "{s:?}");
    }
}
