//! `strata-admin`: administration of Strata worlds and data. Argument
//! parsing and printing only; the commands live in `strata_server::admin`.

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use strata_server::admin::check::{self, CheckArgs};
use strata_server::admin::export_mesh::{self, ExportMeshArgs};
use strata_server::admin::generate::{self, GenerateArgs};
use strata_server::admin::mesh_cmd::{self, MeshArgs};
use strata_server::admin::render_map::{self, RenderMapArgs};
use strata_server::admin::token_cmd::{self, TokenIssueArgs};

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
    /// Draw a map of a stopped server's world (PNG or SVG).
    ///
    /// `--y LEVEL` draws the horizontal slice at that height: solid voxels
    /// by material, open air dark blue, cave air (solid above it) dark
    /// brown, ground outlines black and cave outlines yellow (Marching
    /// Squares contours). `--top-down` draws the surface
    /// by material, shaded by height, with height contours every
    /// `--interval` voxels. The world is the data dir's stored chunks over
    /// its generator; the server must be stopped.
    RenderMap(RenderMapArgs),
    /// Export the mesh of a region of a stopped server's world.
    ///
    /// Chunks are meshed as the server meshes them (at LOD 0 their mesh
    /// hashes equal the server's collision mesh hashes; `--chunk-hashes`
    /// prints them) and welded into one mesh in world voxel coordinates,
    /// with normals and materials: binary PLY, OBJ, or glTF 2.0 binary
    /// (.glb, with per-vertex material colours) for Blender or MeshLab.
    ExportMesh(ExportMeshArgs),
    /// Verify a stopped server's whole store offline.
    ///
    /// Every chunk decodes, chunk versions agree with the edit log, the log
    /// has no gaps and ends at the metadata's last_seq, and no orphaned
    /// records exist. Prints one line per problem and exits non-zero when
    /// the store is not clean.
    Check(CheckArgs),
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
        Command::RenderMap(args) => {
            let report = render_map::run(&args, true).context("strata-admin render-map")?;
            println!("{}", serde_json::to_string(&report)?);
        }
        Command::ExportMesh(args) => {
            let report = export_mesh::run(&args, true).context("strata-admin export-mesh")?;
            if args.chunk_hashes {
                for c in &report.chunks {
                    println!("{}", serde_json::to_string(c)?);
                }
            }
            if args.stats {
                println!("{}", serde_json::to_string(&report.stats)?);
            }
        }
        Command::Check(args) => {
            let outcome = check::run(&args, true).context("strata-admin check")?;
            print!("{outcome}");
            anyhow::ensure!(
                outcome.is_ok(),
                "strata-admin check: the store is not clean ({} problems)",
                outcome.problem_count()
            );
        }
    }
    Ok(())
}
