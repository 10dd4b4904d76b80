//! Who gets in: `Authorization: Bearer <token>` with a valid, unrevoked
//! admin-role token of a player who is not banned. Player tokens are
//! refused like on the admin protocol.

use axum::http::{header, HeaderMap, StatusCode};
use strata_protocol::Role;
use thiserror::Error;
use tracing::warn;

use crate::auth;
use crate::log_every::LogEvery;
use crate::net::session::SessionContext;

/// Why a request was turned away.
#[derive(Debug, Error)]
pub enum Refused {
    #[error("an admin token is needed: send Authorization: Bearer <token>")]
    NoToken,
    #[error("bad token: {0}")]
    BadToken(#[from] auth::AuthError),
    #[error("{player}'s token has role {role}; the console needs role admin")]
    NotAdmin { player: String, role: &'static str },
    #[error("{0}")]
    Denied(#[from] auth::Denied),
}

impl Refused {
    pub fn status(&self) -> StatusCode {
        match self {
            Refused::NoToken | Refused::BadToken(_) => StatusCode::UNAUTHORIZED,
            Refused::NotAdmin { .. } | Refused::Denied(_) => StatusCode::FORBIDDEN,
        }
    }
}

/// Refused tokens, logged at most once a second (anyone can send them,
/// and a player can send its own token on every request).
static TOKEN_REFUSALS: LogEvery = LogEvery::new(crate::log_every::LOG_EVERY);

/// The admin a request comes from (its verified claims), or why it is
/// refused (logged, at most once a second).
pub fn admin(ctx: &SessionContext, headers: &HeaderMap) -> Result<auth::Claims, Refused> {
    check(ctx, headers).inspect_err(|r| {
        // No token at all is the page before sign-in: not worth a line.
        if matches!(r, Refused::NoToken) {
            return;
        }
        if let Some(refused) = TOKEN_REFUSALS.event() {
            warn!(reason = %r, refused, "console refused a request");
        }
    })
}

/// [`admin`] without the log: what the connection limiter asks before a
/// request runs (`conn_limit.rs`).
pub fn check(ctx: &SessionContext, headers: &HeaderMap) -> Result<auth::Claims, Refused> {
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::trim)
        .filter(|t| !t.is_empty() && t.len() <= auth::MAX_TOKEN_LEN)
        .ok_or(Refused::NoToken)?;
    let claims = ctx.verify_token(token)?;
    if claims.role != Role::Admin {
        return Err(Refused::NotAdmin {
            player: claims.player,
            role: claims.role.name(),
        });
    }
    ctx.admitted(&claims)?;
    Ok(claims)
}

/// Whether claims [`admin`] let in are still good at unix second `now`:
/// unexpired, not revoked, the admin not banned (for long-lived requests).
pub fn still_admitted(
    ctx: &SessionContext,
    claims: &auth::Claims,
    now: u64,
) -> Result<(), Refused> {
    if now >= claims.expires_at {
        return Err(auth::AuthError::Expired {
            expired_at: claims.expires_at,
        }
        .into());
    }
    Ok(ctx.admitted(claims)?)
}
