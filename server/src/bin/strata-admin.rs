//! `strata-admin`: administration of Strata worlds and data. Argument
//! parsing and printing only; the commands live in `strata_server::admin`.

use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};
use strata_server::admin::check::{self, CheckArgs};
use strata_server::admin::cluster_cmd::{self, ClusterCommand};
use strata_server::admin::export_mesh::{self, ExportMeshArgs};
use strata_server::admin::generate::{self, GenerateArgs};
use strata_server::admin::mesh_cmd::{self, MeshArgs};
use strata_server::admin::render_map::{self, RenderMapArgs};
use strata_server::admin::token_cmd::{self, TokenIssueArgs};
use strata_server::admin::verify_acks::{self, VerifyAcksArgs};
use strata_server::admin::{access_cmd, inspect, players, snapshot_cmd, stats, zones_cmd};

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
    /// Snapshots: create (online or offline), verify, restore, diff.
    #[command(subcommand)]
    Snapshot(snapshot_cmd::SnapshotCommand),
    /// Look at one piece of the world.
    #[command(subcommand)]
    Inspect(InspectCommand),
    /// World size, modified chunks, sequence, store size (and live sessions online).
    Stats(stats::StatsArgs),
    /// Protected zones, where players may not edit.
    #[command(subcommand)]
    Zones(zones_cmd::ZonesCommand),
    /// Live sessions of a running server.
    #[command(subcommand)]
    Players(PlayersCommand),
    /// Close every session of a player on a running server.
    Kick(players::KickArgs),
    /// Ban a player: refused at every Hello until the ban ends (`--until`)
    /// or is lifted, and (online) the player's live sessions end now.
    /// Works on a running server or a stopped one's data dir.
    Ban(access_cmd::BanArgs),
    /// Lift a player's ban.
    Unban(access_cmd::PlayerArgs),
    /// List bans and token revocations.
    Bans(access_cmd::ListArgs),
    /// Check that the stored world holds every edit in an ack log.
    ///
    /// The ack log (from `strata-bots --ack-log`) has one JSON object per
    /// line: {"seq":17,"chunks":[{"x":16,"y":1,"z":16,"version":4}]}. Each
    /// edit must be in the store's edit log with those chunk versions, and
    /// each chunk stored at that version or later. Prints one JSON report
    /// line; exits non-zero if anything acknowledged is missing. Stop the
    /// server first.
    VerifyAcks(VerifyAcksArgs),
    /// A cluster of nodes sharing a PostgreSQL store.
    ///
    /// `status` lists every region ever claimed: its owner, epoch, lease
    /// state, seconds since its last renewal, and edits per second over a
    /// short sample. The nodes keep running.
    #[command(subcommand)]
    Cluster(ClusterCommand),
}

#[derive(Debug, Subcommand)]
enum InspectCommand {
    /// A chunk's version, hash, material histogram, and generated or modified.
    Chunk(inspect::InspectChunkArgs),
}

#[derive(Debug, Subcommand)]
enum PlayersCommand {
    /// One line per session: id, player, role, position.
    List(players::PlayersArgs),
}

#[derive(Debug, Subcommand)]
enum TokenCommand {
    /// Mint a token signed with the data dir's secret; prints it on stdout.
    Issue(TokenIssueArgs),
    /// Refuse every token of a player issued until now (a leaked token);
    /// tokens issued from the next second on work. Online, the player's
    /// live sessions end now.
    Revoke(access_cmd::PlayerArgs),
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
        Command::Snapshot(cmd) => snapshot(cmd)?,
        Command::Inspect(InspectCommand::Chunk(args)) => print!(
            "{}",
            inspect::run(&args).context("strata-admin inspect chunk")?
        ),
        Command::Stats(args) => print!("{}", stats::run(&args).context("strata-admin stats")?),
        Command::Zones(cmd) => print!(
            "{}",
            zones_cmd::render(&zones_cmd::run(&cmd).context("strata-admin zones")?)
        ),
        Command::Players(PlayersCommand::List(args)) => print!(
            "{}",
            players::render(&players::list(&args).context("strata-admin players list")?)
        ),
        Command::Ban(args) => print!(
            "{}",
            access_cmd::render(&access_cmd::ban(&args).context("strata-admin ban")?)
        ),
        Command::Unban(args) => print!(
            "{}",
            access_cmd::render(&access_cmd::unban(&args).context("strata-admin unban")?)
        ),
        Command::Bans(args) => print!(
            "{}",
            access_cmd::render(&access_cmd::list(&args).context("strata-admin bans")?)
        ),
        Command::Token(TokenCommand::Revoke(args)) => print!(
            "{}",
            access_cmd::render(&access_cmd::revoke(&args).context("strata-admin token revoke")?)
        ),
        Command::Kick(args) => {
            let n = players::kick(&args).context("strata-admin kick")?;
            println!("kicked {n} session(s) of {}", args.name);
        }
        Command::Cluster(ClusterCommand::Status(args)) => print!(
            "{}",
            cluster_cmd::render(
                &cluster_cmd::run(&args).context("strata-admin cluster status")?,
                args.json
            )
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

fn snapshot(cmd: snapshot_cmd::SnapshotCommand) -> anyhow::Result<()> {
    use snapshot_cmd::SnapshotCommand as S;
    match cmd {
        S::Create(args) => {
            let c = snapshot_cmd::create(&args).context("strata-admin snapshot create")?;
            println!(
                "snapshot at seq {}: {} chunks, {} bytes, written to {}",
                c.seq,
                c.chunks,
                c.bytes,
                args.out.display()
            );
        }
        S::Verify(args) => {
            let r =
                snapshot_cmd::verify_file(&args.file).context("strata-admin snapshot verify")?;
            if !r.is_ok() {
                for issue in &r.issues {
                    println!("{issue}");
                }
                if r.issues_dropped > 0 {
                    println!("... and {} more", r.issues_dropped);
                }
                anyhow::bail!(
                    "{} is corrupt: {} problem(s)",
                    args.file.display(),
                    r.issues.len() as u64 + r.issues_dropped
                );
            }
            let seq = r.header.map_or(0, |h| h.seq);
            println!("ok: seq {seq}, {} chunks, every checksum matches", r.chunks);
        }
        S::Restore(args) => {
            let n = snapshot_cmd::restore(&args).context("strata-admin snapshot restore")?;
            println!("restored {n} chunks into {}", args.data_dir.display());
        }
        S::Diff(args) => print!(
            "{}",
            snapshot_cmd::render_diff(
                &snapshot_cmd::diff_files(&args).context("strata-admin snapshot diff")?
            )
        ),
    }
    Ok(())
}
