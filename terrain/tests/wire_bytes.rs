//! Bytes on the wire for typical edits on generated terrain, against zstd-3
//! of the full chunks they touch (issue target: Mine r=3 ≤ 150 bytes per
//! chunk and at least 20× smaller than the zstd-3 chunk).

use std::sync::Arc;

use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::material::ids;
use strata_terrain::{Edit, EditContext, Fixed, FixedVec3, MaterialTable, World};

/// (delta payload bytes, zstd-3 bytes of the touched chunk) per changed chunk.
fn wire_cost(edit_at: impl Fn(i32, i32, i32) -> Edit, x: i32, z: i32) -> Vec<(usize, usize)> {
    let generator = Generator::fractal(GenParams::default()).unwrap();
    let y = generator.surface_height(x, z).floor() as i32;
    let mut world = World::new(Arc::new(generator));
    let materials = MaterialTable::default();
    let structures = StructureLibrary::default();
    let ctx = EditContext {
        materials: &materials,
        structures: &structures,
    };
    let out = edit_at(x, y, z).apply(&mut world, &ctx).unwrap();
    assert!(!out.changed.is_empty());
    out.changed
        .iter()
        .map(|ch| {
            let after = &world.peek(ch.pos).unwrap().chunk;
            let d = ChunkDelta::encode(ch.pos, ch.from_version, ch.to_version, &ch.before, after)
                .unwrap();
            assert_eq!(&d.apply(&ch.before).unwrap(), &**after);
            (d.payload.len(), encode_chunk(after).len())
        })
        .collect()
}

fn report(name: &str, costs: &[(usize, usize)]) {
    for (delta, full) in costs {
        println!(
            "{name}: delta {delta} B, zstd-3 chunk {full} B, ratio {:.1}x",
            *full as f64 / *delta as f64
        );
    }
}

#[test]
fn mine_r3_delta_is_small() {
    // Inside one chunk: (10, 10) is well away from chunk borders in x and z.
    let costs = wire_cost(
        |x, y, z| Edit::Mine {
            center: FixedVec3::from_voxels(x, y, z),
            radius: Fixed::from_voxels(3),
            strength: 255,
        },
        10,
        10,
    );
    report("mine r=3", &costs);
    for (delta, full) in costs {
        assert!(delta <= 150, "Mine r=3 delta is {delta} bytes");
        assert!(
            full >= 20 * delta,
            "only {:.1}x smaller than zstd-3",
            full as f64 / delta as f64
        );
    }
}

#[test]
fn explode_r8_on_a_corner_and_build_r4() {
    let explode = wire_cost(
        |_, y, _| Edit::Explode {
            center: FixedVec3::from_voxels(0, y, 0),
            radius: Fixed::from_voxels(8),
            power: 800,
        },
        0,
        0,
    );
    report("explode r=8 corner", &explode);
    assert!(
        explode.len() >= 4,
        "a corner explosion touches at least four chunks"
    );
    let build = wire_cost(
        |x, y, z| Edit::Build {
            center: FixedVec3::from_voxels(x, y + 2, z),
            radius: Fixed::from_voxels(4),
            material: ids::BRICK,
            strength: 255,
        },
        12,
        12,
    );
    report("build r=4", &build);
    for (delta, full) in explode.iter().chain(&build) {
        assert!(
            delta < full,
            "a delta must beat the full chunk: {delta} vs {full}"
        );
    }
}
