//! `strata-admin token issue`: mint an auth token with the data dir's secret.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use strata_protocol::Role;

use crate::auth::{self, parse_duration};
use crate::config::ServerConfig;
use crate::datadir::DataDir;

#[derive(Debug, Args)]
pub struct TokenIssueArgs {
    /// The server's data directory (holds the auth secret).
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Player name: 1 to 32 of A-Z a-z 0-9 _ -.
    #[arg(long)]
    pub player: String,
    /// `player` or `admin`.
    #[arg(long, default_value = "player")]
    pub role: String,
    /// Lifetime such as 30s, 15m, 12h or 7d.
    #[arg(long, default_value = "12h")]
    pub ttl: String,
    /// Server config, for `auth.token_max_ttl` [default: the data dir's
    /// strata.toml, else the defaults].
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Mints a token; the data dir must already exist (run the server once).
pub fn issue(args: &TokenIssueArgs) -> anyhow::Result<String> {
    let role = Role::from_name(&args.role)
        .with_context(|| format!("role must be player or admin, not {:?}", args.role))?;
    let ttl = parse_duration(&args.ttl).with_context(|| format!("--ttl {:?}", args.ttl))?;
    // A token the server would refuse sooner than asked is refused here.
    let cfg = match &args.config {
        Some(path) => ServerConfig::load(Some(path))?,
        None => crate::admin::remote::data_dir_config(&args.data_dir)?,
    };
    let dir = DataDir::open_existing(&args.data_dir)
        .with_context(|| format!("opening data dir {}", args.data_dir.display()))?;
    let token = auth::issue_with_max_ttl(
        dir.secret(),
        &args.player,
        role,
        ttl,
        cfg.auth.token_max_ttl.0,
        auth::unix_now(),
    )?;
    Ok(token)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn issues_verifiable_tokens_and_refuses_bad_input() {
        let tmp = tempfile::tempdir().unwrap();
        let root = tmp.path().join("data");
        let (dir, _) = DataDir::open_or_init(&root, &[]).unwrap();
        let mut args = TokenIssueArgs {
            data_dir: root.clone(),
            player: "ana".into(),
            role: "admin".into(),
            ttl: "1h".into(),
            config: None,
        };
        let token = issue(&args).unwrap();
        let claims = auth::verify(dir.secret(), &token, auth::unix_now()).unwrap();
        assert_eq!((claims.player.as_str(), claims.role), ("ana", Role::Admin));
        assert_eq!(claims.expires_at - claims.issued_at, 3600);
        args.role = "god".into();
        assert!(issue(&args)
            .unwrap_err()
            .to_string()
            .contains("player or admin"));
        // The data dir's own config caps it too.
        args.role = "admin".into();
        std::fs::write(
            root.join(crate::admin::world_source::DATA_DIR_CONFIG_NAME),
            "[auth]\ntoken_max_ttl = \"7d\"\n",
        )
        .unwrap();
        args.ttl = "30d".into();
        let err = issue(&args).unwrap_err().to_string();
        assert!(err.contains("7d") || err.contains("604800"), "{err}");
        args.ttl = "6d".into();
        issue(&args).unwrap();
        std::fs::remove_file(root.join(crate::admin::world_source::DATA_DIR_CONFIG_NAME)).unwrap();
        args.role = "player".into();
        args.ttl = "400d".into();
        assert!(
            issue(&args).is_err(),
            "over the configured maximum lifetime"
        );
        args.ttl = "1h".into();
        args.player = "bad name".into();
        assert!(issue(&args).is_err());
        args.player = "ana".into();
        args.data_dir = tmp.path().join("missing");
        assert!(format!("{:#}", issue(&args).unwrap_err()).contains("start strata-server once"));
    }
}
