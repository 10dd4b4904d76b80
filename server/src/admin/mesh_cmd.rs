//! `strata-admin mesh`: meshes a raw u8 density volume file into one welded
//! mesh, optionally writes it as PLY or OBJ, and reports timing as JSON.
//!
//! Every input check (output format, dimensions, file size) happens before
//! the volume is read or meshed, and the output appears only once complete
//! (written to a temporary file in the same directory, then renamed).

use std::io::{BufWriter, IsTerminal};
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Serialize;
use strata_terrain::mesh::volume::{
    mesh_volume_with_progress, VolumeError, VolumeGrid, VolumeMeshOptions, VolumeStats,
    MAX_VOLUME_LOD,
};
use thiserror::Error;

use super::export::{write_mesh, ExportError, ExportFormat, MeshRef};

/// Most worker threads `--threads` accepts.
pub const MAX_THREADS: u32 = 1024;
/// Volumes with at least this many chunks get a progress bar (on a terminal).
pub const PROGRESS_MIN_CHUNKS: u64 = 64;
/// Default isovalue: the chunk mesher's (127.5, which no u8 sample equals).
pub const DEFAULT_ISO: f32 = strata_terrain::mesh::DEFAULT_ISO;

/// Arguments of `strata-admin mesh`.
#[derive(Debug, Clone, clap::Args)]
pub struct MeshArgs {
    /// Raw volume: one u8 density per sample, x fastest, then y, then z.
    #[arg(long, value_name = "FILE")]
    pub volume: PathBuf,
    /// Samples along x, y and z; the file must hold exactly X*Y*Z bytes.
    #[arg(long, num_args = 3, value_names = ["X", "Y", "Z"], required = true)]
    pub dims: Vec<u64>,
    /// Isovalue: a sample is solid when its density is greater.
    #[arg(long, default_value_t = DEFAULT_ISO)]
    pub iso: f32,
    /// Level of detail 0..=3: cells span 2^K samples per axis.
    #[arg(long, value_name = "K", default_value_t = 0,
          value_parser = clap::value_parser!(u8).range(0..=MAX_VOLUME_LOD as i64))]
    pub lod: u8,
    /// Worker threads for meshing [default: all cores].
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=MAX_THREADS as i64))]
    pub threads: Option<u32>,
    /// Output mesh; the format follows the extension: .ply (binary), .obj or .glb.
    #[arg(long, value_name = "FILE.ply|FILE.obj|FILE.glb")]
    pub out: Option<PathBuf>,
    /// Print one JSON line of statistics on stdout.
    #[arg(long)]
    pub stats: bool,
}

/// Why `strata-admin mesh` failed.
#[derive(Debug, Error)]
pub enum MeshCmdError {
    #[error("--dims needs exactly 3 values (X Y Z), got {0}")]
    DimsCount(usize),
    #[error(transparent)]
    Volume(#[from] VolumeError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error("cannot read volume file {path:?}: {error}")]
    ReadVolume {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error(
        "volume file {path:?} is {actual} bytes but --dims {dims:?} need {expected} bytes \
         (one byte per sample)"
    )]
    FileSize {
        path: PathBuf,
        dims: [u64; 3],
        expected: u64,
        actual: u64,
    },
    #[error("cannot write output file {path:?}: {error}")]
    WriteOutput {
        path: PathBuf,
        error: std::io::Error,
    },
    #[error("cannot start {threads} worker threads: {reason}")]
    ThreadPool { threads: u32, reason: String },
}

/// The `--stats` line: exactly these fields, in this order.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MeshStatsLine {
    pub cells: u64,
    pub vertices: u64,
    pub triangles: u64,
    /// Wall time of meshing alone (no file reading or writing).
    pub mesh_seconds: f64,
    pub threads: usize,
}

/// What a run did.
#[derive(Debug, Clone)]
pub struct MeshReport {
    pub stats: VolumeStats,
    pub line: MeshStatsLine,
    pub written: Option<PathBuf>,
}

fn dims_of(args: &MeshArgs) -> Result<[u64; 3], MeshCmdError> {
    <[u64; 3]>::try_from(args.dims.as_slice()).map_err(|_| MeshCmdError::DimsCount(args.dims.len()))
}

/// Runs the command. `show_progress` allows a progress bar on stderr (it is
/// still hidden for small volumes or when stderr is not a terminal).
pub fn run(args: &MeshArgs, show_progress: bool) -> Result<MeshReport, MeshCmdError> {
    // Cheap checks first, so bad input fails before any work.
    let format = args
        .out
        .as_deref()
        .map(ExportFormat::from_path)
        .transpose()?;
    let dims = dims_of(args)?;
    let expected = VolumeGrid::sample_count(dims)? as u64;
    let opts = VolumeMeshOptions {
        iso: args.iso,
        lod: args.lod,
        ..Default::default()
    };
    if opts.lod > MAX_VOLUME_LOD {
        return Err(VolumeError::BadLod {
            lod: opts.lod,
            max: MAX_VOLUME_LOD,
        }
        .into());
    }
    if !opts.iso.is_finite() {
        return Err(VolumeError::BadIso(opts.iso).into());
    }
    let read_err = |error| MeshCmdError::ReadVolume {
        path: args.volume.clone(),
        error,
    };
    let actual = std::fs::metadata(&args.volume).map_err(read_err)?.len();
    if actual != expected {
        return Err(MeshCmdError::FileSize {
            path: args.volume.clone(),
            dims,
            expected,
            actual,
        });
    }
    // Claim the output location before the long part, so an unwritable
    // directory is reported now, not after meshing.
    let staged = match (&args.out, format) {
        (Some(out), Some(format)) => Some((stage_output(out)?, out, format)),
        _ => None,
    };

    let data = std::fs::read(&args.volume).map_err(read_err)?;
    let grid = VolumeGrid::new(dims, &data)?;
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = args.threads {
        builder = builder.num_threads(n as usize);
    }
    let pool = builder.build().map_err(|e| MeshCmdError::ThreadPool {
        threads: args.threads.unwrap_or(0),
        reason: e.to_string(),
    })?;

    let bar = progress_bar(show_progress, grid.chunk_count(opts.lod));
    let tick = || bar.inc(1);
    let (result, seconds) = pool.install(|| {
        let start = Instant::now();
        let result = mesh_volume_with_progress(&grid, &opts, &tick);
        (result, start.elapsed().as_secs_f64())
    });
    bar.finish_and_clear();
    let meshed = result?;

    let written = match staged {
        Some((tmp, out, format)) => {
            let write_err = |error| MeshCmdError::WriteOutput {
                path: out.clone(),
                error,
            };
            let mut w = BufWriter::new(tmp.as_file());
            write_mesh(format, MeshRef::from(&meshed.mesh), &mut w)?;
            drop(w);
            crate::durable::persist_temp(tmp, out).map_err(write_err)?;
            Some(out.clone())
        }
        None => None,
    };
    let s = meshed.stats;
    let line = MeshStatsLine {
        cells: s.cells,
        vertices: s.vertices,
        triangles: s.triangles,
        mesh_seconds: seconds,
        threads: pool.current_num_threads(),
    };
    Ok(MeshReport {
        stats: s,
        line,
        written,
    })
}

/// A temporary file next to `out`, renamed onto it once complete.
fn stage_output(out: &Path) -> Result<tempfile::NamedTempFile, MeshCmdError> {
    super::export::stage_output(out).map_err(|error| MeshCmdError::WriteOutput {
        path: out.to_path_buf(),
        error,
    })
}

fn progress_bar(wanted: bool, chunks: u64) -> ProgressBar {
    if !wanted || chunks < PROGRESS_MIN_CHUNKS || !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(chunks), ProgressDrawTarget::stderr());
    if let Ok(style) = ProgressStyle::with_template("meshing {bar:40} {pos}/{len} chunks {eta}") {
        bar.set_style(style);
    }
    bar
}

impl MeshStatsLine {
    /// The single JSON line printed by `--stats`.
    pub fn to_json(&self) -> String {
        // Serialising plain numbers cannot fail; fall back to a debug dump
        // rather than panic if it ever did.
        serde_json::to_string(self).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::admin::ply::read_ply;

    fn args(dir: &Path, dims: [u64; 3], out: Option<&str>) -> MeshArgs {
        MeshArgs {
            volume: dir.join("v.raw"),
            dims: dims.to_vec(),
            iso: DEFAULT_ISO,
            lod: 0,
            threads: Some(2),
            out: out.map(|o| dir.join(o)),
            stats: true,
        }
    }

    /// A solid ball in the middle of a 20³ volume.
    fn ball(dir: &Path) {
        let mut v = Vec::new();
        for z in 0..20i32 {
            for y in 0..20i32 {
                for x in 0..20i32 {
                    let d2 = (x - 10).pow(2) + (y - 9).pow(2) + (z - 10).pow(2);
                    v.push(if d2 < 36 { 220 } else { 10 });
                }
            }
        }
        std::fs::write(dir.join("v.raw"), v).unwrap();
    }

    #[test]
    fn meshes_and_writes_ply() {
        let dir = tempfile::tempdir().unwrap();
        ball(dir.path());
        let report = run(&args(dir.path(), [20, 20, 20], Some("m.ply")), false).unwrap();
        assert_eq!(report.line.cells, 19 * 19 * 19);
        assert_eq!(report.line.threads, 2);
        assert!(report.line.triangles > 0);
        let back = read_ply(&std::fs::read(dir.path().join("m.ply")).unwrap()).unwrap();
        assert_eq!(back.positions.len() as u64, report.line.vertices);
        assert_eq!(back.indices.len() as u64, 3 * report.line.triangles);
        let json: serde_json::Value = serde_json::from_str(&report.line.to_json()).unwrap();
        assert_eq!(json["cells"], 19 * 19 * 19);
    }

    #[test]
    fn bad_input_fails_before_touching_the_output() {
        let dir = tempfile::tempdir().unwrap();
        ball(dir.path());
        let err = run(&args(dir.path(), [20, 20, 21], Some("m.ply")), false).unwrap_err();
        assert!(matches!(
            err,
            MeshCmdError::FileSize {
                expected: 8400,
                actual: 8000,
                ..
            }
        ));
        let err = run(&args(dir.path(), [20, 20, 20], Some("m.stl")), false).unwrap_err();
        assert!(matches!(
            err,
            MeshCmdError::Export(ExportError::UnknownExtension { .. })
        ));
        let err = run(&args(dir.path(), [0, 20, 20], None), false).unwrap_err();
        assert!(matches!(
            err,
            MeshCmdError::Volume(VolumeError::ZeroDim { axis: 'x' })
        ));
        let mut a = args(dir.path(), [20, 20, 20], None);
        a.dims.pop();
        assert!(matches!(run(&a, false), Err(MeshCmdError::DimsCount(2))));
        let only_input = std::fs::read_dir(dir.path()).unwrap().count();
        assert_eq!(only_input, 1, "no output or temporary file left behind");
    }
}
