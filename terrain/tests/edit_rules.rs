//! Edits on a chunked world give exactly the voxels of the flat reference,
//! never touch indestructible voxels, and refuse bad input without changes.

use std::collections::BTreeSet;
use std::sync::Arc;

use proptest::prelude::*;
use strata_terrain::edit::{structure::Structure, Region, StructureLibrary, MAX_POWER, MAX_RADIUS};
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{
    Chunk, ChunkGenerator, ChunkPos, Edit, EditContext, EditError, Fixed, FixedVec3, MaterialTable,
    Voxel, VoxelBox, VoxelPos, VoxelRead, World,
};

/// Rolling ground near y = 0 with layers, scattered bedrock voxels and a
/// uniform sky, so edits cross uniform and dense chunks alike.
#[derive(Debug)]
struct TestGround;

fn ground_voxel(p: VoxelPos) -> Voxel {
    let h = 2 + ((p.x.rem_euclid(13) * 3 + p.z.rem_euclid(7) * 5) % 9) - 4;
    let depth = h - p.y;
    let density = (128 + depth * 40).clamp(0, 255) as u8;
    let scatter =
        (p.x.wrapping_mul(73856093) ^ p.y.wrapping_mul(19349663) ^ p.z.wrapping_mul(83492791)) & 63;
    let material = if density == 0 {
        ids::AIR
    } else if scatter == 0 {
        ids::BEDROCK
    } else if depth <= 1 {
        ids::GRASS
    } else if depth <= 4 {
        ids::DIRT
    } else {
        ids::STONE
    };
    Voxel::new(density, material)
}

impl ChunkGenerator for TestGround {
    fn generate(&self, pos: ChunkPos) -> Chunk {
        if pos.y >= 1 {
            return Chunk::uniform(Voxel::AIR);
        }
        let mut c = Chunk::uniform(Voxel::AIR);
        let o = pos.origin();
        for z in 0..32 {
            for y in 0..32 {
                for x in 0..32 {
                    c.set(
                        x,
                        y,
                        z,
                        ground_voxel(VoxelPos::new(
                            o.x + x as i32,
                            o.y + y as i32,
                            o.z + z as i32,
                        )),
                    );
                }
            }
        }
        c.compact();
        c
    }
}

fn world() -> World {
    World::new(Arc::new(TestGround))
}

fn flat(ground: Voxel) -> World {
    World::new(Arc::new(FlatGenerator { ground }))
}

fn library() -> StructureLibrary {
    let mut lib = StructureLibrary::default();
    // An asymmetric arch so every rotation gives a different footprint.
    let arch = Structure::from_fn("arch", [7, 5, 3], |x, y, z| {
        if y == 4 || x == 0 || (x == 6 && z != 1) {
            Voxel::new(255, ids::BRICK)
        } else if y == 0 && x < 3 {
            Voxel::new(160, ids::STONE)
        } else {
            Voxel::new(0, 0)
        }
    })
    .unwrap();
    lib.insert(1, arch);
    lib
}

/// The material table and template library every edit here runs against.
struct Setup {
    materials: MaterialTable,
    structures: StructureLibrary,
}

impl Setup {
    fn new() -> Self {
        Self {
            materials: MaterialTable::default(),
            structures: library(),
        }
    }

    fn ctx(&self) -> EditContext<'_> {
        EditContext {
            materials: &self.materials,
            structures: &self.structures,
        }
    }
}

fn c(x: f64, y: f64, z: f64) -> FixedVec3 {
    FixedVec3::from_f64([x, y, z]).unwrap()
}

fn r(v: f64) -> Fixed {
    Fixed::from_f64(v).unwrap()
}

fn vp(p: VoxelPos, dx: i32, dy: i32, dz: i32) -> VoxelPos {
    p.checked_offset(dx, dy, dz).unwrap()
}

/// Edits centred on chunk faces, edges, corners and negative coordinates.
fn border_edits() -> Vec<Edit> {
    let mut v = Vec::new();
    for (x, y, z) in [
        (32.0, 0.0, 5.0),
        (31.5, -0.5, 31.5),
        (0.0, 0.0, 0.0),
        (-32.25, -1.0, -33.0),
        (-0.5, 2.0, 64.0),
    ] {
        v.push(Edit::Mine {
            center: c(x, y, z),
            radius: r(3.0),
            strength: 255,
        });
        v.push(Edit::Explode {
            center: c(x, y, z),
            radius: r(8.0),
            power: 600,
        });
        v.push(Edit::Build {
            center: c(x, y + 3.0, z),
            radius: r(4.0),
            material: ids::BRICK,
            strength: 200,
        });
        v.push(Edit::Smooth {
            center: c(x, y, z),
            radius: r(5.5),
            strength: 255,
        });
        let p = VoxelPos::new(x.floor() as i32, y.floor() as i32, z.floor() as i32);
        v.push(Edit::FillBox {
            min: vp(p, -3, -2, -4),
            max: vp(p, 2, 3, 1),
            material: ids::SAND,
        });
        v.push(Edit::ClearBox {
            min: vp(p, -1, -5, -2),
            max: vp(p, 4, 0, 3),
        });
        for rotation in 0..4 {
            v.push(Edit::PlaceStructure {
                structure: 1,
                origin: vp(p, -3, -1, -2),
                rotation,
            });
        }
    }
    v
}

fn check_equivalent(edit: &Edit) {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = world();
    let bbox = edit.validate(&ctx).unwrap();
    let around = VoxelBox {
        min: vp(bbox.min, -3, -3, -3),
        max: vp(bbox.max, 3, 3, 3),
    };
    w.load(around.chunks());
    let original = Region::from_source(&w, around, Voxel::AIR);
    let mut reference = original.clone();
    let (rbox, rcount) = edit.apply_region(&mut reference, &ctx).unwrap();
    let out = edit.apply(&mut w, &ctx).unwrap();
    assert_eq!(out.bbox, rbox);
    assert_eq!(out.voxels_changed, rcount, "{edit:?}");
    let mut differing_chunks = BTreeSet::new();
    for z in around.min.z..=around.max.z {
        for y in around.min.y..=around.max.y {
            for x in around.min.x..=around.max.x {
                let p = VoxelPos::new(x, y, z);
                assert_eq!(w.voxel(p), reference.voxel(p), "{edit:?} at {p:?}");
                if original.voxel(p) != reference.voxel(p) {
                    differing_chunks.insert(p.chunk());
                }
            }
        }
    }
    assert_eq!(
        w.loaded(),
        around.chunks().count(),
        "the edit loads no chunk outside its box"
    );
    let changed: BTreeSet<_> = out.changed.iter().map(|c| c.pos).collect();
    assert_eq!(changed, differing_chunks, "{edit:?}");
    for ch in &out.changed {
        assert_eq!((ch.from_version, ch.to_version), (0, 1));
        assert_eq!(w.peek(ch.pos).unwrap().version, 1);
        assert_eq!(*ch.before, TestGround.generate(ch.pos));
    }
}

#[test]
fn chunked_equals_flat_across_borders_corners_and_negatives() {
    let edits = border_edits();
    assert_eq!(edits.len(), 50);
    for e in &edits {
        check_equivalent(e);
    }
}

#[test]
fn edits_reach_every_touched_chunk() {
    // An explosion on a chunk corner reaches all eight chunks around it;
    // its box is open: voxels 8 away along an axis lie at the radius.
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = flat(Voxel::solid(ids::DIRT));
    let e = Edit::Explode {
        center: c(0.0, 0.0, 0.0),
        radius: r(8.0),
        power: 1024,
    };
    let out = e.apply(&mut w, &ctx).unwrap();
    assert_eq!(
        out.bbox,
        VoxelBox::from_corners(VoxelPos::new(-7, -7, -7), VoxelPos::new(7, 7, 7))
    );
    // Only the four chunks below y = 0 hold solid voxels to destroy.
    assert_eq!(out.changed.len(), 4);
    assert!(out.changed.iter().all(|c| c.pos.y == -1));
}

#[test]
fn seed_explosion_formula() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = flat(Voxel::solid(ids::STONE));
    let e = Edit::Explode {
        center: c(0.0, -16.0, 0.0),
        radius: r(8.0),
        power: 200,
    };
    e.apply(&mut w, &ctx).unwrap();
    // damage = power * (1 - d/r)^2: centre 200, d=4 -> 50, d=8 -> 0.
    assert_eq!(w.voxel(VoxelPos::new(0, -16, 0)).density, 55);
    assert_eq!(w.voxel(VoxelPos::new(4, -16, 0)).density, 205);
    assert_eq!(w.voxel(VoxelPos::new(0, -16, 8)).density, 255);
    assert_eq!(w.voxel(VoxelPos::new(0, -16, 0)).material, ids::STONE);
}

#[test]
fn mine_and_build_shapes() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let dirt = Voxel::solid(ids::DIRT);
    let mut w = flat(dirt);
    Edit::Mine {
        center: c(0.0, -10.0, 0.0),
        radius: r(4.0),
        strength: 255,
    }
    .apply(&mut w, &ctx)
    .unwrap();
    assert_eq!(
        w.voxel(VoxelPos::new(0, -10, 0)).density,
        0,
        "inside is cleared"
    );
    let rim = w.voxel(VoxelPos::new(3, -10, 0)).density;
    assert!(
        (120..=135).contains(&rim),
        "the surface sits one rim-half inside the radius: {rim}"
    );
    assert_eq!(
        w.voxel(VoxelPos::new(4, -10, 0)),
        dirt,
        "nothing at or beyond the radius changes"
    );
    // Stone is 40/16 as hard as dirt: one full-strength mine leaves it solid.
    let mut s = flat(Voxel::solid(ids::STONE));
    Edit::Mine {
        center: c(0.0, -10.0, 0.0),
        radius: r(4.0),
        strength: 255,
    }
    .apply(&mut s, &ctx)
    .unwrap();
    assert_eq!(
        s.voxel(VoxelPos::new(0, -10, 0)).density as i32,
        255 - 255 * 16 / 40
    );
    // Build in the air makes a solid ball of the building material.
    Edit::Build {
        center: c(0.0, 10.0, 0.0),
        radius: r(3.0),
        material: ids::BRICK,
        strength: 255,
    }
    .apply(&mut w, &ctx)
    .unwrap();
    assert_eq!(w.voxel(VoxelPos::new(0, 10, 0)), Voxel::solid(ids::BRICK));
    assert!(!w.voxel(VoxelPos::new(0, 15, 0)).is_solid());
}

#[test]
fn smooth_relaxes_a_step() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = flat(Voxel::solid(ids::DIRT));
    let out = Edit::Smooth {
        center: c(0.0, 0.0, 0.0),
        radius: r(4.0),
        strength: 255,
    }
    .apply(&mut w, &ctx)
    .unwrap();
    assert!(out.voxels_changed > 0);
    // The voxel just above the step gains density; the one below loses some.
    let above = w.voxel(VoxelPos::new(0, 0, 0));
    let below = w.voxel(VoxelPos::new(0, -1, 0));
    assert!(above.density > 0 && above.density < 128, "{above:?}");
    assert!(below.density > 128 && below.density < 255, "{below:?}");
}

#[test]
fn indestructible_voxels_never_change() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let bedrock = Voxel::solid(ids::BEDROCK);
    let mut w = flat(bedrock);
    let edits = [
        Edit::Mine {
            center: c(0.0, -1.0, 0.0),
            radius: MAX_RADIUS,
            strength: 255,
        },
        Edit::Explode {
            center: c(0.0, -1.0, 0.0),
            radius: MAX_RADIUS,
            power: MAX_POWER,
        },
        Edit::Smooth {
            center: c(0.0, 0.0, 0.0),
            radius: r(6.0),
            strength: 255,
        },
        Edit::ClearBox {
            min: VoxelPos::new(-5, -5, -5),
            max: VoxelPos::new(5, 5, 5),
        },
        Edit::FillBox {
            min: VoxelPos::new(-5, -5, -5),
            max: VoxelPos::new(5, 5, 5),
            material: ids::SAND,
        },
        Edit::PlaceStructure {
            structure: 1,
            origin: VoxelPos::new(-2, -3, -1),
            rotation: 1,
        },
    ];
    for e in &edits {
        e.apply(&mut w, &ctx).unwrap();
    }
    for p in [
        VoxelPos::new(0, -1, 0),
        VoxelPos::new(-5, -5, -5),
        VoxelPos::new(3, -32, 7),
        VoxelPos::new(-1, -2, 0),
    ] {
        assert_eq!(w.voxel(p), bedrock, "{p:?}");
    }
    // The fill above ground did change air, so the edits did run.
    assert_eq!(w.voxel(VoxelPos::new(0, 3, 0)), Voxel::solid(ids::SAND));
}

#[test]
fn bad_edits_are_refused_and_change_nothing() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = world();
    let far = Fixed::from_voxels(1 << 22);
    let origin = c(0.0, 0.0, 0.0);
    type Check = fn(&EditError) -> bool;
    let cases: Vec<(Edit, Check)> = vec![
        (
            Edit::Mine {
                center: FixedVec3::new(far, Fixed(0), Fixed(0)),
                radius: r(2.0),
                strength: 9,
            },
            |e| matches!(e, EditError::CoordinateOutOfRange { .. }),
        ),
        (
            Edit::Mine {
                center: FixedVec3::new(Fixed(i32::MAX), Fixed(0), Fixed(0)),
                radius: r(2.0),
                strength: 9,
            },
            |e| matches!(e, EditError::CoordinateOutOfRange { .. }),
        ),
        (
            Edit::Mine {
                center: origin,
                radius: Fixed(MAX_RADIUS.0 + 1),
                strength: 9,
            },
            |e| matches!(e, EditError::RadiusOutOfRange { .. }),
        ),
        (
            Edit::Build {
                center: origin,
                radius: Fixed(0),
                material: ids::DIRT,
                strength: 9,
            },
            |e| matches!(e, EditError::RadiusOutOfRange { .. }),
        ),
        (
            Edit::Smooth {
                center: origin,
                radius: Fixed(-256),
                strength: 9,
            },
            |e| matches!(e, EditError::RadiusOutOfRange { .. }),
        ),
        (
            Edit::Explode {
                center: origin,
                radius: r(4.0),
                power: MAX_POWER + 1,
            },
            |e| matches!(e, EditError::PowerOutOfRange { .. }),
        ),
        (
            Edit::Mine {
                center: origin,
                radius: r(4.0),
                strength: 0,
            },
            |e| *e == EditError::ZeroStrength,
        ),
        (
            Edit::Build {
                center: origin,
                radius: r(4.0),
                material: 99,
                strength: 9,
            },
            |e| *e == EditError::UnknownMaterial(99),
        ),
        (
            Edit::Build {
                center: origin,
                radius: r(4.0),
                material: ids::BEDROCK,
                strength: 9,
            },
            |e| *e == EditError::IndestructibleMaterial(ids::BEDROCK),
        ),
        (
            Edit::Build {
                center: origin,
                radius: r(4.0),
                material: ids::AIR,
                strength: 9,
            },
            |e| *e == EditError::AirBuild,
        ),
        (
            Edit::FillBox {
                min: VoxelPos::new(0, 0, 0),
                max: VoxelPos::new(200, 0, 0),
                material: ids::SAND,
            },
            |e| matches!(e, EditError::BoxTooLarge { .. }),
        ),
        (
            Edit::ClearBox {
                min: VoxelPos::new(1, 0, 0),
                max: VoxelPos::new(0, 0, 0),
            },
            |e| *e == EditError::InvertedBox,
        ),
        (
            Edit::ClearBox {
                min: VoxelPos::new(i32::MAX - 1, 0, 0),
                max: VoxelPos::new(i32::MAX, 0, 0),
            },
            |e| matches!(e, EditError::CoordinateOutOfRange { .. }),
        ),
        (
            Edit::PlaceStructure {
                structure: 7,
                origin: VoxelPos::new(0, 0, 0),
                rotation: 0,
            },
            |e| *e == EditError::UnknownStructure(7),
        ),
        (
            Edit::PlaceStructure {
                structure: 1,
                origin: VoxelPos::new(0, 0, 0),
                rotation: 4,
            },
            |e| *e == EditError::BadRotation(4),
        ),
        (
            Edit::PlaceStructure {
                structure: 1,
                origin: VoxelPos::new((1 << 22) - 3, 0, 0),
                rotation: 0,
            },
            |e| matches!(e, EditError::CoordinateOutOfRange { .. }),
        ),
    ];
    w.load(
        VoxelBox::from_corners(VoxelPos::new(-40, -40, -40), VoxelPos::new(40, 40, 40)).chunks(),
    );
    let snapshot = |w: &World| -> Vec<_> {
        (-2..=1)
            .map(|x| w.peek(ChunkPos::new(x, -1, 0)).cloned())
            .collect()
    };
    let before = snapshot(&w);
    for (edit, expect) in cases {
        let err = edit.apply(&mut w, &ctx).expect_err("must be refused");
        assert!(expect(&err), "{edit:?} gave {err:?}");
        assert!(!err.to_string().is_empty());
    }
    assert_eq!(w.modified().count(), 0);
    assert_eq!(before, snapshot(&w));
}

/// A chunk at the highest version (only stored bytes can put one there)
/// takes no edit: the `+ 1` would leave what a store holds.
#[test]
fn a_chunk_at_the_last_version_takes_no_edit() {
    use strata_terrain::world::MAX_CHUNK_VERSION;
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = flat(Voxel::AIR);
    let at = VoxelPos::new(8, 8, 8);
    let pos = at.chunk();
    w.load([pos]);
    let chunk = w.peek(pos).unwrap().chunk.clone();
    w.insert(pos, chunk.clone(), MAX_CHUNK_VERSION);
    let build = Edit::Build {
        center: FixedVec3::from_voxels(at.x, at.y, at.z),
        radius: r(2.0),
        material: ids::SAND,
        strength: 255,
    };
    assert_eq!(
        build.apply(&mut w, &ctx).expect_err("refused"),
        EditError::VersionExhausted { pos }
    );
    let after = w.peek(pos).unwrap();
    assert_eq!((after.version, &after.chunk), (MAX_CHUNK_VERSION, &chunk));
    w.insert(pos, chunk, MAX_CHUNK_VERSION - 1);
    let out = build.apply(&mut w, &ctx).unwrap();
    assert_eq!(out.changed[0].to_version, MAX_CHUNK_VERSION);
}

#[test]
fn structure_rotation_places_expected_voxels() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = flat(Voxel::AIR);
    let origin = VoxelPos::new(100, 40, -60);
    let out = Edit::PlaceStructure {
        structure: 1,
        origin,
        rotation: 1,
    }
    .apply(&mut w, &ctx)
    .unwrap();
    // The rotated footprint is 3 (x) by 5 (y) by 7 (z).
    assert_eq!(out.bbox.max, VoxelPos::new(102, 44, -54));
    // Template (0, 0, 0) lands at footprint (u=0, v=6) under rotation 1.
    assert_eq!(
        w.voxel(VoxelPos::new(100, 40, -54)),
        Voxel::new(255, ids::BRICK)
    );
    // Template (1, 0, 0) is stone at density 160, one step toward -z.
    assert_eq!(
        w.voxel(VoxelPos::new(100, 40, -55)),
        Voxel::new(160, ids::STONE)
    );
    // Template density 0 leaves the world alone.
    assert_eq!(w.voxel(VoxelPos::new(101, 42, -57)), Voxel::AIR);
}

/// A sphere whose box holds voxels, none of them inside the radius (where
/// every brush's weight is 0), is refused `NoVoxel` like an empty box:
/// accepted, it would change nothing and still be charged, numbered and
/// logged.
#[test]
fn a_sphere_touching_no_voxel_inside_its_radius_is_refused() {
    let setup = Setup::new();
    let at = |x: i32, y: i32, z: i32| FixedVec3::new(Fixed(x), Fixed(y), Fixed(z));
    let empty = [
        Edit::Mine {
            center: at(128, -256, 0),
            radius: Fixed(128),
            strength: 255,
        },
        Edit::Explode {
            center: at(128, -128, 128),
            radius: Fixed(182),
            power: 255,
        },
    ];
    for e in empty {
        assert_eq!(e.validate(&setup.ctx()), Err(EditError::NoVoxel), "{e:?}");
        let mut w = world();
        assert_eq!(
            e.apply(&mut w, &setup.ctx()).unwrap_err(),
            EditError::NoVoxel
        );
    }
    // A hair larger, the nearest voxel is inside: accepted, and it digs.
    let dig = Edit::Mine {
        center: at(128, -256, 0),
        radius: Fixed(129),
        strength: 255,
    };
    assert!(dig.validate(&setup.ctx()).is_ok());
    check_equivalent(&dig);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
    #[test]
    fn random_sphere_edits_match_reference(
        x in -70.0f64..70.0, y in -40.0f64..10.0, z in -70.0f64..70.0,
        radius in 0.25f64..9.0, kind in 0u8..4, amount in 1u8..=255,
    ) {
        let center = c(x, y, z);
        let radius = r(radius);
        let e = match kind {
            0 => Edit::Mine { center, radius, strength: amount },
            1 => Edit::Explode { center, radius, power: amount as u16 * 4 },
            2 => Edit::Build { center, radius, material: ids::ORE, strength: amount },
            _ => Edit::Smooth { center, radius, strength: amount },
        };
        // From the smallest radius allowed: a sphere holding no voxel
        // centre is refused, by both paths, changing nothing.
        let setup = Setup::new();
        if e.validate(&setup.ctx()) == Err(EditError::NoVoxel) {
            let mut w = world();
            prop_assert_eq!(e.apply(&mut w, &setup.ctx()).unwrap_err(), EditError::NoVoxel);
            prop_assert_eq!(w.loaded(), 0);
        } else {
            check_equivalent(&e);
        }
    }

    /// Tiny spheres between voxel centres, where empty boxes lie.
    #[test]
    fn tiny_spheres_never_panic(
        x in -70i32..70, y in -40i32..10, z in -70i32..70,
        fx in 0u8..4, fy in 0u8..4, fz in 0u8..4, raw in 64i32..128,
    ) {
        let quarter = |v: i32, f: u8| v as f64 + f as f64 / 4.0;
        let e = Edit::Mine {
            center: c(quarter(x, fx), quarter(y, fy), quarter(z, fz)),
            radius: Fixed(raw),
            strength: 255,
        };
        let setup = Setup::new();
        match e.validate(&setup.ctx()) {
            Err(EditError::NoVoxel) => {}
            Ok(_) => check_equivalent(&e),
            Err(other) => prop_assert!(false, "{other:?}"),
        }
    }
}

/// A voxel smoothing makes solid next to indestructible voxels and no
/// other solid ones stays below solid: no edit grows bedrock. Beside
/// placeable ones it takes theirs.
#[test]
fn smoothing_never_makes_indestructible_voxels() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let smooth = Edit::Smooth {
        center: c(0.0, 0.0, 0.0),
        radius: r(2.0),
        strength: 255,
    };
    // Bedrock below y = 0: the voxels of y = 0 would become solid.
    let mut w = flat(Voxel::solid(ids::BEDROCK));
    // Sand on the bedrock around (0, 0, 0), that voxel left empty: its
    // 3×3×3 mean is solid, its solid neighbours mostly bedrock.
    Edit::FillBox {
        min: VoxelPos::new(-1, 0, -1),
        max: VoxelPos::new(1, 0, 1),
        material: ids::SAND,
    }
    .apply(&mut w, &ctx)
    .unwrap();
    Edit::ClearBox {
        min: VoxelPos::new(0, 0, 0),
        max: VoxelPos::new(0, 0, 0),
    }
    .apply(&mut w, &ctx)
    .unwrap();
    smooth.apply(&mut w, &ctx).unwrap();
    let v = w.voxel(VoxelPos::new(0, 0, 0));
    assert!(v.is_solid(), "{v:?}");
    assert_eq!(
        v.material,
        ids::SAND,
        "the placeable neighbour's, not bedrock"
    );
    // A hole in solid bedrock: only bedrock around, so it stays below solid.
    let mut w = World::new(Arc::new(BedrockWithAHole));
    smooth.apply(&mut w, &ctx).unwrap();
    let v = w.voxel(VoxelPos::new(0, 0, 0));
    assert_eq!(v.density, strata_terrain::SOLID_THRESHOLD - 1, "{v:?}");
}

/// Bedrock everywhere but the voxel at the origin.
#[derive(Debug)]
struct BedrockWithAHole;

impl ChunkGenerator for BedrockWithAHole {
    fn generate(&self, pos: ChunkPos) -> Chunk {
        let mut c = Chunk::uniform(Voxel::solid(ids::BEDROCK));
        if pos == ChunkPos::new(0, 0, 0) {
            c.set(0, 0, 0, Voxel::AIR);
        }
        c
    }
}

/// A sphere under half a voxel across that lies between voxel centres
/// holds none: refused as such, never an empty box that edits wrongly.
#[test]
fn a_sphere_between_voxel_centres_is_refused() {
    let setup = Setup::new();
    let ctx = setup.ctx();
    let mut w = world();
    let before = w.voxel(VoxelPos::new(0, 10, 0));
    for edit in [
        Edit::Mine {
            center: c(0.5, 10.5, 0.5),
            radius: r(0.25),
            strength: 1,
        },
        Edit::Build {
            center: c(31.5, 0.5, 0.5),
            radius: r(0.25),
            material: ids::SAND,
            strength: 1,
        },
    ] {
        assert_eq!(edit.validate(&ctx), Err(EditError::NoVoxel), "{edit:?}");
        assert_eq!(edit.apply(&mut w, &ctx).unwrap_err(), EditError::NoVoxel);
    }
    assert_eq!(w.voxel(VoxelPos::new(0, 10, 0)), before);
    // On a voxel centre the same radius holds that one voxel.
    let one = Edit::Mine {
        center: c(0.0, 0.0, 0.0),
        radius: r(0.25),
        strength: 1,
    };
    let b = one.validate(&ctx).unwrap();
    assert_eq!(
        (b.min, b.max),
        (VoxelPos::new(0, 0, 0), VoxelPos::new(0, 0, 0))
    );
}
