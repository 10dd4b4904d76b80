//! The server's token-signing key and its text form.

use std::fmt;
use std::path::PathBuf;

use ring::hmac;
use ring::rand::{SecureRandom, SystemRandom};
use thiserror::Error;

/// Bytes of key material.
pub const SECRET_LEN: usize = 32;

/// The 32-byte HMAC-SHA256 key that signs and verifies tokens.
///
/// On disk (the server's `secret_file`) it is its hex text, mode 0600, so an
/// operator can inspect or back it up as text. `Debug` never prints it.
#[derive(Clone)]
pub struct Secret {
    bytes: [u8; SECRET_LEN],
    key: hmac::Key,
}

/// Why a secret could not be made, read or written.
#[derive(Debug, Error)]
pub enum SecretError {
    #[error("cannot read auth secret {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write auth secret {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("auth secret {path} is invalid: {reason}")]
    Invalid { path: PathBuf, reason: &'static str },
    #[error("the system random number generator failed")]
    Rng,
}

impl Secret {
    /// Wraps known key bytes (tests, or keys from elsewhere).
    pub fn from_bytes(bytes: [u8; SECRET_LEN]) -> Self {
        let key = hmac::Key::new(hmac::HMAC_SHA256, &bytes);
        Secret { bytes, key }
    }

    /// A fresh key from the OS random number generator.
    pub fn generate() -> Result<Self, SecretError> {
        let mut bytes = [0u8; SECRET_LEN];
        SystemRandom::new()
            .fill(&mut bytes)
            .map_err(|_| SecretError::Rng)?;
        Ok(Self::from_bytes(bytes))
    }

    /// Parses the key's text form: 64 hex characters, surrounding
    /// whitespace ignored (a hand-edited file with a trailing newline).
    pub fn from_hex(text: &str) -> Result<Self, &'static str> {
        let hex = text.trim();
        if hex.len() != SECRET_LEN * 2 {
            return Err("expected 64 hex characters");
        }
        let mut bytes = [0u8; SECRET_LEN];
        for (i, pair) in hex.as_bytes().chunks_exact(2).enumerate() {
            let hi = hex_value(pair[0]).ok_or("not hexadecimal")?;
            let lo = hex_value(pair[1]).ok_or("not hexadecimal")?;
            bytes[i] = hi << 4 | lo;
        }
        Ok(Self::from_bytes(bytes))
    }

    /// The key's text form: 64 lowercase hex characters and a newline.
    pub fn to_hex(&self) -> String {
        let mut text = String::with_capacity(SECRET_LEN * 2 + 1);
        for b in self.bytes {
            text.push_str(&format!("{b:02x}"));
        }
        text.push('\n');
        text
    }

    pub(crate) fn key(&self) -> &hmac::Key {
        &self.key
    }

    /// HMAC-SHA256 of `message` (for statements other than tokens that
    /// the holders of this secret must trust, such as cluster tickets).
    pub fn sign(&self, message: &[u8]) -> [u8; 32] {
        let mut mac = [0u8; 32];
        mac.copy_from_slice(hmac::sign(&self.key, message).as_ref());
        mac
    }

    /// Whether `mac` is [`Self::sign`]'s for `message` (constant time).
    pub fn verify(&self, message: &[u8], mac: &[u8]) -> bool {
        hmac::verify(&self.key, message, mac).is_ok()
    }
}

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Secret(..)")
    }
}

fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}
