//! PROTOCOL.md's worked numbers, checked against the real code: the Q24.8
//! rounding examples, the masked delta layout's bit order, and the per-voxel
//! edit formulas (re-implemented here from the document's text).

use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::{Region, StructureLibrary};
use strata_terrain::hash::chunk_hash;
use strata_terrain::material::ids;
use strata_terrain::{
    Chunk, ChunkPos, DenseChunk, Edit, EditContext, Fixed, FixedVec3, MaterialTable, Voxel,
    VoxelBox, VoxelPos, VoxelRead,
};

#[test]
fn q24_8_rounding_examples() {
    // (client float, Fixed sent) as PROTOCOL.md lists them.
    let examples: [(f64, i32); 10] = [
        (1.5, 384),
        (2.7, 691),
        (-2.7, -691),
        (0.1, 26),
        (1.0 / 512.0, 1),
        (-1.0 / 512.0, -1),
        (3.0 / 512.0, 2),
        (5.0 / 512.0, 3),
        (-5.0 / 512.0, -3),
        (-0.001, 0),
    ];
    for (v, raw) in examples {
        assert_eq!(Fixed::from_f64(v), Some(Fixed(raw)), "{v}");
        // An f32 widened to f64 rounds the same way.
        assert_eq!(Fixed::from_f64(v as f32 as f64).map(|f| f.0), Some(raw));
    }
    assert_eq!(Fixed::from_f64(f64::NAN), None);
    assert_eq!(Fixed::from_f64(f64::INFINITY), None);
    assert_eq!(
        Fixed::from_f64(8_388_608.0),
        None,
        "2^23 voxels overflow i32"
    );
    // Back to voxels: exact division, and floor by arithmetic shift.
    assert_eq!(Fixed(691).to_f64(), 2.69921875);
    assert_eq!(Fixed(-1).floor_voxel(), -1);
    assert_eq!(Fixed(-256).floor_voxel(), -1);
    assert_eq!(Fixed(-257).floor_voxel(), -2);
    assert_eq!(Fixed(511).floor_voxel(), 1);
    // Coordinates must stay below 2^22 voxels in magnitude.
    assert!(Fixed((1 << 30) - 1).in_coord_range());
    assert!(!Fixed(1 << 30).in_coord_range());
    assert!(!Fixed(-(1 << 30)).in_coord_range());
}

/// Plane index as PROTOCOL.md gives it.
fn index(x: usize, y: usize, z: usize) -> usize {
    x + 32 * y + 1024 * z
}

#[test]
fn masked_delta_bit_order() {
    // A base with a different byte everywhere.
    let density: Vec<u8> = (0..32768).map(|i| (i * 7 % 251) as u8).collect();
    let material: Vec<u8> = (0..32768).map(|i| (i % 5) as u8).collect();
    let base = Chunk::Dense(DenseChunk::from_planes(&density, &material).unwrap());

    // Density section: op 1 (replace), box (1,2,3)-(2,3,4), 2x2x2 = 8 voxels,
    // k = (x-1) + 2*((y-2) + 2*(z-3)). Set: (2,2,3) k=1, (1,3,3) k=2,
    // (1,2,4) k=4, (2,3,4) k=7, so the mask byte is 0b1001_0110.
    // Material section: op 3 (add), box (0,0,0)-(0,0,0), mask 1, value 5.
    let payload = vec![
        0x10, // masked layout, no compression
        1,
        1,
        2,
        3,
        2,
        3,
        4,
        0b1001_0110,
        10,
        20,
        30,
        40, // density
        3,
        0,
        0,
        0,
        0,
        0,
        0,
        0b0000_0001,
        5, // material
    ];
    let mut want_d = density.clone();
    want_d[index(2, 2, 3)] = 10;
    want_d[index(1, 3, 3)] = 20;
    want_d[index(1, 2, 4)] = 30;
    want_d[index(2, 3, 4)] = 40;
    let mut want_m = material.clone();
    want_m[index(0, 0, 0)] = want_m[index(0, 0, 0)].wrapping_add(5);
    let want = Chunk::Dense(DenseChunk::from_planes(&want_d, &want_m).unwrap());

    let delta = ChunkDelta {
        pos: ChunkPos::new(0, 0, 0),
        from_version: 1,
        to_version: 2,
        base_hash: chunk_hash(&base),
        target_hash: chunk_hash(&want),
        payload,
    };
    assert_eq!(delta.apply(&base).unwrap(), want);
}

/// The pre-edit world of the kernel checks: a stone slope under air, a
/// bedrock voxel, and densities that vary from voxel to voxel.
struct Slope;

impl VoxelRead for Slope {
    fn voxel(&self, p: VoxelPos) -> Voxel {
        if p == VoxelPos::new(2, 1, 0) {
            return Voxel::new(255, ids::BEDROCK);
        }
        let d = (128 - 40 * p.y + 7 * p.x - 3 * p.z).clamp(0, 255) as u8;
        let m = if d >= 128 { ids::STONE } else { ids::AIR };
        Voxel::new(d, m)
    }
}

fn isqrt(n: u64) -> u64 {
    let mut r = (n as f64).sqrt() as u64;
    while r * r > n {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= n {
        r += 1;
    }
    r
}

const Q16: i64 = 1 << 16;

/// d: distance from the centre to the voxel, in 1/65536 voxel.
fn dist(c: FixedVec3, p: VoxelPos) -> i64 {
    let d = |v: i32, c: Fixed| (v as i64) * 256 - c.0 as i64;
    let sq = d(p.x, c.x).pow(2) + d(p.y, c.y).pow(2) + d(p.z, c.z).pow(2);
    isqrt((sq as u64) << 16) as i64
}

fn rim(d: i64, r: Fixed) -> i64 {
    let big_r = (r.0 as i64) << 8;
    ((big_r - d) * Q16 / (2 * Q16)).clamp(0, Q16)
}

fn falloff(d: i64, r: Fixed) -> i64 {
    let big_r = (r.0 as i64) << 8;
    if d >= big_r {
        0
    } else {
        (big_r - d) * Q16 / big_r
    }
}

/// The new voxel by PROTOCOL.md's formulas.
fn documented(edit: &Edit, p: VoxelPos, old: Voxel, hardness: impl Fn(u8) -> i64) -> Voxel {
    if old.material == ids::BEDROCK {
        return old;
    }
    match *edit {
        Edit::Mine {
            center,
            radius,
            strength,
        } => {
            let amount =
                strength as i64 * rim(dist(center, p), radius) * 16 / hardness(old.material) / Q16;
            let density = (old.density as i64 - amount.min(255)).max(0);
            Voxel::new(density as u8, old.material)
        }
        Edit::Explode {
            center,
            radius,
            power,
        } => {
            let f = falloff(dist(center, p), radius);
            let damage = (power as i64 * f * f) >> 32;
            Voxel::new((old.density as i64 - damage).max(0) as u8, old.material)
        }
        Edit::Build {
            center,
            radius,
            material,
            strength,
        } => {
            let amount = strength as i64 * rim(dist(center, p), radius) / Q16;
            if amount == 0 {
                return old;
            }
            let density = (old.density as i64 + amount).min(255) as u8;
            let m = if old.density >= 128 {
                old.material
            } else {
                material
            };
            Voxel::new(density, m)
        }
        Edit::Smooth {
            center,
            radius,
            strength,
        } => {
            let f = falloff(dist(center, p), radius);
            if f == 0 {
                return old;
            }
            let weight = strength as i64 * f / 255;
            let mut sum = 0i64;
            let mut counts = [0u32; 256];
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let n = Slope.voxel(VoxelPos::new(p.x + dx, p.y + dy, p.z + dz));
                        sum += n.density as i64;
                        if n.density >= 128 {
                            counts[n.material as usize] += 1;
                        }
                    }
                }
            }
            let mean = (2 * sum + 27) / 54;
            let old_d = old.density as i64;
            let density = (old_d + (mean - old_d) * weight / Q16).clamp(0, 255) as u8;
            let mut m = old.material;
            if old.density < 128 && density >= 128 {
                // Most common solid neighbour material, lowest id on ties.
                let best = (0..256)
                    .filter(|&i| counts[i] > 0)
                    .max_by_key(|&i| (counts[i], std::cmp::Reverse(i)));
                if let Some(i) = best {
                    m = i as u8;
                }
            }
            Voxel::new(density, m)
        }
        _ => unreachable!("only sphere edits are checked here"),
    }
}

#[test]
fn sphere_edits_follow_the_documented_formulas() {
    let materials = MaterialTable::default();
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    let hardness = |m: u8| materials.get(m).map_or(16, |x| x.hardness as i64);
    let center = FixedVec3::new(Fixed(300), Fixed(-100), Fixed(77));
    let radius = Fixed(4 * 256 + 64);
    let edits = [
        Edit::Mine {
            center,
            radius,
            strength: 200,
        },
        Edit::Explode {
            center,
            radius,
            power: 700,
        },
        Edit::Build {
            center,
            radius,
            material: ids::BRICK,
            strength: 90,
        },
        Edit::Smooth {
            center,
            radius,
            strength: 255,
        },
    ];
    let area = VoxelBox::from_corners(VoxelPos::new(-8, -8, -8), VoxelPos::new(8, 8, 8));
    for edit in edits {
        let mut region = Region::from_source(&Slope, area, Voxel::AIR);
        let (bbox, changed) = edit.apply_region(&mut region, &ctx).unwrap();
        // The affected box: ceil(c - r) ..= floor(c + r) on each axis.
        let lo = |c: Fixed| (c.0 - radius.0).div_euclid(256) + ((c.0 - radius.0) % 256 != 0) as i32;
        let hi = |c: Fixed| (c.0 + radius.0).div_euclid(256);
        assert_eq!(
            bbox.min,
            VoxelPos::new(lo(center.x), lo(center.y), lo(center.z))
        );
        assert_eq!(
            bbox.max,
            VoxelPos::new(hi(center.x), hi(center.y), hi(center.z))
        );
        assert!(changed > 0, "{edit:?} changed nothing");
        for z in -7..=7 {
            for y in -7..=7 {
                for x in -7..=7 {
                    let p = VoxelPos::new(x, y, z);
                    let old = Slope.voxel(p);
                    let want = if bbox.contains(p) {
                        documented(&edit, p, old, hardness)
                    } else {
                        old
                    };
                    assert_eq!(region.voxel(p), want, "{edit:?} at {p:?}");
                }
            }
        }
    }
}
