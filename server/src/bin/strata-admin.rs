//! `strata-admin`: administration of Strata worlds and data. Argument
//! parsing and printing only; the commands live in `strata_server::admin`.

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use strata_server::admin::generate::{self, GenerateArgs};
use strata_server::admin::mesh_cmd::{self, MeshArgs};
use strata_server::admin::token_cmd::{self, TokenIssueArgs};
use strata_server::admin::verify_acks::{self, VerifyAcksArgs};

/// Administration tools for Strata.
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
    /// Generate a region of the world and print its statistics.
    Generate(GenerateArgs),
    /// Auth tokens.
    #[command(subcommand)]
    Token(TokenCommand),
    /// Check that the stored world holds every edit in an ack log.
    ///
    /// The ack log (from `strata-bots --ack-log`) has one JSON object per
    /// line: {"seq":17,"chunks":[{"x":16,"y":1,"z":16,"version":4}]}. Each
    /// edit must be in the store's edit log with those chunk versions, and
    /// each chunk stored at that version or later. Prints one JSON report
    /// line; exits non-zero if anything acknowledged is missing. Stop the
    /// server first.
    VerifyAcks(VerifyAcksArgs),
}

#[derive(Debug, Subcommand)]
enum TokenCommand {
    /// Mint a token signed with the data dir's secret; prints it on stdout.
    Issue(TokenIssueArgs),
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
        Command::Generate(args) => generate::run(&args).context("strata-admin generate")?,
        Command::Token(TokenCommand::Issue(args)) => println!(
            "{}",
            token_cmd::issue(&args).context("strata-admin token issue")?
        ),
        Command::VerifyAcks(args) => {
            let report = verify_acks::run(&args).context("strata-admin verify-acks")?;
            println!("{}", serde_json::to_string(&report)?);
            if !report.ok() {
                anyhow::bail!(
                    "{} of {} acknowledged edits are not in the stored world (first: {:?})",
                    report.failure_count,
                    report.records,
                    report.failures.first()
                );
            }
        }
    }
    Ok(())
}
