//! `strata-admin`: offline administration of Strata worlds and data.
//! Argument parsing and printing only; the commands live in
//! `strata_server::admin`.

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use strata_server::admin::mesh_cmd::{self, MeshArgs};

/// Offline administration tools for Strata.
#[derive(Debug, Parser)]
#[command(name = "strata-admin", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Mesh a raw u8 density volume into one welded triangle mesh.
    ///
    /// The volume file holds one density byte per sample (0 air .. 255
    /// solid), x fastest, then y, then z. The mesh can be written as binary
    /// PLY (with per-vertex material) or OBJ; `--stats` prints one JSON line
    /// with the cell, vertex and triangle counts and the meshing time.
    Mesh(MeshArgs),
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line with the whole cause chain; no backtrace for input errors.
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Mesh(args) => {
            let report = mesh_cmd::run(&args, true).context("strata-admin mesh")?;
            if args.stats {
                println!("{}", report.line.to_json());
            }
        }
    }
    Ok(())
}
