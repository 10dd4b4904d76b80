//! Closed analytic surfaces: watertight, right Euler characteristic, right area and volume.

use crate::mesh_common;

use mesh_common::*;
use strata_terrain::mesh::{mesh_chunk, MeshOptions, Neighborhood};
use strata_terrain::{ChunkPos, Voxel, VoxelPos};

use std::f64::consts::PI;
const C: [f64; 3] = [16.0, 16.0, 16.0];
const SLOPE: f64 = 16.0;

fn opts(iso: f64) -> MeshOptions {
    MeshOptions {
        iso: iso as f32,
        ..MeshOptions::default()
    }
}

fn check_closed(f: &Field, iso: f64, chi: Option<i64>) -> strata_terrain::mesh::Mesh {
    let m = mesh_field(ChunkPos::new(0, 0, 0), f, iso, SLOPE, &opts(iso));
    assert_watertight(&m.indices);
    if let Some(chi) = chi {
        assert_eq!(euler(&m.indices), chi, "Euler characteristic");
    }
    assert!(
        min_double_area(&positions64(&m), &m.indices) > 0.0,
        "degenerate triangle"
    );
    assert_normals_agree(&m);
    m
}

#[test]
fn sphere_is_closed_with_right_area_and_volume_at_several_isovalues() {
    let r = 12.0;
    for iso in [127.5, 80.0, 200.0] {
        let m = check_closed(&sphere(C, r), iso, Some(2));
        let (area, vol) = area_volume(&positions64(&m), &m.indices);
        let (a0, v0) = (4.0 * PI * r * r, 4.0 / 3.0 * PI * r * r * r);
        assert!(
            (area / a0 - 1.0).abs() < 0.01,
            "iso {iso}: area {area} vs {a0}"
        );
        assert!(
            (vol / v0 - 1.0).abs() < 0.01,
            "iso {iso}: volume {vol} vs {v0}"
        );
    }
}

#[test]
fn torus_has_euler_zero() {
    let m = check_closed(&torus(C, 9.0, 3.5), 127.5, Some(0));
    let (_, vol) = area_volume(&positions64(&m), &m.indices);
    let v0 = 2.0 * PI * PI * 9.0 * 3.5 * 3.5;
    assert!((vol / v0 - 1.0).abs() < 0.02, "torus volume {vol} vs {v0}");
    check_closed(&torus(C, 9.0, 3.5), 60.0, Some(0));
}

#[test]
fn double_torus_has_euler_minus_two() {
    let a = torus([10.0, 16.0, 16.0], 6.0, 2.5);
    let b = torus([22.0, 16.0, 16.0], 6.0, 2.5);
    let f = move |p: [f64; 3]| a(p).max(b(p));
    check_closed(&f, 127.5, Some(-2));
}

#[test]
fn gyroid_clipped_to_a_ball_is_watertight() {
    let ball = sphere(C, 13.0);
    let f = move |p: [f64; 3]| {
        let k = 2.0 * PI / 10.0;
        let (x, y, z) = (p[0] * k, p[1] * k, p[2] * k);
        let g = x.sin() * y.cos() + y.sin() * z.cos() + z.sin() * x.cos();
        (g * 2.0).min(ball(p))
    };
    let m = check_closed(&f, 127.5, None);
    assert!(m.triangle_count() > 2000, "the gyroid should be intricate");
    assert_eq!(
        euler(&m.indices) % 2,
        0,
        "closed orientable surfaces have even Euler characteristic"
    );
}

#[test]
fn random_smooth_fields_are_watertight() {
    for seed in 0..6u64 {
        let noise = value_noise(seed, 5.0 + seed as f64);
        let ball = sphere(C, 14.0);
        let f = move |p: [f64; 3]| (noise(p) * 6.0).min(ball(p));
        let m = mesh_field(ChunkPos::new(0, 0, 0), &f, 127.5, SLOPE, &opts(127.5));
        assert!(m.triangle_count() > 100, "seed {seed}");
        assert_watertight(&m.indices);
        assert_eq!(euler(&m.indices) % 2, 0);
        assert!(min_double_area(&positions64(&m), &m.indices) > 0.0);
    }
}

#[test]
fn plateaus_at_the_isovalue_give_no_degenerate_triangles() {
    // Samples of 127 and 128 only, and a float iso of 100.0 hit exactly by many samples.
    for (iso, lo, hi) in [
        (127.5f32, 127u8, 128u8),
        (100.0, 100, 101),
        (100.0, 100, 255),
    ] {
        let noise = value_noise(7, 3.0);
        let nb = Neighborhood::from_fn(VoxelPos::new(0, 0, 0), |p| {
            let q = [p.x as f64, p.y as f64, p.z as f64];
            let inside = (q[0] - 16.0)
                .abs()
                .max((q[1] - 16.0).abs())
                .max((q[2] - 16.0).abs())
                < 12.0;
            let d = if inside && noise(q) > -0.3 { hi } else { lo };
            Voxel::new(d, 2)
        });
        let m = mesh_chunk(
            &nb,
            &MeshOptions {
                iso,
                ..MeshOptions::default()
            },
        );
        assert!(
            m.triangle_count() > 100,
            "iso {iso} {lo}/{hi}: {} triangles",
            m.triangle_count()
        );
        assert_watertight(&m.indices);
        assert!(
            min_double_area(&positions64(&m), &m.indices) > 0.0,
            "iso {iso} {lo}/{hi}"
        );
        for n in &m.normals {
            assert!(n.iter().all(|c| c.is_finite()));
        }
    }
}
