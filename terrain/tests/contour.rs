//! Marching Squares contouring: geometry, saddle rule, tiling, world slices.

use std::f64::consts::PI;
use std::sync::Arc;

use proptest::prelude::*;
use strata_terrain::contour::{
    contour, contour_levels, contour_tiled, grid_segments, slice_contours, slice_grid,
    slice_grid_chunks, stitch, tile_segments, Axis, ContourError, EdgeAxis, EdgeKey, GridView,
    Polyline, Rect, Sample, Segment, SliceSpec, TiledField, DENSITY_ISO, MAX_LEVELS,
};
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{ChunkPos, Voxel, VoxelPos, World, CHUNK_SIZE};

/// Samples `f` over `width x height` positions starting at `origin`.
fn sample<T: Copy>(origin: [i32; 2], width: u32, height: u32, f: impl Fn(i32, i32) -> T) -> Vec<T> {
    let mut v = Vec::with_capacity((width * height) as usize);
    for j in 0..height as i32 {
        for i in 0..width as i32 {
            v.push(f(origin[0] + i, origin[1] + j));
        }
    }
    v
}

/// Independent shoelace area (not the library's), positive when CCW.
fn area(p: &Polyline) -> f64 {
    assert!(p.closed);
    let n = p.points.len();
    (0..n)
        .map(|i| {
            let (a, b) = (p.points[i], p.points[(i + 1) % n]);
            f64::from(a[0]) * f64::from(b[1]) - f64::from(b[0]) * f64::from(a[1])
        })
        .sum::<f64>()
        / 2.0
}

fn centroid(p: &Polyline) -> [f64; 2] {
    let n = p.points.len() as f64;
    let sx: f64 = p.points.iter().map(|q| f64::from(q[0])).sum();
    let sy: f64 = p.points.iter().map(|q| f64::from(q[1])).sum();
    [sx / n, sy / n]
}

fn dist(x: f64, y: f64, c: [f64; 2]) -> f64 {
    ((x - c[0]) * (x - c[0]) + (y - c[1]) * (y - c[1])).sqrt()
}

#[test]
fn circle_is_one_ccw_loop_with_circle_area() {
    let (r, c, origin) = (20.0, [0.3, -0.45], [-32, -30]);
    let f32_field = sample(origin, 64, 62, |x, y| {
        (127.5 + (r - dist(f64::from(x), f64::from(y), c)) * 8.0) as f32
    });
    let u8_field = sample(origin, 64, 62, |x, y| {
        (127.5 + (r - dist(f64::from(x), f64::from(y), c)) * 32.0).clamp(0.0, 255.0) as u8
    });
    let expected = PI * r * r;
    let check = |lines: Vec<Polyline>| {
        assert_eq!(lines.len(), 1, "one contour");
        let l = &lines[0];
        assert!(l.closed);
        let a = area(l);
        assert!(
            (a - expected).abs() < 0.01 * expected,
            "area {a} vs {expected}"
        );
        assert!(
            (l.signed_area() - a).abs() < 1e-6,
            "library shoelace agrees"
        );
        for p in &l.points {
            let d = dist(f64::from(p[0]), f64::from(p[1]), c);
            assert!((d - r).abs() < 0.06, "point {p:?} at distance {d}");
        }
    };
    check(
        contour(
            &GridView::new(&f32_field, 64, 62, origin).unwrap(),
            DENSITY_ISO,
        )
        .unwrap(),
    );
    check(
        contour(
            &GridView::new(&u8_field, 64, 62, origin).unwrap(),
            DENSITY_ISO,
        )
        .unwrap(),
    );

    // The complement (a round hole in rock) is the same loop, clockwise.
    let hole: Vec<u8> = u8_field.iter().map(|v| 255 - v).collect();
    let lines = contour(&GridView::new(&hole, 64, 62, origin).unwrap(), DENSITY_ISO).unwrap();
    assert_eq!(lines.len(), 1);
    assert!(
        (area(&lines[0]) + expected).abs() < 0.01 * expected,
        "hole is clockwise"
    );
}

/// Two 2x2 blobs touching diagonally at the cell with lower corner (2, 2).
/// `main_diagonal`: blobs at a and d of that cell (case 9), else at b and c
/// (case 6). The two other corners of the saddle cell get `gap`.
fn saddle_field(main_diagonal: bool, inside: u8, gap: u8) -> Vec<u8> {
    sample([0, 0], 6, 6, |x, y| {
        let (lo, hi) = (1..=2, 3..=4);
        let blob = if main_diagonal {
            (lo.contains(&x) && lo.contains(&y)) || (hi.contains(&x) && hi.contains(&y))
        } else {
            (hi.contains(&x) && lo.contains(&y)) || (lo.contains(&x) && hi.contains(&y))
        };
        let saddle_gap = if main_diagonal {
            (x, y) == (3, 2) || (x, y) == (2, 3)
        } else {
            (x, y) == (2, 2) || (x, y) == (3, 3)
        };
        if blob {
            inside
        } else if saddle_gap {
            gap
        } else {
            0
        }
    })
}

#[test]
fn saddle_connects_only_when_the_cell_centre_is_inside() {
    for main_diagonal in [true, false] {
        // Centre average 150 > 127.5: the blobs join into one loop.
        let f = saddle_field(main_diagonal, 200, 100);
        let lines = contour(&GridView::new(&f, 6, 6, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
        assert_eq!(lines.len(), 1, "connected, diagonal {main_diagonal}");
        assert!(lines[0].closed && area(&lines[0]) > 0.0);

        // Centre average 100: two separate loops.
        let f = saddle_field(main_diagonal, 200, 0);
        let lines = contour(&GridView::new(&f, 6, 6, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
        assert_eq!(lines.len(), 2, "separated, diagonal {main_diagonal}");
        assert!(lines.iter().all(|l| l.closed && area(l) > 0.0));

        // Exact tie (255 + 0 + 255 + 0) / 4 == 127.5 is not inside: separated.
        let f = saddle_field(main_diagonal, 255, 0);
        let lines = contour(&GridView::new(&f, 6, 6, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
        assert_eq!(lines.len(), 2, "tie separates, diagonal {main_diagonal}");
    }
}

#[test]
fn saddle_rule_is_symmetric_for_holes() {
    // Inverting densities turns the two blobs into two holes in rock and the
    // saddle centre average 150 into 105: now outside, so the inside (rock)
    // corners are separated and the holes stay joined, exactly the topology
    // of the original. One clockwise loop; no open lines, as the border is
    // all rock.
    let f: Vec<u8> = saddle_field(true, 200, 100)
        .iter()
        .map(|v| 255 - v)
        .collect();
    let lines = contour(&GridView::new(&f, 6, 6, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
    assert_eq!(lines.len(), 1);
    assert!(lines[0].closed && area(&lines[0]) < 0.0);
    // And inverting the separated configuration keeps two holes.
    let f: Vec<u8> = saddle_field(false, 200, 0)
        .iter()
        .map(|v| 255 - v)
        .collect();
    let lines = contour(&GridView::new(&f, 6, 6, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
    assert_eq!(lines.len(), 2);
    assert!(lines.iter().all(|l| l.closed && area(l) < 0.0));
}

#[test]
fn open_contour_ends_on_the_region_border() {
    let (origin, w, h) = ([-10, -5], 31, 31);
    let rect = |p: [f32; 2]| {
        let on_x = p[0] == origin[0] as f32 || p[0] == (origin[0] + w as i32 - 1) as f32;
        let on_y = p[1] == origin[1] as f32 || p[1] == (origin[1] + h as i32 - 1) as f32;
        on_x || on_y
    };
    // Inside for x > 3.3: a vertical line, walked top to bottom.
    let f = sample(origin, w, h, |x, _| 127.5 + (x as f32 - 3.3) * 10.0);
    let lines = contour(&GridView::new(&f, w, h, origin).unwrap(), DENSITY_ISO).unwrap();
    assert_eq!(lines.len(), 1);
    let l = &lines[0];
    assert!(!l.closed);
    assert_eq!(l.points.len(), h as usize);
    assert_eq!(l.points[0], [3.3f32, 25.0]);
    assert_eq!(*l.points.last().unwrap(), [3.3f32, -5.0]);
    assert!(l.points.iter().all(|p| (p[0] - 3.3).abs() < 1e-5));

    // A diagonal cutting the region's lower-left corner.
    let f = sample(origin, w, h, |x, y| 127.5 + (-(x + y) as f32 + 0.5) * 20.0);
    let lines = contour(&GridView::new(&f, w, h, origin).unwrap(), DENSITY_ISO).unwrap();
    assert_eq!(lines.len(), 1);
    let l = &lines[0];
    assert!(!l.closed);
    assert!(rect(l.points[0]) && rect(*l.points.last().unwrap()));
    assert!(
        l.points[1..l.points.len() - 1].iter().all(|p| !rect(*p)),
        "interior points inside"
    );
}

fn sorted_segments(mut s: Vec<Segment>) -> Vec<Segment> {
    s.sort_by_key(|s| (s.from, s.to));
    s
}

/// Closed loops rotated to start at their smallest point: equal up to start.
fn canonical(mut lines: Vec<Polyline>) -> Vec<Polyline> {
    for l in &mut lines {
        if l.closed {
            let k = (0..l.points.len())
                .min_by(|&i, &j| l.points[i].partial_cmp(&l.points[j]).unwrap())
                .unwrap();
            l.points.rotate_left(k);
        }
    }
    lines.sort_by(|a, b| a.points.partial_cmp(&b.points).unwrap());
    lines
}

/// Single-grid and tiled contouring agree on segments and polylines.
fn assert_tiled_matches<T: Sample + std::fmt::Debug>(
    values: &[T],
    w: u32,
    h: u32,
    origin: [i32; 2],
    iso: f32,
) {
    let grid = GridView::new(values, w, h, origin).unwrap();
    let field = TiledField::from_grid(&grid).unwrap();
    let single = grid_segments(&grid, iso).unwrap();
    let tiled: Vec<Segment> = field
        .tiles()
        .flat_map(|tp| tile_segments(&field, tp, iso).unwrap())
        .collect();
    assert_eq!(
        sorted_segments(single.clone()),
        sorted_segments(tiled),
        "same segment set"
    );
    let a = contour(&grid, iso).unwrap();
    let b = contour_tiled(&field, iso).unwrap();
    assert_eq!(
        canonical(a.clone()),
        canonical(b.clone()),
        "same polylines up to start"
    );
    // Stitching is canonical, so the outputs are in fact identical.
    assert_eq!(a, b);
    // Every cell segment is used exactly once.
    let used: usize = a
        .iter()
        .map(|l| l.points.len() - usize::from(!l.closed))
        .sum();
    assert_eq!(used, single.len());
}

/// A smooth field: a sum of rational bumps (deterministic, no trig).
fn bumps(bs: &[(f32, f32, f32, f32)]) -> impl Fn(i32, i32) -> f32 + '_ {
    move |x, y| {
        bs.iter()
            .map(|&(cx, cy, s, a)| {
                let (dx, dy) = ((x as f32 - cx) / s, (y as f32 - cy) / s);
                a / (1.0 + dx * dx + dy * dy)
            })
            .sum()
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn tiled_equals_single_on_smooth_fields(
        ox in -100i32..60, oy in -100i32..60, w in 1u32..110, h in 1u32..110,
        bs in prop::collection::vec((-120f32..170.0, -120f32..170.0, 3f32..30.0, -300f32..300.0), 1..6),
        iso in -40f32..40.0,
    ) {
        let f = sample([ox, oy], w, h, bumps(&bs));
        assert_tiled_matches(&f, w, h, [ox, oy], iso);
    }

    #[test]
    fn tiled_equals_single_on_noise(
        ox in -80i32..40, oy in -80i32..40, w in 1u32..90, h in 1u32..90, seed in any::<u64>(),
    ) {
        // Per-sample noise: saddles (and exact 127.5 ties) everywhere.
        let f = sample([ox, oy], w, h, |x, y| {
            let k = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ seed;
            let k = (k ^ (k >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            (k >> 56) as u8
        });
        assert_tiled_matches(&f, w, h, [ox, oy], DENSITY_ISO);
        // Small integer heights with an integer iso: samples equal to the iso
        // level (outside, crossing at t = 0) everywhere.
        let heights: Vec<f32> = f.iter().map(|&v| f32::from(v >> 5)).collect();
        assert_tiled_matches(&heights, w, h, [ox, oy], 3.0);
    }
}

#[test]
fn tiled_equals_single_across_tile_corners() {
    let t = CHUNK_SIZE;
    // Circles centred on tile corners (0, 0), (-32, -32) and (32, -32), and a
    // ring that crosses many tile borders.
    for (c, r) in [
        ([0.0, 0.0], 10.0),
        ([-32.0, -32.0], 7.5),
        ([32.2, -31.7], 12.0),
        ([0.5, 0.5], 40.0),
    ] {
        let origin = [-2 * t - 5, -2 * t - 3];
        let (w, h) = (4 * t as u32 + 9, 4 * t as u32 + 7);
        let f = sample(origin, w, h, |x, y| {
            (127.5 + (r - dist(f64::from(x), f64::from(y), c)) * 24.0).clamp(0.0, 255.0) as u8
        });
        assert_tiled_matches(&f, w, h, origin, DENSITY_ISO);
        let lines = contour_tiled(
            &TiledField::from_grid(&GridView::new(&f, w, h, origin).unwrap()).unwrap(),
            DENSITY_ISO,
        )
        .unwrap();
        assert_eq!(lines.len(), 1, "circle at {c:?}");
        assert!(lines[0].closed);
        let expected = PI * r * r;
        assert!((area(&lines[0]) - expected).abs() < 0.01 * expected);
    }
    // Regions one or two samples wide straddling a tile border.
    for (origin, w, h) in [
        ([-1, -40], 2u32, 80u32),
        ([31, -1], 2, 2),
        ([-33, 5], 70, 1),
    ] {
        let f = sample(origin, w, h, |x, y| {
            ((x * 37 + y * 91).rem_euclid(256)) as u8
        });
        assert_tiled_matches(&f, w, h, origin, DENSITY_ISO);
    }
}

#[test]
fn stitching_far_apart_pieces_matches_compact_stitching() {
    // Far-apart keys take the hash index instead of the dense one; both
    // must join segments identically.
    let f = sample([0, 0], 30, 30, |x, y| {
        (127.5 + (8.0 - dist(f64::from(x), f64::from(y), [14.2, 15.1])) * 20.0).clamp(0.0, 255.0)
            as u8
    });
    let segs = grid_segments(&GridView::new(&f, 30, 30, [0, 0]).unwrap(), DENSITY_ISO).unwrap();
    let near = stitch(segs.clone()).unwrap();
    assert_eq!(near.len(), 1);
    let shift = |k: EdgeKey| EdgeKey {
        x: k.x + (1 << 30),
        ..k
    };
    let far: Vec<Segment> = segs
        .iter()
        .map(|s| Segment {
            from: shift(s.from),
            to: shift(s.to),
            ..*s
        })
        .collect();
    let both = stitch(segs.iter().copied().chain(far).collect()).unwrap();
    assert_eq!(both, vec![near[0].clone(), near[0].clone()]);
}

#[test]
fn tiled_contouring_is_deterministic_across_thread_counts() {
    let bs = [
        (10.0, 20.0, 9.0, 200.0),
        (70.0, 40.0, 14.0, 180.0),
        (40.0, 90.0, 6.0, -90.0),
    ];
    let field = TiledField::from_fn(Rect::new(-20, -30, 140, 130).unwrap(), bumps(&bs)).unwrap();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let a = one.install(|| contour_tiled(&field, 60.0).unwrap());
    let b = contour_tiled(&field, 60.0).unwrap();
    assert!(!a.is_empty());
    assert_eq!(a, b);
}

/// Carves a smooth spherical air cavity by committing each touched chunk.
fn carve(world: &mut World, c: [f64; 3], r: f64) {
    let reach = r as i32 + 2;
    let (cx, cy, cz) = (c[0] as i32, c[1] as i32, c[2] as i32);
    let lo = VoxelPos::new(cx - reach, cy - reach, cz - reach).chunk();
    let hi = VoxelPos::new(cx + reach, cy + reach, cz + reach).chunk();
    for pz in lo.z..=hi.z {
        for py in lo.y..=hi.y {
            for px in lo.x..=hi.x {
                let pos = ChunkPos::new(px, py, pz);
                let mut chunk = strata_terrain::Chunk::clone(&world.chunk(pos).chunk);
                let o = pos.origin();
                for z in 0..32 {
                    for y in 0..32 {
                        for x in 0..32 {
                            let p = [o.x + x, o.y + y, o.z + z];
                            let d = ((f64::from(p[0]) - c[0]).powi(2)
                                + (f64::from(p[1]) - c[1]).powi(2)
                                + (f64::from(p[2]) - c[2]).powi(2))
                            .sqrt();
                            let cave = (127.5 + (d - r) * 32.0).clamp(0.0, 255.0) as u8;
                            let old = chunk.get(x as usize, y as usize, z as usize);
                            if cave < old.density {
                                let m = if cave >= 128 { old.material } else { ids::AIR };
                                chunk.set(x as usize, y as usize, z as usize, Voxel::new(cave, m));
                            }
                        }
                    }
                }
                world.commit(pos, chunk);
            }
        }
    }
}

fn cave_world() -> World {
    let mut w = World::new(Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    }));
    // Centred on a chunk corner in x and z, so its outline crosses tiles.
    carve(&mut w, [0.0, -16.0, 0.0], 6.0);
    carve(&mut w, [40.0, -20.0, 10.0], 5.0);
    carve(&mut w, [10.0, -50.0, 10.0], 5.0);
    w
}

#[test]
fn horizontal_slice_outlines_each_cavity() {
    let world = cave_world();
    let spec = SliceSpec {
        axis: Axis::Y,
        level: -16,
        region: Rect::new(-20, -20, 60, 40).unwrap(),
    };
    let via_voxels = slice_grid(&world, spec).unwrap();
    let via_chunks = slice_grid_chunks(&world, spec).unwrap();
    assert_eq!(via_voxels, via_chunks, "both readers sample the same slice");
    assert_eq!(
        via_chunks.voxel(0, 0),
        Some(Voxel::new(0, ids::AIR)),
        "cavity centre"
    );
    assert_eq!(via_chunks.voxel(20, 30), Some(Voxel::solid(ids::STONE)));
    assert_eq!(via_chunks.voxel(61, 0), None, "outside the region");

    let mut lines = via_chunks.contours(DENSITY_ISO).unwrap();
    assert_eq!(
        lines,
        slice_contours(&world, Axis::Y, -16, (-20, -20, 60, 40), DENSITY_ISO).unwrap()
    );
    assert_eq!(lines.len(), 2, "two cavities cut by y = -16");
    assert!(
        lines.iter().all(|l| l.closed && area(l) < 0.0),
        "cavities are clockwise holes"
    );
    lines.sort_by(|a, b| area(a).partial_cmp(&area(b)).unwrap());
    // Cavity 1 cut through its centre (r = 6) at (x, z) = (0, 0); cavity 2
    // cut 4 below its centre (r = 3) at (40, 10): u = x, v = z.
    for (l, r, c) in [(&lines[0], 6.0, [0.0, 0.0]), (&lines[1], 3.0, [40.0, 10.0])] {
        let expected = PI * r * r;
        assert!(
            (-area(l) - expected).abs() < 0.03 * expected,
            "area {} vs {expected}",
            -area(l)
        );
        let g = centroid(l);
        assert!(dist(g[0], g[1], c) < 0.2, "centroid {g:?} vs {c:?}");
    }
    // Deep in the rock between the cavities: nothing to draw.
    let solid = slice_contours(&world, Axis::Y, -35, (-20, -20, 60, 40), DENSITY_ISO).unwrap();
    assert!(solid.is_empty());
}

#[test]
fn vertical_slices_show_ground_line_and_cavity() {
    let world = cave_world();
    for axis in [Axis::X, Axis::Z] {
        // X slice: u = y, v = z; Z slice: u = x, v = y.
        let region = if axis == Axis::X {
            (-30, -20, 10, 20)
        } else {
            (-20, -30, 20, 10)
        };
        let lines = slice_contours(&world, axis, 0, region, DENSITY_ISO).unwrap();
        assert_eq!(lines.len(), 2, "{axis:?}: ground line and cavity");
        let (open, closed): (Vec<_>, Vec<_>) = lines.into_iter().partition(|l| !l.closed);
        assert_eq!(open.len(), 1);
        // The ground surface lies halfway between y = -1 (solid) and y = 0.
        let y_of = |p: &[f32; 2]| if axis == Axis::X { p[0] } else { p[1] };
        assert!(open[0].points.iter().all(|p| y_of(p) == -0.5));
        let expected = PI * 36.0;
        assert!((-area(&closed[0]) - expected).abs() < 0.03 * expected);
        let cave = slice_grid_chunks(
            &world,
            SliceSpec {
                axis,
                level: 0,
                region: Rect::new(region.0, region.1, region.2, region.3).unwrap(),
            },
        )
        .unwrap();
        let (u, v) = if axis == Axis::X { (-16, 0) } else { (0, -16) };
        assert_eq!(cave.voxel(u, v).map(|v| v.material), Some(ids::AIR));
        // Chunk-wise and per-voxel reading agree on dense chunks at any depth
        // inside the chunk, on both sides of the chunk border at 0.
        for level in [-4, -1, 0, 3] {
            let spec = SliceSpec {
                level,
                ..cave.spec()
            };
            assert_eq!(
                slice_grid(&world, spec).unwrap(),
                slice_grid_chunks(&world, spec).unwrap()
            );
        }
    }
}

#[test]
fn cone_heights_give_concentric_loops() {
    let (c, top) = ([50.3, 49.7], 50.0);
    let heights = sample([0, 0], 101, 101, |x, y| {
        (top - dist(f64::from(x), f64::from(y), c)) as f32
    });
    let grid = GridView::new(&heights, 101, 101, [0, 0]).unwrap();
    let levels = [5.0, 15.0, 25.0, 35.0, 45.0];
    let out = contour_levels(&grid, &levels).unwrap();
    assert_eq!(out.len(), levels.len());
    let mut last_area = f64::MAX;
    for lc in &out {
        assert_eq!(lc.polylines.len(), 1, "level {}", lc.level);
        let l = &lc.polylines[0];
        assert!(l.closed);
        let r = top - f64::from(lc.level);
        let a = area(l);
        assert!(
            (a - PI * r * r).abs() < 0.01 * PI * r * r,
            "level {} area {a}",
            lc.level
        );
        assert!(a < last_area, "nested: higher levels enclose less");
        last_area = a;
        let g = centroid(l);
        assert!(dist(g[0], g[1], c) < 0.3);
    }
    // Above the peak nothing, below the lowest sample nothing either.
    let none = contour_levels(&grid, &[60.0, -30.0]).unwrap();
    assert!(none.iter().all(|lc| lc.polylines.is_empty()));
}

#[test]
fn bad_input_is_refused_with_reasons() {
    let ok = vec![0u8; 16];
    assert!(matches!(
        GridView::new(&ok, 5, 4, [0, 0]),
        Err(ContourError::LengthMismatch { .. })
    ));
    assert!(matches!(
        GridView::new(&ok, 0, 4, [0, 0]),
        Err(ContourError::BadGridSize { .. })
    ));
    assert!(matches!(
        GridView::new(&ok, 4, 4, [i32::MAX - 2, 0]),
        Err(ContourError::OriginOverflow { .. })
    ));
    let mut nan = vec![1.0f32; 16];
    nan[6] = f32::NAN;
    assert_eq!(
        GridView::new(&nan, 4, 4, [10, 20]).unwrap_err(),
        ContourError::NonFiniteSample { x: 12, y: 21 }
    );
    let grid = GridView::new(&ok, 4, 4, [0, 0]).unwrap();
    assert_eq!(
        contour(&grid, f32::INFINITY).unwrap_err(),
        ContourError::NonFiniteIso(f32::INFINITY)
    );
    assert!(matches!(
        contour_levels(&grid, &vec![1.0; MAX_LEVELS + 1]),
        Err(ContourError::TooManyLevels { .. })
    ));
    assert!(matches!(
        contour_levels(&grid, &[1.0, f32::NAN]),
        Err(ContourError::NonFiniteIso(_))
    ));
    assert!(matches!(
        Rect::new(5, 0, 4, 0),
        Err(ContourError::InvertedRegion { .. })
    ));
    assert!(matches!(
        Rect::new(0, 0, 9000, 3),
        Err(ContourError::RegionTooLarge { .. })
    ));
    let r = Rect::new(-1, 0, 1, 0).unwrap();
    assert!(matches!(
        TiledField::<u8>::from_tiles(r, vec![]),
        Err(ContourError::TileCountMismatch { .. })
    ));
    assert!(matches!(
        TiledField::<u8>::from_tiles(r, vec![vec![0; 1024], vec![0; 10]]),
        Err(ContourError::BadTileLength {
            x: 0,
            y: 0,
            got: 10
        })
    ));
    assert!(matches!(
        TiledField::<f32>::from_fn(r, |x, _| if x == 1 { f32::NAN } else { 0.0 }),
        Err(ContourError::NonFiniteSample { x: 1, y: 0 })
    ));
    assert!(slice_contours(&cave_world(), Axis::Y, 0, (0, 0, -1, 0), DENSITY_ISO).is_err());

    // Stitching refuses segment sets where an edge starts two segments.
    let k = |x| EdgeKey {
        x,
        y: 0,
        axis: EdgeAxis::X,
    };
    let seg = |f, t| Segment {
        from: k(f),
        to: k(t),
        a: [0.0; 2],
        b: [1.0; 2],
    };
    assert_eq!(
        stitch(vec![seg(0, 1), seg(0, 2)]).unwrap_err(),
        ContourError::DuplicateEdge(k(0))
    );
    assert_eq!(
        stitch(vec![seg(0, 2), seg(1, 2)]).unwrap_err(),
        ContourError::DuplicateEdge(k(2))
    );
    // The same checks when the keys are far apart (hash index).
    let far = 1 << 30;
    assert_eq!(
        stitch(vec![seg(0, far), seg(0, 2)]).unwrap_err(),
        ContourError::DuplicateEdge(k(0))
    );
    assert_eq!(
        stitch(vec![seg(0, far), seg(1, far)]).unwrap_err(),
        ContourError::DuplicateEdge(k(far))
    );
    // A consistent set stitches: a 3-cycle and an open chain.
    let lines = stitch(vec![seg(5, 6), seg(1, 2), seg(6, 4), seg(2, 3), seg(4, 5)]).unwrap();
    assert_eq!(lines.len(), 2);
    assert!(!lines[0].closed && lines[0].points.len() == 3);
    assert!(lines[1].closed && lines[1].points.len() == 3);
}
