//! Raster maps: sample squares, then contour lines stamped along their
//! length, encoded as an 8-bit RGB PNG.

use std::io::Write;

use super::{MapError, MapImage, Rgb};

/// Distance between line stamps, in pixels: dense enough for no gaps.
const STAMP_STEP: f32 = 0.5;

/// An RGB pixel buffer.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster {
    pub width: u32,
    pub height: u32,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

impl Raster {
    fn put(&mut self, x: i64, y: i64, c: Rgb) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = (y as usize * self.width as usize + x as usize) * 3;
        self.rgb[i..i + 3].copy_from_slice(&c);
    }

    /// Fills the pixels within `half` of `(x, y)` (at least the one pixel
    /// holding the point).
    fn stamp(&mut self, x: f32, y: f32, half: f32, c: Rgb) {
        let (x0, x1) = ((x - half).floor() as i64, (x + half).ceil() as i64 - 1);
        let (y0, y1) = ((y - half).floor() as i64, (y + half).ceil() as i64 - 1);
        for py in y0..=y1.max(y0) {
            for px in x0..=x1.max(x0) {
                self.put(px, py, c);
            }
        }
    }

    fn segment(&mut self, a: [f32; 2], b: [f32; 2], width: f32, c: Rgb) {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let steps = ((dx.abs().max(dy.abs()) / STAMP_STEP).ceil() as u32).max(1);
        for s in 0..=steps {
            let t = s as f32 / steps as f32;
            self.stamp(a[0] + dx * t, a[1] + dy * t, width / 2.0, c);
        }
    }
}

/// Draws the map into a raster.
pub fn rasterize(map: &MapImage) -> Result<Raster, MapError> {
    let (w, h) = map.pixel_size()?;
    let mut r = Raster {
        width: w,
        height: h,
        rgb: vec![0; w as usize * h as usize * 3],
    };
    let s = map.scale as usize;
    for (row, line) in r.rgb.chunks_exact_mut(w as usize * 3).enumerate() {
        let j = row / s;
        let samples = &map.fill[j * map.width as usize..(j + 1) * map.width as usize];
        for (px, out) in line.chunks_exact_mut(3).enumerate() {
            out.copy_from_slice(&samples[px / s]);
        }
    }
    for line in &map.lines {
        let pts: Vec<[f32; 2]> = line.points.iter().map(|p| map.to_pixel(*p)).collect();
        for pair in pts.windows(2) {
            r.segment(pair[0], pair[1], line.width, line.color);
        }
        if line.closed && pts.len() > 2 {
            r.segment(pts[pts.len() - 1], pts[0], line.width, line.color);
        }
    }
    Ok(r)
}

/// Writes the map as an 8-bit RGB PNG.
pub fn write_png(map: &MapImage, out: &mut impl Write) -> Result<(), MapError> {
    let raster = rasterize(map)?;
    let png_err = |e: png::EncodingError| MapError::Png(e.to_string());
    let mut enc = png::Encoder::new(out, raster.width, raster.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(png_err)?;
    writer.write_image_data(&raster.rgb).map_err(png_err)?;
    writer.finish().map_err(png_err)
}

#[cfg(test)]
mod tests {
    use super::super::MapLine;
    use super::*;

    fn map() -> MapImage {
        MapImage {
            origin: [-4, 10],
            width: 4,
            height: 3,
            fill: (0..12u8).map(|i| [i, 0, 0]).collect(),
            lines: vec![MapLine {
                points: vec![[-4.0, 10.0], [-1.0, 10.0]],
                closed: false,
                color: [0, 255, 0],
                width: 1.0,
            }],
            scale: 2,
            title: String::new(),
            legend: vec![],
        }
    }

    #[test]
    fn fills_samples_and_draws_lines() {
        let r = rasterize(&map()).unwrap();
        assert_eq!((r.width, r.height), (8, 6));
        let px = |x: usize, y: usize| {
            let i = (y * 8 + x) * 3;
            [r.rgb[i], r.rgb[i + 1], r.rgb[i + 2]]
        };
        // Sample (1, 2) covers pixels (2..4, 4..6).
        assert_eq!(px(3, 5), [9, 0, 0]);
        // The line runs along the middle of row 0's samples: pixel row 1.
        assert_eq!(px(0, 1), [0, 255, 0]);
        assert_eq!(px(7, 1), [0, 255, 0]);
        assert_eq!(px(4, 3), [6, 0, 0]);
    }

    #[test]
    fn bad_sizes_are_refused() {
        let mut m = map();
        m.scale = 0;
        assert_eq!(rasterize(&m), Err(MapError::BadScale(0)));
        m.scale = 16;
        m.width = 2000;
        m.fill = vec![[0; 3]; 2000 * 3];
        assert!(matches!(rasterize(&m), Err(MapError::TooLarge { .. })));
    }
}
