//! `strata-admin render-map`: a map of a stopped server's world, drawn with
//! the Marching Squares contours of `strata_terrain::contour`.
//!
//! - `--y LEVEL`: the horizontal slice at that height. Solid voxels take
//!   their material's colour; open air is dark blue and cave air (air with
//!   solid ground above it) dark brown; the solid/air boundary is drawn
//!   black where it borders open air and yellow around caves.
//! - `--top-down`: the surface seen from above, coloured by its material and
//!   shaded by height, with height contours every `--interval` voxels (every
//!   fifth heavier).
//!
//! The output follows the extension: `.png` (8-bit RGB) or `.svg`. It
//! appears only once complete (a temporary file renamed into place).

use std::io::BufWriter;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;
use strata_terrain::contour::{
    contour_levels, slice_grid_chunks, Axis, ContourError, GridView, Rect, SliceSpec, DENSITY_ISO,
    MAX_LEVELS,
};
use strata_terrain::{Chunk, ChunkPos, ChunkRead, MaterialTable, World, CHUNK_SIZE};
use thiserror::Error;

use super::export::stage_output;
use super::map::png::write_png;
use super::map::svg::write_svg;
use super::map::{palette, MapError, MapImage, MapLine, Rgb, MAX_SCALE};
use super::world_source::{
    progress_bar, ChunkBox, OfflineArgs, OfflineWorld, RegionArgs, WorldSourceError, WorldView,
};

/// Samples along a chunk column's side.
const COLUMN_SIDE: usize = CHUNK_SIZE as usize;
/// Samples per chunk column (32 x 32).
const COLUMN_AREA: usize = COLUMN_SIDE * COLUMN_SIDE;
/// Largest `--interval`.
pub const MAX_INTERVAL: u32 = 4096;

/// Arguments of `strata-admin render-map`.
#[derive(Debug, Clone, clap::Args)]
#[command(group(clap::ArgGroup::new("view").required(true).args(["y", "top_down"])))]
pub struct RenderMapArgs {
    #[command(flatten)]
    pub world: OfflineArgs,
    /// Horizontal slice at this height (voxels): solid by material, open air
    /// and cave air dark, ground outlines black and cave outlines yellow.
    #[arg(long, value_name = "LEVEL", allow_negative_numbers = true)]
    pub y: Option<i32>,
    /// Top-down view: the surface by material, shaded by height, with height
    /// contours every --interval voxels.
    #[arg(long)]
    pub top_down: bool,
    #[command(flatten)]
    pub region: RegionArgs,
    /// Voxels between height contours (top-down view).
    #[arg(long, value_name = "N", default_value_t = 8,
          value_parser = clap::value_parser!(u32).range(1..=MAX_INTERVAL as i64))]
    pub interval: u32,
    /// Pixels per voxel.
    #[arg(long, value_name = "S", default_value_t = 2,
          value_parser = clap::value_parser!(u32).range(1..=MAX_SCALE as i64))]
    pub scale: u32,
    /// Output image; the format follows the extension: .png or .svg.
    #[arg(long, value_name = "FILE.svg|FILE.png")]
    pub out: PathBuf,
}

/// Image formats of `render-map`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapFormat {
    Png,
    Svg,
}

/// Why `render-map` failed. Nothing is written on error.
#[derive(Debug, Error)]
pub enum RenderMapError {
    #[error("output file {0:?} must end in .png or .svg")]
    Extension(PathBuf),
    #[error(transparent)]
    World(#[from] WorldSourceError),
    #[error("contouring: {0}")]
    Contour(#[from] ContourError),
    #[error(transparent)]
    Map(#[from] MapError),
    #[error("heights {min}..{max} need {levels} contour levels at --interval {interval}; at most {MAX_LEVELS} (raise --interval)")]
    TooManyLevels {
        min: f32,
        max: f32,
        interval: u32,
        levels: u64,
    },
    #[error("cannot write {path:?}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}

/// What `render-map` drew.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapReport {
    pub width_px: u32,
    pub height_px: u32,
    pub lines: usize,
    /// Top-down: the contour levels drawn.
    pub levels: Vec<f32>,
    pub out: PathBuf,
}

impl MapFormat {
    pub fn from_path(path: &Path) -> Result<Self, RenderMapError> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        match ext.to_ascii_lowercase().as_str() {
            "png" => Ok(MapFormat::Png),
            "svg" => Ok(MapFormat::Svg),
            _ => Err(RenderMapError::Extension(path.to_path_buf())),
        }
    }
}

/// Runs the command; `show_progress` allows a progress bar on stderr.
pub fn run(args: &RenderMapArgs, show_progress: bool) -> Result<MapReport, RenderMapError> {
    let format = MapFormat::from_path(&args.out)?;
    let cols = args.region.columns()?;
    let world = OfflineWorld::open(&args.world)?;
    let (map, levels) = match args.y {
        Some(level) => (
            slice_map(&world, cols, level, args.scale, show_progress)?,
            Vec::new(),
        ),
        None => top_down_map(&world, cols, args.interval, args.scale, None, show_progress)?,
    };
    let (width_px, height_px) = map.pixel_size()?;
    let write_err = |source| RenderMapError::Write {
        path: args.out.clone(),
        source,
    };
    let tmp = stage_output(&args.out).map_err(write_err)?;
    let mut w = BufWriter::new(tmp.as_file());
    match format {
        MapFormat::Png => write_png(&map, &mut w)?,
        MapFormat::Svg => write_svg(&map, &mut w).map_err(write_err)?,
    }
    drop(w);
    crate::durable::persist_temp(tmp, &args.out).map_err(write_err)?;
    Ok(MapReport {
        width_px,
        height_px,
        lines: map.lines.len(),
        levels,
        out: args.out.clone(),
    })
}

/// The voxel rectangle (x, z) of a region of chunk columns.
fn voxel_rect(cols: [i32; 4]) -> Result<Rect, ContourError> {
    let [x0, z0, x1, z1] = cols;
    Rect::new(
        x0 * CHUNK_SIZE,
        z0 * CHUNK_SIZE,
        (x1 + 1) * CHUNK_SIZE - 1,
        (z1 + 1) * CHUNK_SIZE - 1,
    )
}

fn title(world: &dyn WorldView, cols: [i32; 4], view: &str) -> String {
    let [x0, z0, x1, z1] = cols;
    format!(
        "Strata world (seed {}): {view}; chunk columns x {x0}..={x1}, z {z0}..={z1}; x right, z down",
        world.params().seed
    )
}

/// Legend entries for the materials in `ids` (sorted, deduplicated).
fn material_legend(table: &MaterialTable, mut ids: Vec<u8>) -> Vec<(String, Rgb)> {
    ids.sort_unstable();
    ids.dedup();
    ids.into_iter()
        .map(|id| {
            let name = table
                .get(id)
                .map_or(format!("material #{id}"), |m| m.name.clone());
            (name, palette::material(table, id))
        })
        .collect()
}

/// The horizontal slice at `level` of the chunk columns `cols` (x0, z0,
/// x1, z1). Air under the surface (solid somewhere
/// above it in its column) is cave air, and an outline bordering cave air
/// is a cave outline.
pub fn slice_map(
    world: &dyn WorldView,
    cols: [i32; 4],
    level: i32,
    scale: u32,
    show_progress: bool,
) -> Result<MapImage, RenderMapError> {
    let [x0, z0, x1, z1] = cols;
    let row = level.div_euclid(CHUNK_SIZE);
    let layer = ChunkBox {
        min: ChunkPos::new(x0, row, z0),
        max: ChunkPos::new(x1, row, z1),
    };
    let w = world.world(layer)?;
    let region = voxel_rect(cols)?;
    let grid = slice_grid_chunks(
        &w,
        SliceSpec {
            axis: Axis::Y,
            level,
            region,
        },
    )?;
    let surface = region_surface(world, cols, row, show_progress)?;
    let table = MaterialTable::default();
    let (width, height) = (region.width(), region.height());
    let index = |u: i32, v: i32| -> Option<usize> {
        let (i, j) = (u - region.min[0], v - region.min[1]);
        let inside = (0..width as i32).contains(&i) && (0..height as i32).contains(&j);
        inside.then(|| j as usize * width as usize + i as usize)
    };
    let is_solid = |u: i32, v: i32| {
        grid.voxel(u, v)
            .is_some_and(|vox| f32::from(vox.density) > DENSITY_ISO)
    };
    let is_cave_air = |u: i32, v: i32| {
        !is_solid(u, v)
            && index(u, v)
                .and_then(|k| surface[k])
                .is_some_and(|(h, _)| h > level as f32)
    };
    let mut fill = Vec::with_capacity(width as usize * height as usize);
    let mut present = Vec::new();
    for v in region.min[1]..=region.max[1] {
        for u in region.min[0]..=region.max[0] {
            let vox = grid.voxel(u, v).unwrap_or_default();
            fill.push(if is_solid(u, v) {
                present.push(vox.material);
                palette::material(&table, vox.material)
            } else if is_cave_air(u, v) {
                palette::CAVE_AIR
            } else {
                palette::AIR
            });
        }
    }
    let lines = grid
        .contours(DENSITY_ISO)?
        .into_iter()
        .map(|p| {
            // The samples at the corners of the cell holding the first point.
            let cave = p.points.first().is_some_and(|&[x, z]| {
                let (u, v) = (x.floor() as i32, z.floor() as i32);
                [(u, v), (u + 1, v), (u, v + 1), (u + 1, v + 1)]
                    .iter()
                    .any(|&(u, v)| is_cave_air(u, v))
            });
            MapLine {
                color: if cave {
                    palette::CAVE_OUTLINE
                } else {
                    palette::SOLID_OUTLINE
                },
                width: 1.0,
                points: p.points,
                closed: p.closed,
            }
        })
        .collect();
    let mut legend = material_legend(&table, present);
    legend.push(("open air".into(), palette::AIR));
    legend.push(("cave air".into(), palette::CAVE_AIR));
    legend.push(("ground outline".into(), palette::SOLID_OUTLINE));
    legend.push(("cave outline".into(), palette::CAVE_OUTLINE));
    Ok(MapImage {
        origin: region.min,
        width,
        height,
        fill,
        lines,
        scale,
        title: title(world, cols, &format!("horizontal slice at y = {level}")),
        legend,
    })
}

/// The surface of one chunk column: per (x, z), x fastest, the height where
/// density crosses the iso level going down from the top of the world
/// (interpolated between the first solid sample and the one above it) and
/// that solid sample's material; `None` where the column holds no solid.
pub fn column_surface(
    src: &impl ChunkRead,
    cx: i32,
    cz: i32,
    rows: std::ops::RangeInclusive<i32>,
) -> Vec<Option<(f32, u8)>> {
    let mut surface = vec![None; COLUMN_AREA];
    let mut above = [0u8; COLUMN_AREA];
    let mut open = COLUMN_AREA;
    let crossing = |y: i32, solid: u8, above: u8| {
        let (s, a) = (f32::from(solid), f32::from(above));
        y as f32 + (s - DENSITY_ISO) / (s - a)
    };
    for cy in rows.rev() {
        if open == 0 {
            break;
        }
        let chunk = src.chunk_at(ChunkPos::new(cx, cy, cz));
        let top = cy * CHUNK_SIZE + CHUNK_SIZE - 1;
        if let Chunk::Uniform(v) = &*chunk {
            let solid = f32::from(v.density) > DENSITY_ISO;
            for (col, s) in surface.iter_mut().enumerate() {
                if s.is_some() {
                    continue;
                }
                if solid {
                    *s = Some((crossing(top, v.density, above[col]), v.material));
                    open -= 1;
                } else {
                    above[col] = v.density;
                }
            }
            continue;
        }
        for ly in (0..CHUNK_SIZE as usize).rev() {
            for col in 0..COLUMN_AREA {
                if surface[col].is_some() {
                    continue;
                }
                let v = chunk.get(col % COLUMN_SIDE, ly, col / COLUMN_SIDE);
                if f32::from(v.density) > DENSITY_ISO {
                    let y = cy * CHUNK_SIZE + ly as i32;
                    surface[col] = Some((crossing(y, v.density, above[col]), v.material));
                    open -= 1;
                } else {
                    above[col] = v.density;
                }
            }
        }
    }
    surface
}

/// The surface of every column of the region (see [`column_surface`]),
/// row-major with x fastest, scanning down to chunk row `lowest_row`.
fn region_surface(
    world: &dyn WorldView,
    cols: [i32; 4],
    lowest_row: i32,
    show_progress: bool,
) -> Result<Vec<Option<(f32, u8)>>, RenderMapError> {
    let [x0, z0, x1, z1] = cols;
    let top = *world.rows().end();
    let rows = lowest_row.min(top)..=top;
    let w: World = world.world(ChunkBox {
        min: ChunkPos::new(x0, *rows.start(), z0),
        max: ChunkPos::new(x1, *rows.end(), z1),
    })?;
    let columns: Vec<(i32, i32)> = (z0..=z1)
        .flat_map(|z| (x0..=x1).map(move |x| (x, z)))
        .collect();
    let bar = progress_bar(show_progress, Some(columns.len() as u64), "surface");
    let surfaces: Vec<Vec<Option<(f32, u8)>>> = columns
        .par_iter()
        .map(|&(cx, cz)| {
            let s = column_surface(&w, cx, cz, rows.clone());
            bar.inc(1);
            s
        })
        .collect();
    bar.finish_and_clear();
    let width = (x1 - x0 + 1) as usize * COLUMN_SIDE;
    let nx = (x1 - x0 + 1) as usize;
    let mut cells = vec![None; width * (z1 - z0 + 1) as usize * COLUMN_SIDE];
    for (k, s) in surfaces.iter().enumerate() {
        let (ox, oz) = ((k % nx) * COLUMN_SIDE, (k / nx) * COLUMN_SIDE);
        for (col, v) in s.iter().enumerate() {
            cells[(oz + col / COLUMN_SIDE) * width + ox + col % COLUMN_SIDE] = *v;
        }
    }
    Ok(cells)
}

/// The top-down view of the chunk columns `cols` (x0, z0, x1, z1) with
/// height contours every `interval` voxels. Heights are shaded over
/// `shade` (low, high), or over the region's own range when `None`: maps
/// drawn in tiles pass one range so the tiles' shades agree.
pub fn top_down_map(
    world: &dyn WorldView,
    cols: [i32; 4],
    interval: u32,
    scale: u32,
    shade: Option<(f32, f32)>,
    show_progress: bool,
) -> Result<(MapImage, Vec<f32>), RenderMapError> {
    let cells = region_surface(world, cols, *world.rows().start(), show_progress)?;
    let region = voxel_rect(cols)?;
    let (width, height) = (region.width() as usize, region.height() as usize);
    let found = cells.iter().flatten().map(|c| c.0);
    let (lo, hi) = found.fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), h| {
        (lo.min(h), hi.max(h))
    });
    // Columns without ground sit just under the lowest one found.
    let floor = if lo.is_finite() {
        lo - 1.0
    } else {
        world.params().min_y as f32
    };
    let heights: Vec<f32> = cells.iter().map(|c| c.map_or(floor, |c| c.0)).collect();

    let table = MaterialTable::default();
    let (shade_lo, shade_hi) = shade.unwrap_or((lo, hi));
    let span = (shade_hi - shade_lo).max(1.0);
    let fill = (0..height)
        .flat_map(|j| (0..width).map(move |i| (i, j)))
        .map(|(i, j)| {
            let Some((h, m)) = cells[j * width + i] else {
                return palette::VOID;
            };
            // Height tint plus light from the north-west.
            let nw = if i > 0 && j > 0 {
                heights[(j - 1) * width + i - 1]
            } else {
                h
            };
            let relief = 0.7
                + 0.45 * ((h - shade_lo) / span).clamp(0.0, 1.0)
                + 0.08 * (h - nw).clamp(-3.0, 3.0);
            palette::shade(palette::material(&table, m), relief)
        })
        .collect();

    let levels = contour_levels_between(lo, hi, interval)?;
    let grid = GridView::new(&heights, width as u32, height as u32, region.min)?;
    let mut lines = Vec::new();
    for lc in contour_levels(&grid, &levels)? {
        let index = (lc.level as i64 / i64::from(interval)) % palette::INDEX_EVERY == 0;
        let (color, width) = if index {
            (palette::INDEX_CONTOUR, 2.0)
        } else {
            (palette::CONTOUR, 1.0)
        };
        lines.extend(lc.polylines.into_iter().map(|p| MapLine {
            points: p.points,
            closed: p.closed,
            color,
            width,
        }));
    }
    let mut legend = material_legend(&table, cells.iter().flatten().map(|c| c.1).collect());
    legend.push((
        format!("height contour every {interval} voxels"),
        palette::CONTOUR,
    ));
    legend.push((
        format!(
            "index contour every {} voxels",
            i64::from(interval) * palette::INDEX_EVERY
        ),
        palette::INDEX_CONTOUR,
    ));
    let map = MapImage {
        origin: region.min,
        width: width as u32,
        height: height as u32,
        fill,
        lines,
        scale,
        title: title(
            world,
            cols,
            &format!("top-down, heights {lo:.1}..{hi:.1}, contours every {interval} voxels"),
        ),
        legend,
    };
    Ok((map, levels))
}

/// Multiples of `interval` within `lo..=hi`.
fn contour_levels_between(lo: f32, hi: f32, interval: u32) -> Result<Vec<f32>, RenderMapError> {
    if !(lo.is_finite() && hi.is_finite()) {
        return Ok(Vec::new());
    }
    let n = i64::from(interval);
    let (first, last) = (
        (lo as f64 / n as f64).ceil() as i64,
        (hi as f64 / n as f64).floor() as i64,
    );
    let count = (last - first + 1).max(0) as u64;
    if count > MAX_LEVELS as u64 {
        return Err(RenderMapError::TooManyLevels {
            min: lo,
            max: hi,
            interval,
            levels: count,
        });
    }
    Ok((first..=last).map(|k| (k * n) as f32).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_are_multiples_inside_the_range() {
        assert_eq!(
            contour_levels_between(-3.5, 17.0, 8).unwrap(),
            vec![0.0, 8.0, 16.0]
        );
        assert!(contour_levels_between(3.0, 5.0, 8).unwrap().is_empty());
        assert!(matches!(
            contour_levels_between(0.0, 5000.0, 1),
            Err(RenderMapError::TooManyLevels { .. })
        ));
        assert!(matches!(
            MapFormat::from_path(Path::new("m.jpg")),
            Err(RenderMapError::Extension(_))
        ));
    }
}
