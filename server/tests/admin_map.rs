//! `strata-admin render-map` on a stopped server's data dir: PNGs decode
//! with the expected size and show the stored edits and contour lines;
//! SVGs parse as XML with the same lines; the generator comes from the
//! store, the data dir's config or `--config`, and a config that disagrees
//! with the store is refused.

use crate::offline_common;

use std::collections::HashSet;
use std::path::Path;

use offline_common::*;
use strata_server::admin::map::palette;
use strata_terrain::gen::GenParams;
use strata_terrain::material::ids;
use strata_terrain::MaterialTable;

const SCALE: u32 = 2;
/// The region is 3 x 3 chunk columns.
const SIDE_PX: u32 = 3 * 32 * SCALE;

fn render(fx: &Fixture, out: &Path, view: &[&str], extra: &[&str]) -> std::process::Output {
    let region = region_args();
    let scale = SCALE.to_string();
    let mut args = vec!["render-map", "--data-dir", fx.data_dir().to_str().unwrap()];
    args.extend(view);
    args.extend([
        "--scale",
        &scale,
        "--out",
        out.to_str().unwrap(),
        "--region",
    ]);
    args.extend(region.iter().map(String::as_str));
    args.extend(extra);
    admin(&args)
}

struct Png {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Png {
    fn read(path: &Path) -> Png {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        buf.truncate(info.buffer_size());
        Png {
            width: info.width,
            height: info.height,
            rgb: buf,
        }
    }

    /// The pixel at the middle of world voxel `(x, z)`'s square.
    fn at_world(&self, x: i32, z: i32) -> [u8; 3] {
        let [x0, z0] = [REGION[0] * 32, REGION[1] * 32];
        let (px, py) = (
            ((x - x0) as u32 * SCALE + SCALE / 2) as usize,
            ((z - z0) as u32 * SCALE + SCALE / 2) as usize,
        );
        let i = (py * self.width as usize + px) * 3;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    fn colours(&self) -> HashSet<[u8; 3]> {
        self.rgb
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect()
    }
}

fn rgb(id: u8) -> [u8; 3] {
    let [r, g, b, _] = MaterialTable::default().rgba(id);
    [r, g, b]
}

fn report(out: &std::process::Output) -> serde_json::Value {
    serde_json::from_str(ok(out).trim()).unwrap()
}

#[test]
fn slice_png_and_svg_show_the_stored_world() {
    let fx = build();
    let level = (fx.brick_top - 1).to_string();
    let png_path = fx.data_dir().join("slice.png");
    let r = report(&render(&fx, &png_path, &["--y", &level], &[]));
    let img = Png::read(&png_path);
    assert_eq!((img.width, img.height), (SIDE_PX, SIDE_PX));
    assert_eq!(r["width_px"], SIDE_PX);
    // The brick box stored by the edit, above the ground around it.
    let (bx, bz, _) = BRICK;
    assert_eq!(img.at_world(bx, bz), rgb(ids::BRICK));
    let colours = img.colours();
    assert!(colours.contains(&palette::AIR), "open air around the box");
    assert!(colours.contains(&palette::SOLID_OUTLINE), "outlines drawn");
    assert!(colours.len() >= 4, "not blank: {colours:?}");
    let lines = r["lines"].as_u64().unwrap();
    assert!(lines >= 1);

    // Deep down every air pocket is a cave: solid ground above it.
    let deep = fx.data_dir().join("deep.png");
    report(&render(&fx, &deep, &["--y", "-40"], &[]));
    let colours = Png::read(&deep).colours();
    assert!(colours.contains(&palette::CAVE_AIR), "caves at y = -40");
    assert!(colours.contains(&palette::CAVE_OUTLINE));
    assert!(!colours.contains(&palette::AIR), "no open air underground");

    let svg_path = fx.data_dir().join("slice.svg");
    let r2 = report(&render(&fx, &svg_path, &["--y", &level], &[]));
    assert_eq!(r2["lines"], lines, "same contours in both formats");
    let text = std::fs::read_to_string(&svg_path).unwrap();
    let doc = roxmltree::Document::parse(&text).expect("the SVG is well-formed XML");
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "svg");
    assert_eq!(
        root.tag_name().namespace(),
        Some("http://www.w3.org/2000/svg")
    );
    assert_eq!(root.attribute("width"), Some(SIDE_PX.to_string().as_str()));
    let count = |tag: &str| doc.descendants().filter(|n| n.has_tag_name(tag)).count();
    assert_eq!(count("path") as u64, lines);
    assert!(count("rect") > 9, "sample runs");
    let legend: Vec<&str> = doc
        .descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text())
        .collect();
    assert!(legend.contains(&"brick"), "{legend:?}");
    assert!(legend.contains(&"cave outline"));
}

#[test]
fn top_down_has_height_contours_every_interval() {
    let fx = build();
    let png_path = fx.data_dir().join("top.png");
    let r = report(&render(
        &fx,
        &png_path,
        &["--top-down"],
        &["--interval", "4"],
    ));
    let img = Png::read(&png_path);
    assert_eq!((img.width, img.height), (SIDE_PX, SIDE_PX));
    let levels: Vec<f64> = r["levels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(levels.len() >= 2, "hills span several levels: {levels:?}");
    assert!(levels.iter().all(|l| l % 4.0 == 0.0));
    let colours = img.colours();
    assert!(colours.contains(&palette::CONTOUR) || colours.contains(&palette::INDEX_CONTOUR));
    assert!(colours.len() > 20, "shaded relief, not blank");

    let svg_path = fx.data_dir().join("top.svg");
    let r2 = report(&render(
        &fx,
        &svg_path,
        &["--top-down"],
        &["--interval", "4"],
    ));
    assert_eq!(r2["levels"], r["levels"]);
    let text = std::fs::read_to_string(&svg_path).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let paths = doc.descendants().filter(|n| n.has_tag_name("path")).count();
    assert_eq!(paths as u64, r2["lines"].as_u64().unwrap());
    assert!(paths >= levels.len());
}

#[test]
fn generator_comes_from_the_store_or_an_agreeing_config() {
    let fx = build();
    let out = fx.data_dir().join("m.png");
    let level = ["--y", "0"];
    // No config anywhere: the generator recorded in the store.
    let from_store = report(&render(&fx, &out, &level, &[]));
    let from_store_png = std::fs::read(&out).unwrap();
    // The same parameters in a config file.
    let cfg = fx.data_dir().join("same.toml");
    std::fs::write(
        &cfg,
        format!("[world.generator]\nseed = {}\n", GenParams::default().seed),
    )
    .unwrap();
    let with_cfg = report(&render(
        &fx,
        &out,
        &level,
        &["--config", cfg.to_str().unwrap()],
    ));
    assert_eq!(with_cfg, from_store);
    assert_eq!(std::fs::read(&out).unwrap(), from_store_png);

    // Another seed disagrees with the store, from --config or DIR/strata.toml.
    let other = format!(
        "[world.generator]\nseed = {}\n",
        GenParams::default().seed + 1
    );
    let bad = fx.data_dir().join("other.toml");
    std::fs::write(&bad, &other).unwrap();
    let refused = render(&fx, &out, &level, &["--config", bad.to_str().unwrap()]);
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("seed"));
    std::fs::write(fx.data_dir().join("strata.toml"), &other).unwrap();
    let refused = render(&fx, &out, &level, &[]);
    assert!(String::from_utf8_lossy(&refused.stderr).contains("seed"));
    std::fs::remove_file(fx.data_dir().join("strata.toml")).unwrap();

    // A data dir without a world, a bad extension, no view.
    let empty = tempfile::tempdir().unwrap();
    let out = admin(&[
        "render-map",
        "--data-dir",
        empty.path().to_str().unwrap(),
        "--top-down",
        "--region",
        "0",
        "0",
        "0",
        "0",
        "--out",
        "x.png",
    ]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("world.sled does not exist"));
    let jpg = fx.data_dir().join("m.jpg");
    let out = render(&fx, &jpg, &["--top-down"], &[]);
    assert!(String::from_utf8_lossy(&out.stderr).contains(".png or .svg"));
    let out = render(&fx, &jpg, &[], &[]);
    assert!(!out.status.success(), "--y or --top-down is required");
}
