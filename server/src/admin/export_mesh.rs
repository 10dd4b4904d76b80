//! `strata-admin export-mesh`: the mesh of a region of a stopped server's
//! world, welded across chunks, as PLY, OBJ or GLB for Blender or MeshLab.
//!
//! Each chunk is meshed exactly as the server meshes it (its voxels plus a
//! one-voxel apron from its neighbours, stored or generated) at one level
//! of detail, so at LOD 0 a chunk's mesh hash is the server's collision mesh
//! hash for that chunk version (`--chunk-hashes` prints them). The chunk
//! meshes are then welded by vertex key into one indexed mesh in world
//! voxel coordinates. The mesh is open only where the region cuts the
//! surface: at its side, top and bottom faces.
//!
//! Chunks are generated a z-slab at a time (with the slabs on either side
//! for the apron), so memory stays bounded by three slabs whatever the
//! region's depth.

use std::io::BufWriter;
use std::path::PathBuf;

use rayon::prelude::*;
use serde::Serialize;
use strata_terrain::mesh::volume::{weld, VolumeError};
use strata_terrain::mesh::{try_mesh_chunk, Mesh, MeshError, MeshOptions, Neighborhood, MAX_LOD};
use strata_terrain::ChunkPos;
use thiserror::Error;

use super::export::{stage_output, write_mesh, ExportError, ExportFormat, MeshRef};
use super::world_source::{
    progress_bar, ChunkBox, OfflineArgs, OfflineWorld, RegionArgs, WorldSourceError, WorldView,
    MAX_REGION_CHUNKS, MAX_REGION_COORD,
};

/// Arguments of `strata-admin export-mesh`.
#[derive(Debug, Clone, clap::Args)]
pub struct ExportMeshArgs {
    #[command(flatten)]
    pub world: OfflineArgs,
    #[command(flatten)]
    pub region: RegionArgs,
    /// Chunk rows Y0 Y1 (inclusive) [default: the world's whole height].
    #[arg(long, num_args = 2, value_names = ["Y0", "Y1"], allow_negative_numbers = true)]
    pub rows: Option<Vec<i32>>,
    /// Level of detail 0..=3: cells span 2^K voxels per axis.
    #[arg(long, value_name = "K", default_value_t = 0,
          value_parser = clap::value_parser!(u8).range(0..=MAX_LOD as i64))]
    pub lod: u8,
    /// Output mesh; the format follows the extension: .ply, .obj or .glb.
    #[arg(long, value_name = "FILE.ply|FILE.obj|FILE.glb")]
    pub out: PathBuf,
    /// Print one JSON line per chunk on stdout: position, version, triangles
    /// and mesh hash (at LOD 0, the server's collision mesh hash).
    #[arg(long)]
    pub chunk_hashes: bool,
    /// Print one JSON line of totals on stdout.
    #[arg(long)]
    pub stats: bool,
}

/// Why `export-mesh` failed. Nothing is written on error.
#[derive(Debug, Error)]
pub enum ExportMeshError {
    #[error(transparent)]
    World(#[from] WorldSourceError),
    #[error(transparent)]
    Export(#[from] ExportError),
    #[error("--rows needs Y0 Y1 with Y0 <= Y1, at most {MAX_REGION_CHUNKS} rows and each within ±{MAX_REGION_COORD}, got {0:?}")]
    BadRows(Vec<i32>),
    #[error("meshing: {0}")]
    Mesh(#[from] MeshError),
    #[error("welding: {0}")]
    Weld(#[from] VolumeError),
    #[error("cannot write {path:?}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// One chunk's mesh before welding.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChunkHash {
    pub x: i32,
    pub y: i32,
    pub z: i32,
    /// Stored version, 0 when the chunk is as generated.
    pub version: u64,
    pub triangles: usize,
    /// [`Mesh::hash`] of the chunk-local mesh.
    pub mesh_hash: u64,
}

/// Totals of an export.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ExportStats {
    pub chunks: u64,
    pub empty_chunks: u64,
    pub vertices: usize,
    pub triangles: usize,
    pub lod: u8,
}

/// What `export-mesh` did.
#[derive(Debug, Clone)]
pub struct ExportReport {
    pub stats: ExportStats,
    /// Every chunk of the region in z, y, x order.
    pub chunks: Vec<ChunkHash>,
    /// The welded mesh that was written.
    pub mesh: Mesh,
}

/// The chunk box of the export: region columns by `rows` (or the world's).
fn export_box(args: &ExportMeshArgs, world: &OfflineWorld) -> Result<ChunkBox, ExportMeshError> {
    let [x0, z0, x1, z1] = args.region.columns()?;
    let (y0, y1) = match &args.rows {
        Some(r) => match r.as_slice() {
            &[a, b]
                if a <= b
                    && a.unsigned_abs().max(b.unsigned_abs())
                        <= MAX_REGION_COORD.unsigned_abs()
                    && b - a < MAX_REGION_CHUNKS =>
            {
                (a, b)
            }
            _ => return Err(ExportMeshError::BadRows(r.clone())),
        },
        None => {
            let rows = world.rows();
            (*rows.start(), *rows.end())
        }
    };
    Ok(ChunkBox {
        min: ChunkPos::new(x0, y0, z0),
        max: ChunkPos::new(x1, y1, z1),
    })
}

/// Meshes every chunk of `bx` at `lod`; returns the meshes (empty ones
/// too) with their positions and versions, in z, y, x order.
pub fn mesh_region(
    world: &dyn WorldView,
    bx: ChunkBox,
    lod: u8,
    show_progress: bool,
) -> Result<Vec<(ChunkPos, u64, Mesh)>, ExportMeshError> {
    let opts = MeshOptions {
        lod,
        ..MeshOptions::default()
    };
    opts.validate()?;
    let around = bx.grown(1);
    let mut w = world.world(around)?;
    let bar = progress_bar(show_progress, Some(bx.count()), "meshing");
    let mut out = Vec::new();
    for z in bx.min.z..=bx.max.z {
        // Keep generated chunks of slabs z-1..=z+1 only.
        w.evict_generated(|p| (z - 1..=z + 1).contains(&p.z));
        for dz in -1..=1 {
            world.pregenerate(&mut w, &around.slab(z + dz));
        }
        let slab = bx.slab(z);
        let meshes: Vec<Result<(ChunkPos, u64, Mesh), MeshError>> = slab
            .par_iter()
            .map(|&pos| {
                let nb = Neighborhood::from_world(&w, pos);
                let mesh = try_mesh_chunk(&nb, &opts);
                bar.inc(1);
                mesh.map(|m| (pos, w.peek(pos).map_or(0, |c| c.version), m))
            })
            .collect();
        for m in meshes {
            out.push(m?);
        }
    }
    bar.finish_and_clear();
    Ok(out)
}

/// Runs the command; `show_progress` allows a progress bar on stderr.
pub fn run(args: &ExportMeshArgs, show_progress: bool) -> Result<ExportReport, ExportMeshError> {
    let format = ExportFormat::from_path(&args.out)?;
    let world = OfflineWorld::open(&args.world)?;
    let bx = export_box(args, &world)?;
    let write_err = |source| ExportMeshError::Write {
        path: args.out.clone(),
        source,
    };
    let tmp = stage_output(&args.out).map_err(write_err)?;

    let meshes = mesh_region(&world, bx, args.lod, show_progress)?;
    let chunks: Vec<ChunkHash> = meshes
        .iter()
        .map(|(pos, version, m)| ChunkHash {
            x: pos.x,
            y: pos.y,
            z: pos.z,
            version: *version,
            triangles: m.triangle_count(),
            mesh_hash: m.hash(),
        })
        .collect();
    let mesh = weld(meshes.into_iter().map(|(pos, _, m)| (pos.origin(), m)))?;

    let mut w = BufWriter::new(tmp.as_file());
    write_mesh(format, MeshRef::from(&mesh), &mut w)?;
    drop(w);
    crate::durable::persist_temp(tmp, &args.out).map_err(write_err)?;
    let stats = ExportStats {
        chunks: bx.count(),
        empty_chunks: chunks.iter().filter(|c| c.triangles == 0).count() as u64,
        vertices: mesh.vertex_count(),
        triangles: mesh.triangle_count(),
        lod: args.lod,
    };
    Ok(ExportReport {
        stats,
        chunks,
        mesh,
    })
}
