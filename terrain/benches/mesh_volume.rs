//! Whole-volume meshing throughput (cells/s) on 256³ u8 volumes, one thread
//! and all threads; compare with VTK's vtkFlyingEdges3D via
//! scripts/vtk_flying_edges.py, which builds the same volumes.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use strata_terrain::mesh::volume::{mesh_volume, VolumeGrid, VolumeMeshOptions};

/// The two benchmark volumes, shared with scripts/vtk_flying_edges.py, which
/// builds the same bytes with numpy (integer arithmetic only, so both sides
/// agree exactly; each prints an FNV-1a hash of the bytes to compare).
mod volume_fields {
    /// Integer lattice hash to a byte.
    fn lattice(ix: u64, iy: u64, iz: u64, seed: u64) -> u64 {
        const M: u64 = 0xffff_ffff;
        let mut h =
            (ix * 0x27d4_eb2d + iy * 0x1656_67b1 + iz * 0x9e37_79b1 + seed * 0x85eb_ca77) & M;
        h ^= h >> 15;
        h = (h * 0x2c1b_3c6d) & M;
        h ^= h >> 12;
        h = (h * 0x297a_2d39) & M;
        h ^= h >> 15;
        h & 255
    }

    /// Integer smoothstep weight of `f` in `0..=c`, in `0..=c`.
    fn smooth(f: u64, c: u64) -> u64 {
        f * f * (3 * c - 2 * f) / (c * c)
    }

    /// 2D value noise in 0..=255 with cell size `c`.
    fn noise2(x: u64, z: u64, c: u64, seed: u64) -> u64 {
        let (ix, iz) = (x / c, z / c);
        let (wx, wz) = (smooth(x % c, c), smooth(z % c, c));
        let v = lattice(ix, iz, 0, seed) * (c - wx) * (c - wz)
            + lattice(ix + 1, iz, 0, seed) * wx * (c - wz)
            + lattice(ix, iz + 1, 0, seed) * (c - wx) * wz
            + lattice(ix + 1, iz + 1, 0, seed) * wx * wz;
        v / (c * c)
    }

    /// 3D value noise in 0..=255 with cell size `c`.
    fn noise3(x: u64, y: u64, z: u64, c: u64, seed: u64) -> u64 {
        let (ix, iy, iz) = (x / c, y / c, z / c);
        let w = [smooth(x % c, c), smooth(y % c, c), smooth(z % c, c)];
        let mut v = 0;
        for corner in 0..8u64 {
            let b = [corner & 1, (corner >> 1) & 1, corner >> 2];
            let weight: u64 = (0..3)
                .map(|a| if b[a] == 1 { w[a] } else { c - w[a] })
                .product();
            v += lattice(ix + b[0], iy + b[1], iz + b[2], seed) * weight;
        }
        v / (c * c * c)
    }

    /// Terrain-like field: a layered value-noise height field plus a 3D noise
    /// term that makes overhangs.
    pub fn terrain_volume(n: u64) -> Vec<u8> {
        let mut height = vec![0i64; (n * n) as usize];
        for z in 0..n {
            for x in 0..n {
                let h =
                    noise2(x, z, 64, 1) * 120 + noise2(x, z, 16, 2) * 40 + noise2(x, z, 4, 3) * 10;
                height[(z * n + x) as usize] = (n as i64 * 40 / 256) + (h / 255 * n / 256) as i64;
            }
        }
        let mut v = Vec::with_capacity((n * n * n) as usize);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let h = height[(z * n + x) as usize];
                    let d = 128 + 10 * (h - y as i64) + noise3(x, y, z, 32, 4) as i64 - 128;
                    v.push(d.clamp(0, 255) as u8);
                }
            }
        }
        v
    }

    /// A ball of radius 100·n/256 centred in the volume, density falling 4 per voxel.
    pub fn sphere_volume(n: u64) -> Vec<u8> {
        let r32 = (3200 * n / 256) as i64;
        let mut v = Vec::with_capacity((n * n * n) as usize);
        for z in 0..n as i64 {
            for y in 0..n as i64 {
                for x in 0..n as i64 {
                    let c = n as i64 - 1;
                    let d2 = (2 * x - c).pow(2) + (2 * y - c).pow(2) + (2 * z - c).pow(2);
                    let s = ((256 * d2) as u64).isqrt() as i64;
                    v.push((128 + ((r32 - s) >> 3)).clamp(0, 255) as u8);
                }
            }
        }
        v
    }

    /// FNV-1a 64 of the bytes: printed by both sides to prove they match.
    pub fn fnv1a(bytes: &[u8]) -> u64 {
        bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
            (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
        })
    }
}

const N: u64 = 256;

fn bench(c: &mut Criterion) {
    let volumes = [
        ("terrain", volume_fields::terrain_volume(N)),
        ("sphere", volume_fields::sphere_volume(N)),
    ];
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut group = c.benchmark_group("mesh_volume_256");
    group.sample_size(20);
    for (name, data) in &volumes {
        eprintln!("{name}: fnv1a {:016x}", volume_fields::fnv1a(data));
        let grid = VolumeGrid::new([N; 3], data).expect("valid volume");
        let opts = VolumeMeshOptions::default();
        group.throughput(Throughput::Elements(grid.cell_count(opts.lod)));
        for threads in [1, all] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let stats = pool
                .install(|| mesh_volume(&grid, &opts))
                .expect("meshes")
                .stats;
            eprintln!("{name} x{threads}: {stats:?}");
            group.bench_function(format!("{name}/threads_{threads}"), |b| {
                b.iter(|| pool.install(|| mesh_volume(&grid, &opts)).expect("meshes"))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
