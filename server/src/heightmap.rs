//! Loading a heightmap file named in `[world.heightmap]`: a 16-bit (or
//! 8-bit) grayscale PNG, or raw little-endian u16 samples with their size.

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use strata_terrain::gen::{GenParams, Generator, HeightSource, Heightmap, HeightmapPlacement};
use strata_terrain::hash::hash_bytes;

/// Largest heightmap file read, in bytes.
pub const MAX_HEIGHTMAP_FILE: u64 = 256 * 1024 * 1024;

/// `[world.heightmap]`: replaces the fractal hills with a height image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeightmapSection {
    /// A `.png` (16-bit or 8-bit grayscale) or a raw file of u16 LE samples.
    pub path: PathBuf,
    /// Samples per row and rows, for raw files only.
    pub width: Option<u32>,
    pub height: Option<u32>,
    /// Where the map sits and how sample values become heights.
    #[serde(default)]
    pub placement: HeightmapPlacement,
}

/// What a raw map's size adds to its fingerprint, before `WxH`.
const RAW_SIZE_MARK: &str = ", raw ";

/// The generator parameter text (`params`, ending in a heightmap's
/// fingerprint line) as data dirs made before a raw map's size was part of
/// the fingerprint recorded it; `None` when `params` names no raw size.
/// Such a data dir still opens, its map's size unchecked.
pub fn without_raw_size(params: &str) -> Option<String> {
    let body = params.strip_suffix('\n')?;
    let at = body.rfind(RAW_SIZE_MARK)?;
    let (w, h) = body[at + RAW_SIZE_MARK.len()..].split_once('x')?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    (digits(w) && digits(h)).then(|| format!("{}\n", &body[..at]))
}

/// A generator over the heightmap, and a fingerprint of the file (and of
/// a raw file's size) so a data dir refuses a changed map.
pub fn load(section: &HeightmapSection, params: &GenParams) -> anyhow::Result<(Generator, String)> {
    let path: &Path = &section.path;
    let len = std::fs::metadata(path)
        .with_context(|| format!("heightmap {}", path.display()))?
        .len();
    anyhow::ensure!(
        len <= MAX_HEIGHTMAP_FILE,
        "heightmap {}: {len} bytes is over the {MAX_HEIGHTMAP_FILE}-byte cap",
        path.display()
    );
    let bytes =
        std::fs::read(path).with_context(|| format!("reading heightmap {}", path.display()))?;
    let is_png = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    // A PNG's size is in its bytes; a raw file's is the config's, and the
    // same bytes read at another size are another map.
    let mut size = String::new();
    let map = if is_png {
        Heightmap::from_png16(&bytes)
    } else {
        let (Some(w), Some(h)) = (section.width, section.height) else {
            anyhow::bail!(
                "heightmap {}: a raw file needs width and height",
                path.display()
            );
        };
        size = format!("{RAW_SIZE_MARK}{w}x{h}");
        Heightmap::from_raw(&bytes, w, h)
    }
    .with_context(|| format!("heightmap {}", path.display()))?
    .with_placement(section.placement)?;
    let generator = Generator::new(params.clone(), HeightSource::heightmap(map))?;
    let fingerprint = format!(
        "heightmap xxh3 {:016x}, {} bytes, {:?}{size}",
        hash_bytes(&bytes),
        bytes.len(),
        section.placement
    );
    Ok((generator, fingerprint))
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::ChunkGenerator;

    #[test]
    fn a_raw_size_is_left_out_as_older_data_dirs_recorded_it() {
        let params = "seed = 1\n# heightmap xxh3 00ff, 8 bytes, P, raw 2x2\n";
        assert_eq!(
            without_raw_size(params).as_deref(),
            Some("seed = 1\n# heightmap xxh3 00ff, 8 bytes, P\n")
        );
        for other in [
            "seed = 1\n# heightmap xxh3 00ff, 8 bytes, P\n",
            "seed = 1\n# heightmap xxh3 00ff, 8 bytes, P, raw 2x\n",
            "seed = 1\n# heightmap xxh3 00ff, 8 bytes, P, raw 2x2",
            "seed = 1\n",
        ] {
            assert_eq!(without_raw_size(other), None, "{other:?}");
        }
    }

    #[test]
    fn raw_maps_load_and_bad_ones_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("hills.raw");
        let samples: Vec<u8> = (0..64u32 * 64)
            .flat_map(|i| ((i % 64) as u16 * 512).to_le_bytes())
            .collect();
        std::fs::write(&path, &samples).unwrap();
        let mut section = HeightmapSection {
            path: path.clone(),
            width: Some(64),
            height: Some(64),
            placement: HeightmapPlacement::default(),
        };
        let (g, fingerprint) = load(&section, &GenParams::default()).unwrap();
        assert!(fingerprint.starts_with("heightmap "));
        // Heights rise along x, so the surface is higher at x = 60 than at x = 2.
        assert!(g.surface_height(60, 10) > g.surface_height(2, 10));
        assert_eq!(
            g.generate(strata_terrain::ChunkPos::new(0, 0, 0)),
            g.generate(strata_terrain::ChunkPos::new(0, 0, 0))
        );
        section.width = None;
        assert!(load(&section, &GenParams::default())
            .unwrap_err()
            .to_string()
            .contains("width and height"));
        section.width = Some(65);
        assert!(
            load(&section, &GenParams::default()).is_err(),
            "size mismatch"
        );
        section.path = dir.path().join("missing.png");
        assert!(load(&section, &GenParams::default()).is_err());
    }
}
