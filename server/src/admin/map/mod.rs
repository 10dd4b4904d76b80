//! A map picture independent of its file format: one colour per voxel
//! sample and contour lines on top, written as PNG ([`png`]) or SVG
//! ([`svg`]).
//!
//! Coordinates: sample `(i, j)` is world `(origin.x + i, origin.z + j)`;
//! image x grows with world x and image y with world z (so north, -z, is
//! up). At `scale` pixels per voxel, sample `(i, j)` covers the pixel square
//! from `(i * scale, j * scale)`, and a world point `(x, z)` (a contour
//! vertex, where samples sit at integer positions) lands at
//! `((x - origin.x + 0.5) * scale, (z - origin.z + 0.5) * scale)`: the
//! middle of its sample's square.

pub mod palette;
pub mod png;
pub mod svg;

use thiserror::Error;

/// Largest image side in pixels.
pub const MAX_IMAGE_SIDE: u64 = 16_384;
/// Largest `--scale` (pixels per voxel).
pub const MAX_SCALE: u32 = 16;

/// An RGB colour.
pub type Rgb = [u8; 3];

/// One contour line in world `(x, z)` units.
#[derive(Debug, Clone, PartialEq)]
pub struct MapLine {
    pub points: Vec<[f32; 2]>,
    /// A loop: the last point joins the first.
    pub closed: bool,
    pub color: Rgb,
    /// Stroke width in pixels.
    pub width: f32,
}

/// A map: a grid of sample colours plus lines.
#[derive(Debug, Clone, PartialEq)]
pub struct MapImage {
    /// World `(x, z)` of sample `(0, 0)`.
    pub origin: [i32; 2],
    /// Samples along x and z.
    pub width: u32,
    pub height: u32,
    /// Row-major colours, x fastest: `fill[j * width + i]`.
    pub fill: Vec<Rgb>,
    pub lines: Vec<MapLine>,
    /// Pixels per voxel sample.
    pub scale: u32,
    /// A one-line description (the SVG `<title>`).
    pub title: String,
    /// Colour keys shown in the SVG legend: `(name, colour)`.
    pub legend: Vec<(String, Rgb)>,
}

/// Why a map cannot be drawn.
#[derive(Debug, Error, PartialEq)]
pub enum MapError {
    #[error("scale {0} is out of range 1..={MAX_SCALE}")]
    BadScale(u32),
    #[error("the image would be {width}x{height} pixels; each side must be at most {MAX_IMAGE_SIDE} (lower --scale or the region)")]
    TooLarge { width: u64, height: u64 },
    #[error("{got} fill colours for {width}x{height} samples")]
    FillLength { width: u32, height: u32, got: usize },
    #[error("PNG encoding failed: {0}")]
    Png(String),
}

impl MapImage {
    /// Image size in pixels, checked against [`MAX_IMAGE_SIDE`].
    pub fn pixel_size(&self) -> Result<(u32, u32), MapError> {
        if !(1..=MAX_SCALE).contains(&self.scale) {
            return Err(MapError::BadScale(self.scale));
        }
        if self.fill.len() != self.width as usize * self.height as usize {
            return Err(MapError::FillLength {
                width: self.width,
                height: self.height,
                got: self.fill.len(),
            });
        }
        let (w, h) = (
            u64::from(self.width) * u64::from(self.scale),
            u64::from(self.height) * u64::from(self.scale),
        );
        if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || w == 0 || h == 0 {
            return Err(MapError::TooLarge {
                width: w,
                height: h,
            });
        }
        Ok((w as u32, h as u32))
    }

    /// Pixel position of world point `(x, z)`.
    pub fn to_pixel(&self, p: [f32; 2]) -> [f32; 2] {
        let s = self.scale as f32;
        [
            (p[0] - self.origin[0] as f32 + 0.5) * s,
            (p[1] - self.origin[1] as f32 + 0.5) * s,
        ]
    }
}
