//! `strata-admin generate`: generate a region of the world and print its
//! statistics. Needs no server and no data dir: a first look at the terrain.

use std::time::Instant;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkGenerator, ChunkPos, MaterialTable, CHUNK_SIZE};

/// Largest region edge in chunks, to keep a typo from running for hours.
pub const MAX_REGION_CHUNKS: i32 = 256;
/// Largest |chunk coordinate| of a region: the chunks of the voxels an
/// edit may reach, far from overflowing any voxel coordinate.
pub const MAX_REGION_COORD: i32 = strata_terrain::edit::fixed::COORD_LIMIT_VOXELS / CHUNK_SIZE;

/// Checks a region `[x0, z0, x1, z1]` of chunk columns: ordered, at most
/// [`MAX_REGION_CHUNKS`] a side, every coordinate within
/// ±[`MAX_REGION_COORD`].
pub fn check_region(region: [i32; 4]) -> anyhow::Result<()> {
    let [x0, z0, x1, z1] = region;
    anyhow::ensure!(
        region
            .iter()
            .all(|c| c.unsigned_abs() <= MAX_REGION_COORD.unsigned_abs()),
        "region coordinates must lie within ±{MAX_REGION_COORD} chunks"
    );
    anyhow::ensure!(
        x0 <= x1 && z0 <= z1,
        "region X0 Z0 X1 Z1 must have X0 <= X1 and Z0 <= Z1"
    );
    anyhow::ensure!(
        x1 - x0 < MAX_REGION_CHUNKS && z1 - z0 < MAX_REGION_CHUNKS,
        "region is larger than {MAX_REGION_CHUNKS} chunks on a side"
    );
    Ok(())
}

#[derive(Debug, Args)]
pub struct GenerateArgs {
    /// World seed (default: the generator's default seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Region in chunk columns: X0 Z0 X1 Z1 (inclusive); all heights of the world.
    #[arg(long, num_args = 4, value_names = ["X0", "Z0", "X1", "Z1"], allow_negative_numbers = true, default_values_t = [-4, -4, 3, 3])]
    pub region: Vec<i32>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print one JSON line instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// What a generated region holds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegionStats {
    pub seed: u64,
    pub generator_version: u32,
    pub chunks: u64,
    pub uniform_chunks: u64,
    pub solid_voxels: u64,
    /// Solid voxels per material name, most first.
    pub materials: Vec<(String, u64)>,
    pub min_surface_y: f64,
    pub max_surface_y: f64,
    pub seconds: f64,
    pub threads: usize,
}

/// Generates every chunk of the region in parallel and gathers statistics.
pub fn generate_region(
    params: GenParams,
    region: [i32; 4],
    threads: Option<usize>,
    progress: bool,
) -> anyhow::Result<RegionStats> {
    check_region(region)?;
    let [x0, z0, x1, z1] = region;
    let seed = params.seed;
    let generator = Generator::fractal(params.clone())?;
    let (y0, y1) = (
        params.min_y.div_euclid(CHUNK_SIZE) - 1,
        params.max_y.div_euclid(CHUNK_SIZE),
    );
    let positions: Vec<ChunkPos> = (z0..=z1)
        .flat_map(|z| (x0..=x1).flat_map(move |x| (y0..=y1).map(move |y| ChunkPos::new(x, y, z))))
        .collect();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()?;
    let bar = if progress {
        ProgressBar::new(positions.len() as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(ProgressStyle::with_template(
        "{bar:40} {pos}/{len} chunks {elapsed}",
    )?);
    let start = Instant::now();
    let per_chunk: Vec<(bool, [u32; 256])> = pool.install(|| {
        positions
            .par_iter()
            .map(|&p| {
                let c = generator.generate(p);
                bar.inc(1);
                (c.is_uniform(), c.solid_histogram())
            })
            .collect()
    });
    let seconds = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    let mut hist = [0u64; 256];
    for (_, h) in &per_chunk {
        for (acc, n) in hist.iter_mut().zip(h) {
            *acc += *n as u64;
        }
    }
    let table = MaterialTable::default();
    let mut materials: Vec<(String, u64)> = hist
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(id, n)| {
            (
                table
                    .get(id as u8)
                    .map_or(format!("#{id}"), |m| m.name.clone()),
                *n,
            )
        })
        .collect();
    materials.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut min_surface_y = f64::INFINITY;
    let mut max_surface_y = f64::NEG_INFINITY;
    for z in (z0 * CHUNK_SIZE..(z1 + 1) * CHUNK_SIZE).step_by(4) {
        for x in (x0 * CHUNK_SIZE..(x1 + 1) * CHUNK_SIZE).step_by(4) {
            let h = generator.surface_height(x, z);
            min_surface_y = min_surface_y.min(h);
            max_surface_y = max_surface_y.max(h);
        }
    }
    Ok(RegionStats {
        seed,
        generator_version: strata_terrain::gen::GENERATOR_VERSION,
        chunks: per_chunk.len() as u64,
        uniform_chunks: per_chunk.iter().filter(|(u, _)| *u).count() as u64,
        solid_voxels: hist.iter().sum(),
        materials,
        min_surface_y,
        max_surface_y,
        seconds,
        threads: pool.current_num_threads(),
    })
}

/// Runs the command: generate, then print a table or one JSON line.
pub fn run(args: &GenerateArgs) -> anyhow::Result<()> {
    let mut params = GenParams::default();
    if let Some(seed) = args.seed {
        params.seed = seed;
    }
    let region: [i32; 4] = args
        .region
        .as_slice()
        .try_into()
        .map_err(|_| anyhow::anyhow!("--region takes 4 numbers"))?;
    let stats = generate_region(params, region, args.threads, !args.json)?;
    if args.json {
        println!("{}", serde_json::to_string(&stats)?);
        return Ok(());
    }
    println!(
        "seed {} (generator v{})",
        stats.seed, stats.generator_version
    );
    println!(
        "{} chunks in {:.3} s on {} threads ({:.0} µs per chunk per thread)",
        stats.chunks,
        stats.seconds,
        stats.threads,
        stats.seconds * 1e6 * stats.threads as f64 / stats.chunks.max(1) as f64
    );
    println!(
        "{} uniform ({:.0}%), surface height {:.1} .. {:.1}",
        stats.uniform_chunks,
        100.0 * stats.uniform_chunks as f64 / stats.chunks.max(1) as f64,
        stats.min_surface_y,
        stats.max_surface_y
    );
    println!("solid voxels by material:");
    for (name, n) in &stats.materials {
        println!(
            "  {name:<10} {n:>12} ({:.2}%)",
            100.0 * *n as f64 / stats.solid_voxels.max(1) as f64
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn region_stats_are_plausible_and_deterministic() {
        let a = generate_region(GenParams::default(), [0, 0, 1, 1], Some(1), false).unwrap();
        let b = generate_region(GenParams::default(), [0, 0, 1, 1], Some(2), false).unwrap();
        assert_eq!(
            (a.chunks, a.uniform_chunks, &a.materials),
            (b.chunks, b.uniform_chunks, &b.materials)
        );
        assert!(a.uniform_chunks > 0 && a.uniform_chunks < a.chunks);
        let names: Vec<_> = a.materials.iter().map(|(n, _)| n.as_str()).collect();
        for expected in ["stone", "bedrock", "dirt", "grass"] {
            assert!(
                names.contains(&expected),
                "{expected} missing from {names:?}"
            );
        }
        assert!(a.min_surface_y < a.max_surface_y);
    }

    #[test]
    fn bad_regions_are_refused() {
        assert!(generate_region(GenParams::default(), [1, 0, 0, 0], None, false).is_err());
        assert!(generate_region(
            GenParams::default(),
            [0, 0, MAX_REGION_CHUNKS, 0],
            None,
            false
        )
        .is_err());
        // Coordinates past the edit limit, whose differences and voxel
        // coordinates overflow i32, are refused before any arithmetic.
        for region in [
            [i32::MIN, 0, i32::MAX, 0],
            [i32::MAX, 0, i32::MAX, 0],
            [MAX_REGION_COORD + 1, 0, MAX_REGION_COORD + 1, 0],
            [0, -MAX_REGION_COORD - 1, 0, -MAX_REGION_COORD - 1],
        ] {
            assert!(check_region(region).is_err(), "{region:?}");
            let args = crate::admin::world_source::RegionArgs {
                region: region.to_vec(),
            };
            assert!(args.columns().is_err(), "{region:?}");
        }
        let edge = [MAX_REGION_COORD; 4];
        assert!(check_region(edge).is_ok());
        assert!(check_region([-MAX_REGION_COORD, 0, -MAX_REGION_COORD + 1, 0]).is_ok());
    }
}
