//! `strata-admin check`: verifies a stopped server's whole store offline.
//!
//! Runs the store's `check_with_progress` (sled's or PostgreSQL's, as the
//! data dir's config names: every chunk decodes, chunk
//! versions agree with the edit log, the log has no gaps and ends at the
//! metadata's `last_seq`, no orphaned records or trees) and adds what only
//! the server's code knows: the world metadata was written by this
//! generator version, and the stored protected zones parse.

use std::fmt;
use std::path::PathBuf;

use strata_terrain::gen::GENERATOR_VERSION;

use crate::app::ZONES_BLOB;
use crate::store::{CheckReport, ChunkStore};
use crate::validate::zones::Zone;

use super::world_source::{open_offline, progress_bar, WorldSourceError};

/// Arguments of `strata-admin check`.
#[derive(Debug, Clone, clap::Args)]
pub struct CheckArgs {
    /// Data directory of a STOPPED server: the store its strata.toml (or
    /// --config) names is opened directly, world.sled without one.
    #[arg(long, value_name = "DIR")]
    pub data_dir: PathBuf,
    /// Server config naming the store [default: DIR/strata.toml if
    /// present, else the data dir's world.sled]. With `[store] backend =
    /// "postgres"` its database is checked; stop every node first.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

/// The store's report plus the world-level findings.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckOutcome {
    pub store: CheckReport,
    /// Problems outside the store's own invariants.
    pub world: Vec<String>,
    pub blobs: u64,
}

impl CheckOutcome {
    pub fn is_ok(&self) -> bool {
        self.store.is_ok() && self.world.is_empty()
    }

    /// Problems found, including any past the report's cap.
    pub fn problem_count(&self) -> u64 {
        self.store.issues.len() as u64 + self.store.issues_dropped + self.world.len() as u64
    }
}

impl fmt::Display for CheckOutcome {
    /// The report `strata-admin check` prints: totals, then one line per problem.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "checked {} log entries, {} chunks, {} blobs",
            self.store.log_entries, self.store.chunks, self.blobs
        )?;
        for issue in &self.store.issues {
            writeln!(f, "PROBLEM {issue}")?;
        }
        if self.store.issues_dropped > 0 {
            writeln!(
                f,
                "PROBLEM ... and {} more store problems not listed",
                self.store.issues_dropped
            )?;
        }
        for w in &self.world {
            writeln!(f, "PROBLEM {w}")?;
        }
        if self.is_ok() {
            writeln!(f, "OK: the store is consistent")
        } else {
            writeln!(f, "NOT CLEAN: {} problems", self.problem_count())
        }
    }
}

/// World-level checks on a store whose records were scanned.
fn world_findings(store: &dyn ChunkStore) -> Vec<String> {
    let mut out = Vec::new();
    match store.load_meta() {
        Ok(Some(meta)) if meta.generator_version != GENERATOR_VERSION => out.push(format!(
            "meta: generator version {} but this build generates version {GENERATOR_VERSION}; \
             unmodified chunks would differ",
            meta.generator_version
        )),
        // An unreadable record is already a store issue.
        _ => {}
    }
    match store.get_blob(ZONES_BLOB) {
        Ok(Some(bytes)) => {
            if let Err(e) = serde_json::from_slice::<Vec<Zone>>(&bytes) {
                out.push(format!(
                    "blob {ZONES_BLOB:?}: protected zones do not parse: {e}"
                ));
            }
        }
        Ok(None) => {}
        Err(e) => out.push(format!("blob {ZONES_BLOB:?}: {e}")),
    }
    out
}

/// Runs the check; `show_progress` allows a spinner on stderr.
pub fn run(args: &CheckArgs, show_progress: bool) -> Result<CheckOutcome, WorldSourceError> {
    let (store, path) = open_offline(&args.data_dir, args.config.as_deref())?;
    let store_err = |source| WorldSourceError::Store {
        path: path.clone(),
        source,
    };
    let bar = progress_bar(show_progress, None, "checked records");
    let report = store
        .check_with_progress(&|| bar.inc(1))
        .map_err(store_err)?;
    bar.finish_and_clear();
    let blobs = store.blob_count().map_err(store_err)?;
    Ok(CheckOutcome {
        store: report,
        world: world_findings(store.as_store()),
        blobs,
    })
}
