//! `strata-admin cluster status`: a cluster's regions as its PostgreSQL
//! store records them: owner, epoch, lease state and age, and edits per
//! second (the `edits` counters that fenced commits raise, read twice
//! `--sample-ms` apart). It reads the shared database, so the nodes keep
//! running.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::Serialize;

use crate::config::ServerConfig;
use crate::sequencer::regions::RegionId;
use crate::store::pg::RegionLease;
use crate::store::PgStore;
use crate::store::StoreBackend;

use super::world_source::DATA_DIR_CONFIG_NAME;

/// Longest `--sample-ms` accepted.
pub const MAX_SAMPLE_MS: u64 = 60_000;

#[derive(Debug, clap::Subcommand)]
pub enum ClusterCommand {
    /// Regions, owners, epochs, lease age and edits/s, from PostgreSQL.
    Status(StatusArgs),
}

#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    /// A node's config, naming `[store] backend = "postgres"` and its URL.
    #[arg(long, value_name = "FILE", conflicts_with = "data_dir")]
    pub config: Option<PathBuf>,
    /// A node's data dir: its strata.toml is read.
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Read the edit counters twice this far apart to report edits/s (0:
    /// read once, no rate).
    #[arg(long, default_value_t = 1000, value_name = "MS")]
    pub sample_ms: u64,
    /// One JSON object per region and line, instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One region's line of the report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegionStatus {
    pub region: [i32; 2],
    /// `None` once released.
    pub owner: Option<String>,
    pub epoch: u64,
    /// `live`, `expired` or `released`.
    pub state: &'static str,
    /// Milliseconds until the lease runs out (negative: expired).
    pub expires_in_ms: i64,
    /// Milliseconds since the lease was last claimed or renewed.
    pub lease_age_ms: i64,
    /// Edits that changed the region since it was first claimed.
    pub edits: u64,
    /// Over the sample; `None` without one.
    pub edits_per_s: Option<f64>,
}

/// The config `cluster status` reads: `--config`, else `DIR/strata.toml`.
fn load_config(args: &StatusArgs) -> anyhow::Result<ServerConfig> {
    let path = match (&args.config, &args.data_dir) {
        (Some(p), _) => p.clone(),
        (None, Some(dir)) => dir.join(DATA_DIR_CONFIG_NAME),
        (None, None) => bail!("give --config FILE or --data-dir DIR (a cluster node's)"),
    };
    let cfg =
        ServerConfig::load(Some(&path)).with_context(|| format!("loading {}", path.display()))?;
    if cfg.store.backend != StoreBackend::Postgres {
        bail!(
            "{} does not name [store] backend = \"postgres\": a cluster's regions live in PostgreSQL",
            path.display()
        );
    }
    Ok(cfg)
}

/// Reads the regions table (twice, `sample_ms` apart, for the rates).
pub fn run(args: &StatusArgs) -> anyhow::Result<Vec<RegionStatus>> {
    if args.sample_ms > MAX_SAMPLE_MS {
        bail!("--sample-ms {} is over {MAX_SAMPLE_MS}", args.sample_ms);
    }
    let cfg = load_config(args)?;
    let store = PgStore::open_admin(&cfg.store.postgres, cfg.sequencer.region_chunks)
        .context("opening the cluster's PostgreSQL store")?;
    let first = store.region_leases()?;
    let first_at = Instant::now();
    if args.sample_ms == 0 {
        return Ok(first.iter().map(|l| status(l, None)).collect());
    }
    std::thread::sleep(Duration::from_millis(args.sample_ms));
    let last = store.region_leases()?;
    let secs = first_at.elapsed().as_secs_f64();
    let before: BTreeMap<RegionId, u64> = first.iter().map(|l| (l.region, l.edits)).collect();
    Ok(last
        .iter()
        .map(|l| {
            let was = before.get(&l.region).copied().unwrap_or(0);
            status(l, Some(l.edits.saturating_sub(was) as f64 / secs))
        })
        .collect())
}

fn status(l: &RegionLease, edits_per_s: Option<f64>) -> RegionStatus {
    let state = match (&l.owner, l.expires_in_ms) {
        (None, _) => "released",
        (Some(_), ms) if ms < 0 => "expired",
        _ => "live",
    };
    RegionStatus {
        region: [l.region.x, l.region.z],
        owner: l.owner.clone(),
        epoch: l.epoch,
        state,
        expires_in_ms: l.expires_in_ms,
        lease_age_ms: l.renewed_ms_ago,
        edits: l.edits,
        edits_per_s,
    }
}

/// The report as a table with a per-node summary, or as JSON lines.
pub fn render(rows: &[RegionStatus], json: bool) -> String {
    let mut out = String::new();
    if json {
        for r in rows {
            let _ = writeln!(out, "{}", serde_json::to_string(r).unwrap_or_default());
        }
        return out;
    }
    let rate = |r: Option<f64>| r.map_or("-".to_string(), |v| format!("{v:.1}"));
    let _ = writeln!(
        out,
        "{:<12} {:<16} {:>6} {:<9} {:>10} {:>10} {:>10} {:>8}",
        "region", "owner", "epoch", "lease", "expires_s", "age_s", "edits", "edits/s"
    );
    let mut nodes: BTreeMap<&str, (usize, f64)> = BTreeMap::new();
    for r in rows {
        let _ = writeln!(
            out,
            "{:<12} {:<16} {:>6} {:<9} {:>10.1} {:>10.1} {:>10} {:>8}",
            format!("({}, {})", r.region[0], r.region[1]),
            r.owner.as_deref().unwrap_or("-"),
            r.epoch,
            r.state,
            r.expires_in_ms as f64 / 1000.0,
            r.lease_age_ms as f64 / 1000.0,
            r.edits,
            rate(r.edits_per_s)
        );
        if let (Some(owner), "live") = (&r.owner, r.state) {
            let n = nodes.entry(owner).or_default();
            n.0 += 1;
            n.1 += r.edits_per_s.unwrap_or(0.0);
        }
    }
    let unowned = rows.iter().filter(|r| r.state != "live").count();
    let _ = writeln!(
        out,
        "{} regions: {} live on {} nodes, {} released or expired",
        rows.len(),
        rows.len() - unowned,
        nodes.len(),
        unowned
    );
    for (node, (regions, per_s)) in &nodes {
        let _ = writeln!(out, "node {node}: {regions} regions, {per_s:.1} edits/s");
    }
    out
}
