//! Applying each edit kind to generated terrain at the surface.
//! Run: cargo bench -p strata-terrain --bench edit

use std::hint::black_box;
use std::sync::Arc;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use strata_terrain::edit::{structure::Structure, StructureLibrary};
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::material::ids;
use strata_terrain::{
    Edit, EditContext, Fixed, FixedVec3, MaterialTable, Voxel, VoxelBox, VoxelPos, World,
};

fn bench_edits(c: &mut Criterion) {
    let generator = Generator::fractal(GenParams::default()).expect("default params are valid");
    let (x, z) = (16, 16);
    let y = generator.surface_height(x, z).floor() as i32;
    let mut world = World::new(Arc::new(generator));
    let around = VoxelBox::from_corners(
        VoxelPos::new(x - 40, y - 40, z - 40),
        VoxelPos::new(x + 40, y + 40, z + 40),
    );
    world.load(around.chunks());
    let materials = MaterialTable::default();
    let mut structures = StructureLibrary::default();
    let hut = Structure::from_fn("hut", [9, 6, 9], |x, y, z| {
        let wall = x == 0 || x == 8 || z == 0 || z == 8 || y == 5;
        if wall {
            Voxel::solid(ids::BRICK)
        } else {
            Voxel::new(0, 0)
        }
    })
    .expect("valid template");
    structures.insert(1, hut);
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    let at = |dy: i32| FixedVec3::from_voxels(x, y + dy, z);
    let p = VoxelPos::new(x, y, z);
    let edits = [
        (
            "mine_r3",
            Edit::Mine {
                center: at(0),
                radius: Fixed::from_voxels(3),
                strength: 255,
            },
        ),
        (
            "explode_r8",
            Edit::Explode {
                center: at(0),
                radius: Fixed::from_voxels(8),
                power: 800,
            },
        ),
        (
            "build_r4",
            Edit::Build {
                center: at(3),
                radius: Fixed::from_voxels(4),
                material: ids::BRICK,
                strength: 255,
            },
        ),
        (
            "fill_box_8",
            Edit::FillBox {
                min: p,
                max: VoxelPos::new(x + 7, y + 7, z + 7),
                material: ids::BRICK,
            },
        ),
        (
            "clear_box_8",
            Edit::ClearBox {
                min: VoxelPos::new(x - 4, y - 4, z - 4),
                max: VoxelPos::new(x + 3, y + 3, z + 3),
            },
        ),
        (
            "place_structure_9x6x9",
            Edit::PlaceStructure {
                structure: 1,
                origin: p,
                rotation: 1,
            },
        ),
        (
            "smooth_r4",
            Edit::Smooth {
                center: at(0),
                radius: Fixed::from_voxels(4),
                strength: 255,
            },
        ),
    ];
    let mut group = c.benchmark_group("edit_apply");
    for (name, edit) in &edits {
        group.bench_function(*name, |b| {
            b.iter_batched(
                || world.clone(),
                |mut w| black_box(edit.apply(&mut w, &ctx).unwrap()),
                BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bench_edits);
criterion_main!(benches);
