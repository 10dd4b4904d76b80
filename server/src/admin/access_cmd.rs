//! `strata-admin ban|unban|bans` and `token revoke`: the access list
//! ([`crate::auth::access`]). Online, a change is persisted by the server,
//! takes effect at the next Hello and ends the player's live sessions;
//! offline, it edits the stored list of a stopped server.

use std::fmt::Write as _;

use anyhow::{bail, Context};
use clap::Args;
use strata_protocol::admin::{AccessSpec, AdminRequest, AdminResponse};

use super::remote::{open_offline_store, Target, TargetArgs};
use crate::auth::{parse_duration, unix_now, validate_player_name, AccessList, ACCESS_BLOB};
use crate::net::admin_session::{access_spec, ACCESS_WRITE_ATTEMPTS};

#[derive(Debug, Args)]
pub struct BanArgs {
    /// The player to ban.
    pub player: String,
    /// When the ban ends: a duration from now (`90m`, `12h`, `30d`) or a
    /// unix time in seconds. Without it the ban lasts until `unban`.
    #[arg(long)]
    pub until: Option<String>,
    #[command(flatten)]
    pub target: TargetArgs,
}

#[derive(Debug, Args)]
pub struct PlayerArgs {
    pub player: String,
    #[command(flatten)]
    pub target: TargetArgs,
}

#[derive(Debug, Args)]
pub struct ListArgs {
    #[command(flatten)]
    pub target: TargetArgs,
}

/// `--until`: a duration from `now`, or unix seconds.
pub fn parse_until(text: &str, now: u64) -> anyhow::Result<u64> {
    if text.bytes().all(|b| b.is_ascii_digit()) {
        let at: u64 = text.parse().context("--until")?;
        if at <= now {
            bail!("--until {at} is in the past (now is {now})");
        }
        return Ok(at);
    }
    let d = parse_duration(text).with_context(|| format!("--until {text:?}"))?;
    Ok(now.saturating_add(d.as_secs().max(1)))
}

/// One line per ban and revocation (and the sessions ended, if any).
pub fn render(a: &AccessSpec) -> String {
    let mut out = String::new();
    for (p, until) in &a.bans {
        let _ = match until {
            Some(u) => writeln!(out, "banned {p} until unix time {u}"),
            None => writeln!(out, "banned {p} until unbanned"),
        };
    }
    for (p, t) in &a.revoked_before {
        let _ = writeln!(
            out,
            "revoked {p}'s tokens issued at or before unix time {t}"
        );
    }
    if a.kicked > 0 {
        let _ = writeln!(out, "ended {} live session(s)", a.kicked);
    }
    if out.is_empty() {
        out.push_str("no bans or revocations\n");
    }
    out
}

/// Sends `req` to a running server, or applies `change` to a stopped one's
/// stored list. Returns the list after it.
fn apply(
    target: &TargetArgs,
    req: AdminRequest,
    change: impl Fn(&mut AccessList, u64) -> anyhow::Result<()>,
) -> anyhow::Result<AccessSpec> {
    if let Some(answer) = target.request_if_online(&req)? {
        return match answer {
            AdminResponse::Access(a) => Ok(a),
            AdminResponse::Refused { message } => bail!("{message}"),
            other => bail!("unexpected answer {other:?}"),
        };
    }
    let Target::Offline(dir) = target.target()? else {
        unreachable!("online handled first")
    };
    let store = open_offline_store(&dir)?;
    // On PostgreSQL the cluster's nodes may change the list meanwhile: it
    // is written only over what was read.
    for _ in 0..ACCESS_WRITE_ATTEMPTS {
        let raw = store.get_blob(ACCESS_BLOB)?;
        let mut list = AccessList::from_blob(raw.as_deref())?;
        let before = list.clone();
        change(&mut list, unix_now())?;
        if list == before || store.swap_blob(ACCESS_BLOB, raw.as_deref(), &list.to_blob())? {
            return Ok(access_spec(&list, 0));
        }
    }
    bail!("the stored access list changed under this change {ACCESS_WRITE_ATTEMPTS} times; nothing was written, try again")
}

pub fn ban(a: &BanArgs) -> anyhow::Result<AccessSpec> {
    validate_player_name(&a.player)?;
    let until = a
        .until
        .as_deref()
        .map(|u| parse_until(u, unix_now()))
        .transpose()?;
    let req = AdminRequest::Ban {
        player: a.player.clone(),
        until,
    };
    apply(&a.target, req, |list, now| {
        Ok(list.ban(&a.player, until, now)?)
    })
}

pub fn unban(a: &PlayerArgs) -> anyhow::Result<AccessSpec> {
    let req = AdminRequest::Unban {
        player: a.player.clone(),
    };
    apply(&a.target, req, |list, _| {
        list.unban(&a.player);
        Ok(())
    })
}

pub fn revoke(a: &PlayerArgs) -> anyhow::Result<AccessSpec> {
    validate_player_name(&a.player)?;
    let req = AdminRequest::RevokeTokens {
        player: a.player.clone(),
    };
    apply(&a.target, req, |list, now| Ok(list.revoke(&a.player, now)?))
}

pub fn list(a: &ListArgs) -> anyhow::Result<AccessSpec> {
    apply(&a.target, AdminRequest::Access, |_, _| Ok(()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn until_takes_durations_and_future_unix_times() {
        assert_eq!(parse_until("2h", 1000).unwrap(), 1000 + 7200);
        assert_eq!(parse_until("5000", 1000).unwrap(), 5000);
        assert!(parse_until("999", 1000).is_err());
        assert!(parse_until("soon", 1000).is_err());
    }
}
