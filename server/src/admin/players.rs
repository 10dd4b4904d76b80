//! `strata-admin players list` and `kick NAME` (online only).

use std::fmt::Write as _;

use anyhow::bail;
use clap::Args;
use strata_protocol::admin::{AdminRequest, AdminResponse, PlayerInfo};
use strata_terrain::Fixed;

use super::remote::TargetArgs;

#[derive(Debug, Args)]
pub struct PlayersArgs {
    #[command(flatten)]
    pub target: TargetArgs,
}

#[derive(Debug, Args)]
pub struct KickArgs {
    /// Player name: every session of this player is closed.
    pub name: String,
    #[command(flatten)]
    pub target: TargetArgs,
}

fn online(target: &TargetArgs, req: AdminRequest) -> anyhow::Result<AdminResponse> {
    target.request_if_online(&req)?.ok_or_else(|| {
        anyhow::anyhow!("sessions exist only on a running server: use --server, --cert and --token")
    })
}

/// One line per session: id, player, role, position.
pub fn render(list: &[PlayerInfo]) -> String {
    let mut out = String::new();
    for p in list {
        let at = p.position.map_or("no position yet".to_string(), |v| {
            let f = |x: Fixed| x.to_f64();
            format!("at ({:.1}, {:.1}, {:.1})", f(v.x), f(v.y), f(v.z))
        });
        let _ = writeln!(out, "{} {} {} {}", p.session, p.player, p.role.name(), at);
    }
    out
}

pub fn list(args: &PlayersArgs) -> anyhow::Result<Vec<PlayerInfo>> {
    match online(&args.target, AdminRequest::Players)? {
        AdminResponse::Players(l) => Ok(l),
        other => bail!("unexpected answer {other:?}"),
    }
}

/// Kicks every session of the player; returns how many there were.
pub fn kick(args: &KickArgs) -> anyhow::Result<u32> {
    let req = AdminRequest::Kick {
        player: args.name.clone(),
    };
    match online(&args.target, req)? {
        AdminResponse::Kicked { sessions } => Ok(sessions),
        other => bail!("unexpected answer {other:?}"),
    }
}
