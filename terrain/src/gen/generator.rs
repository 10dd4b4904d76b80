//! The world generator: heights, caves and layers combined into chunks.

use std::sync::Arc;

use super::caves::{row_at, Lattice, NoiseField};
use super::columns::ColumnHeights;
use super::height::{FractalHills, HeightSource};
use super::layers::Layers;
use super::noise::floor_i64;
use super::params::{GenError, GenParams};
use crate::chunk::{Chunk, DenseChunk, Voxel};
use crate::material::ids;
use crate::pos::{local_index, ChunkPos, CHUNK_SIZE};
use crate::world::ChunkGenerator;

/// Seed layers of the 3D fields (see [`super::noise::sub_seed`]).
const CAVE_LAYER: u64 = 2;
const ORE_LAYER: u64 = 3;

const SIZE: usize = CHUNK_SIZE as usize;

/// Bedrock voxel: indestructible in the default material table.
pub const BEDROCK: Voxel = Voxel::solid(ids::BEDROCK);

/// Deterministic seeded world generator; see the module docs for the algorithm.
#[derive(Debug, Clone)]
pub struct Generator {
    params: GenParams,
    source: HeightSource,
    hills: FractalHills,
    /// `None` when `cave_octaves` is 0.
    caves: Option<NoiseField>,
    ore: NoiseField,
    layers: Layers,
    /// Surface heights are clamped to `floor..=ceiling`.
    floor: f64,
    ceiling: f64,
    /// Highest surface anywhere.
    max_surface: f64,
    /// Voxels this far above their column's surface are density 0: 128/k.
    air_band: f64,
    /// Recent columns' surface heights, shared by clones.
    columns: Arc<ColumnHeights>,
}

impl Generator {
    /// A generator for `params` with heights from `source`.
    pub fn new(params: GenParams, source: HeightSource) -> Result<Self, GenError> {
        params.validate()?;
        let p = &params;
        let hills = FractalHills::new(p);
        let caves = (p.cave_octaves > 0).then(|| {
            NoiseField::new(
                p.seed,
                CAVE_LAYER,
                p.cave_octaves,
                p.cave_wavelength,
                p.cave_flatness,
            )
        });
        let ore = NoiseField::new(p.seed, ORE_LAYER, 1, p.ore_wavelength, 1.0);
        let layers = Layers::new(p);
        let floor = layers.bedrock_max_top() as f64;
        let air_band = 128.0 / p.surface_sharpness;
        let ceiling = p.max_y as f64 - air_band - 1.0;
        let max_surface = source.max_raw_height(&hills).clamp(floor, ceiling);
        Ok(Self {
            hills,
            caves,
            ore,
            layers,
            floor,
            ceiling,
            max_surface,
            air_band,
            source,
            params,
            columns: Arc::default(),
        })
    }

    /// Fractal hills from `params`.
    pub fn fractal(params: GenParams) -> Result<Self, GenError> {
        Self::new(params, HeightSource::Fractal)
    }

    pub fn params(&self) -> &GenParams {
        &self.params
    }

    pub fn source(&self) -> &HeightSource {
        &self.source
    }

    /// Surface height of the column at `(x, z)`, in voxels: the terrain
    /// (before caves) is solid at `y <= surface_height`. For top-down maps.
    pub fn surface_height(&self, x: i32, z: i32) -> f64 {
        self.height(x as i64, z as i64)
    }

    /// The highest surface height anywhere: chunks above it (plus the
    /// density band) are uniform air.
    pub fn max_surface_height(&self) -> f64 {
        self.max_surface
    }

    /// Bedrock fills `y < bedrock_top(x, z)` in that column.
    pub fn bedrock_top(&self, x: i32, z: i32) -> i64 {
        self.layers.bedrock_top(x as i64, z as i64)
    }

    fn height(&self, x: i64, z: i64) -> f64 {
        self.source
            .raw_height(&self.hills, x, z)
            .clamp(self.floor, self.ceiling)
    }

    /// Generates a chunk; `fast` enables the uniform shortcuts, which the
    /// tests switch off to prove they change nothing.
    pub(crate) fn generate_with(&self, pos: ChunkPos, fast: bool) -> Chunk {
        let s = CHUNK_SIZE as i64;
        let (ox, oy, oz) = (pos.x as i64 * s, pos.y as i64 * s, pos.z as i64 * s);
        let top = oy + s - 1;
        if fast && top < self.layers.bedrock_min_top() {
            return Chunk::uniform(BEDROCK);
        }
        if fast && oy as f64 > self.max_surface + self.air_band {
            return Chunk::uniform(Voxel::AIR);
        }
        let heights = self.columns.get(pos.x, pos.z, || {
            let mut heights = [0.0f64; SIZE * SIZE];
            for (i, h) in heights.iter_mut().enumerate() {
                *h = self.height(ox + (i % SIZE) as i64, oz + (i / SIZE) as i64);
            }
            heights
        });
        let heights = &heights[..];
        let hmax = heights.iter().copied().fold(f64::MIN, f64::max);
        if fast && oy as f64 > hmax + self.air_band {
            return Chunk::uniform(Voxel::AIR);
        }
        let mut chunk = Chunk::Dense(self.fill((ox, oy, oz), heights, hmax));
        chunk.compact();
        chunk
    }

    /// The per-voxel pass. Density is the smaller of the surface term
    /// `k·(h − y)` and the cave term `kc·(threshold + guard(depth) − cave)`,
    /// offset to the 127.5 surface and floored: a voxel is solid exactly when
    /// both terms are ≥ 0.
    ///
    /// Column data is prepared one z-row at a time so the voxel loop runs in
    /// memory order (x fastest) without branches that depend on the terrain:
    /// cave walls made such branches mispredict constantly.
    fn fill(&self, o: (i64, i64, i64), heights: &[f64], hmax: f64) -> DenseChunk {
        let p = &self.params;
        let (k, kc) = (p.surface_sharpness, p.cave_sharpness);
        let (threshold, guard, inv_guard_depth) =
            (p.cave_threshold, p.cave_guard, 1.0 / p.cave_guard_depth);
        let ore_threshold = p.ore_threshold;
        // Fields are only sampled where they can matter (an exact shortcut):
        // stone, hence ore, lies at least `soil` voxels under the top voxel.
        let needs_ore = (o.1 as f64) <= hmax - self.layers.soil() as f64;
        let cave = self.caves.as_ref().map(|f| Lattice::sample(f, o));
        let ore = needs_ore.then(|| Lattice::sample(&self.ore, o));
        let needs_bedrock = o.1 < self.layers.bedrock_max_top();

        let mut d = DenseChunk::filled(Voxel::AIR);
        let mut h = [0.0f64; SIZE];
        let mut y_top = [0i64; SIZE];
        let mut bedrock_top = [i64::MIN; SIZE];
        for lz in 0..SIZE {
            h.copy_from_slice(&heights[lz * SIZE..(lz + 1) * SIZE]);
            for lx in 0..SIZE {
                y_top[lx] = floor_i64(h[lx]);
                if needs_bedrock {
                    bedrock_top[lx] = self.layers.bedrock_top(o.0 + lx as i64, o.2 + lz as i64);
                }
            }
            let cave_rows = cave.as_ref().map(|l| l.z_rows(lz));
            let ore_rows = ore.as_ref().map(|l| l.z_rows(lz));
            // Rows above every column's surface band are air (already filled).
            let row_top = h.iter().fold(f64::MIN, |m, &v| m.max(v)) + self.air_band;
            for ly in 0..SIZE {
                let y = o.1 + ly as i64;
                if y as f64 > row_top {
                    break;
                }
                let yf = y as f64;
                let row = local_index(0, ly, lz);
                // Density first, a whole row in one branch-free loop that
                // the compiler vectorises (the same operations per voxel).
                let density_row = &mut d.density[row..row + SIZE];
                match &cave_rows {
                    Some(rows) => {
                        let cave_at = row_at(rows, ly);
                        for ((dn, &hc), &cv) in density_row.iter_mut().zip(&h).zip(&cave_at) {
                            let depth = hc - yf;
                            let g = guard * (1.0 - (depth * inv_guard_depth).clamp(0.0, 1.0));
                            *dn = density_of((k * depth).min(kc * (threshold + g - cv)));
                        }
                    }
                    None => {
                        for (dn, &hc) in density_row.iter_mut().zip(&h) {
                            *dn = density_of(k * (hc - yf));
                        }
                    }
                }
                let ore_at = ore_rows.as_ref().map(|r| row_at(r, ly));
                let material_row = &mut d.material[row..row + SIZE];
                for (lx, (m, &dn)) in material_row.iter_mut().zip(&*density_row).enumerate() {
                    let is_ore = ore_at.as_ref().is_some_and(|o| o[lx] > ore_threshold);
                    *m = if dn == 0 {
                        ids::AIR
                    } else {
                        self.layers.material(y_top[lx] - y, is_ore)
                    };
                }
                if needs_bedrock {
                    for (lx, (dn, m)) in density_row.iter_mut().zip(material_row).enumerate() {
                        if y < bedrock_top[lx] {
                            *dn = BEDROCK.density;
                            *m = BEDROCK.material;
                        }
                    }
                }
            }
        }
        d
    }
}

/// floor(128 + v) clamped to 0..=255: on the clamped, non-negative range
/// truncation equals floor (no libm call).
#[inline]
fn density_of(v: f64) -> u8 {
    (128.0 + v).clamp(0.0, 255.0) as u8
}

impl ChunkGenerator for Generator {
    fn generate(&self, pos: ChunkPos) -> Chunk {
        self.generate_with(pos, true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_paths_match_the_full_pass() {
        let g = Generator::fractal(GenParams::with_seed(3)).unwrap();
        let min_chunk = g.params().min_y.div_euclid(CHUNK_SIZE);
        let sky = (g.max_surface_height() as i32).div_euclid(CHUNK_SIZE) + 1;
        for y in [
            min_chunk - 2,
            min_chunk - 1,
            min_chunk,
            0,
            1,
            sky,
            sky + 1,
            9,
        ] {
            for (x, z) in [(0, 0), (-3, 7)] {
                let pos = ChunkPos::new(x, y, z);
                assert_eq!(
                    g.generate_with(pos, true),
                    g.generate_with(pos, false),
                    "{pos:?}"
                );
            }
        }
        assert!(g.generate(ChunkPos::new(0, min_chunk - 2, 0)).is_uniform());
        assert!(g.generate(ChunkPos::new(0, 9, 0)).is_uniform());
    }
}
