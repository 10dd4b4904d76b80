//! Heightmap terrain (seed 002): a grayscale image gives the surface height.
//!
//! terrain does no file I/O, so maps arrive as bytes: a PNG (16-bit gray, or
//! 8-bit gray scaled up) or raw little-endian u16 samples. Sampling is
//! bilinear between pixels and clamps to the edge outside the map.

use std::io::Cursor;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Largest accepted width or height, in pixels. 8192² u16 samples are
/// 128 MiB, the most a server should hold for one map.
pub const MAX_HEIGHTMAP_SIDE: u32 = 8192;
/// Largest accepted `voxels_per_pixel` (horizontal stretch).
pub const MAX_VOXELS_PER_PIXEL: u32 = 1024;
/// Largest accepted `|vertical_scale|` and `|base_y|`, in voxels: beyond this
/// heights leave any sensible world.
pub const MAX_HEIGHTMAP_EXTENT: f64 = 1_048_576.0;
/// Default vertical scale: the full u16 range spans 256 voxels.
pub const DEFAULT_VERTICAL_SCALE: f64 = 1.0 / 256.0;
/// PNG decoder memory cap: the largest map plus room for the row buffers.
const PNG_DECODE_LIMIT_BYTES: usize =
    (MAX_HEIGHTMAP_SIDE as usize) * (MAX_HEIGHTMAP_SIDE as usize) * 4 + (1 << 20);

/// Why a heightmap was rejected.
#[derive(Debug, Error, Clone, PartialEq, Eq)]
pub enum HeightmapError {
    #[error("heightmap is not a readable PNG: {0}")]
    BadPng(String),
    #[error("heightmap PNG must be 8- or 16-bit grayscale, got {color} at {bits} bits")]
    NotGrayscale { color: String, bits: u8 },
    #[error("heightmap has a zero dimension ({width}x{height})")]
    ZeroDims { width: u32, height: u32 },
    #[error("heightmap {width}x{height} exceeds the {max} pixel per side cap")]
    TooLarge { width: u32, height: u32, max: u32 },
    #[error("raw heightmap of {width}x{height} needs {expected} bytes, got {actual}")]
    RawSize {
        width: u32,
        height: u32,
        expected: u64,
        actual: usize,
    },
    #[error("heightmap placement: {0}")]
    BadPlacement(&'static str),
}

/// Where a heightmap sits in the world and how its values become voxels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HeightmapPlacement {
    /// World x of pixel column 0.
    pub origin_x: i32,
    /// World z of pixel row 0.
    pub origin_z: i32,
    /// Surface height (voxels) for sample value 0.
    pub base_y: f64,
    /// Voxels per sample unit (u16 value 65535 is `base_y + 65535 * scale`).
    pub vertical_scale: f64,
    /// Voxels per pixel horizontally; heights between pixel centres are
    /// interpolated bilinearly.
    pub voxels_per_pixel: u32,
}

impl Default for HeightmapPlacement {
    fn default() -> Self {
        Self {
            origin_x: 0,
            origin_z: 0,
            base_y: 0.0,
            vertical_scale: DEFAULT_VERTICAL_SCALE,
            voxels_per_pixel: 1,
        }
    }
}

impl HeightmapPlacement {
    fn validate(&self) -> Result<(), HeightmapError> {
        let finite_in = |v: f64| v.is_finite() && v.abs() <= MAX_HEIGHTMAP_EXTENT;
        if !finite_in(self.base_y) {
            return Err(HeightmapError::BadPlacement(
                "base_y must be finite and within ±2^20",
            ));
        }
        if !finite_in(self.vertical_scale) || self.vertical_scale < 0.0 {
            return Err(HeightmapError::BadPlacement(
                "vertical_scale must be finite, non-negative and at most 2^20",
            ));
        }
        if self.voxels_per_pixel == 0 || self.voxels_per_pixel > MAX_VOXELS_PER_PIXEL {
            return Err(HeightmapError::BadPlacement(
                "voxels_per_pixel must be 1..=1024",
            ));
        }
        Ok(())
    }
}

/// A decoded heightmap: u16 samples, row-major (x fastest), plus placement.
#[derive(Clone, PartialEq)]
pub struct Heightmap {
    width: u32,
    height: u32,
    samples: Vec<u16>,
    max_sample: u16,
    placement: HeightmapPlacement,
}

impl std::fmt::Debug for Heightmap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Heightmap")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("max_sample", &self.max_sample)
            .field("placement", &self.placement)
            .finish_non_exhaustive()
    }
}

fn check_dims(width: u32, height: u32) -> Result<(), HeightmapError> {
    if width == 0 || height == 0 {
        return Err(HeightmapError::ZeroDims { width, height });
    }
    if width > MAX_HEIGHTMAP_SIDE || height > MAX_HEIGHTMAP_SIDE {
        return Err(HeightmapError::TooLarge {
            width,
            height,
            max: MAX_HEIGHTMAP_SIDE,
        });
    }
    Ok(())
}

impl Heightmap {
    /// A map from samples already in memory (row-major, x fastest).
    pub fn from_samples(
        width: u32,
        height: u32,
        samples: Vec<u16>,
    ) -> Result<Self, HeightmapError> {
        check_dims(width, height)?;
        let expected = width as u64 * height as u64;
        if samples.len() as u64 != expected {
            return Err(HeightmapError::RawSize {
                width,
                height,
                expected: expected * 2,
                actual: samples.len() * 2,
            });
        }
        let max_sample = samples.iter().copied().max().unwrap_or(0);
        Ok(Self {
            width,
            height,
            samples,
            max_sample,
            placement: HeightmapPlacement::default(),
        })
    }

    /// Raw little-endian u16 samples, row-major, exactly `width * height * 2` bytes.
    pub fn from_raw(bytes: &[u8], width: u32, height: u32) -> Result<Self, HeightmapError> {
        check_dims(width, height)?;
        let expected = width as u64 * height as u64 * 2;
        if bytes.len() as u64 != expected {
            return Err(HeightmapError::RawSize {
                width,
                height,
                expected,
                actual: bytes.len(),
            });
        }
        let samples = bytes
            .chunks_exact(2)
            .map(|p| u16::from_le_bytes([p[0], p[1]]))
            .collect();
        Self::from_samples(width, height, samples)
    }

    /// A grayscale PNG: 16-bit samples as they are, 8-bit (and lower, after
    /// expansion) scaled by 257 so white is 65535. An alpha channel is ignored.
    pub fn from_png16(bytes: &[u8]) -> Result<Self, HeightmapError> {
        let bad = |e: png::DecodingError| HeightmapError::BadPng(e.to_string());
        let mut decoder = png::Decoder::new_with_limits(
            Cursor::new(bytes),
            png::Limits {
                bytes: PNG_DECODE_LIMIT_BYTES,
            },
        );
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(bad)?;
        let (width, height) = reader.info().size();
        // Checked before the frame buffer is allocated.
        check_dims(width, height)?;
        let (color, depth) = reader.output_color_type();
        let channels = match color {
            png::ColorType::Grayscale => 1,
            png::ColorType::GrayscaleAlpha => 2,
            other => {
                return Err(HeightmapError::NotGrayscale {
                    color: format!("{other:?}"),
                    bits: depth as u8,
                })
            }
        };
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| HeightmapError::BadPng("image too large for memory".into()))?;
        let mut buf = vec![0u8; size];
        let frame = reader.next_frame(&mut buf).map_err(bad)?;
        let line = frame.line_size;
        let mut samples = Vec::with_capacity(width as usize * height as usize);
        for row in buf.chunks_exact(line).take(height as usize) {
            match depth {
                png::BitDepth::Sixteen => samples.extend(
                    row.chunks_exact(2 * channels)
                        .take(width as usize)
                        .map(|p| u16::from_be_bytes([p[0], p[1]])),
                ),
                png::BitDepth::Eight => samples.extend(
                    row.chunks_exact(channels)
                        .take(width as usize)
                        .map(|p| p[0] as u16 * 257),
                ),
                other => {
                    return Err(HeightmapError::NotGrayscale {
                        color: format!("{color:?}"),
                        bits: other as u8,
                    })
                }
            }
        }
        Self::from_samples(width, height, samples)
    }

    /// The same map placed differently in the world.
    pub fn with_placement(mut self, placement: HeightmapPlacement) -> Result<Self, HeightmapError> {
        placement.validate()?;
        self.placement = placement;
        Ok(self)
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn placement(&self) -> &HeightmapPlacement {
        &self.placement
    }

    /// The raw sample at a pixel, clamped to the edge.
    pub fn sample(&self, px: i64, pz: i64) -> u16 {
        let x = px.clamp(0, self.width as i64 - 1) as usize;
        let z = pz.clamp(0, self.height as i64 - 1) as usize;
        self.samples[z * self.width as usize + x]
    }

    /// One axis: pixel index and fraction (in voxels) of world coordinate
    /// `w`, clamped so positions outside the map take the edge pixel.
    fn axis(w: i64, origin: i32, vpp: u32, len: u32) -> (i64, i64) {
        let u = w - origin as i64;
        let (p, f) = (u.div_euclid(vpp as i64), u.rem_euclid(vpp as i64));
        if p < 0 {
            (0, 0)
        } else if p >= len as i64 - 1 {
            (len as i64 - 1, 0)
        } else {
            (p, f)
        }
    }

    /// Bilinearly interpolated sample (in sample units) at a world column.
    pub fn interpolated(&self, x: i32, z: i32) -> f64 {
        self.interpolated_wide(x as i64, z as i64)
    }

    fn interpolated_wide(&self, x: i64, z: i64) -> f64 {
        let p = &self.placement;
        let vpp = p.voxels_per_pixel;
        let (px, fx) = Self::axis(x, p.origin_x, vpp, self.width);
        let (pz, fz) = Self::axis(z, p.origin_z, vpp, self.height);
        let s = |dx: i64, dz: i64| self.sample(px + dx, pz + dz) as f64;
        let (tx, tz) = (fx as f64 / vpp as f64, fz as f64 / vpp as f64);
        let top = s(0, 0) + (s(1, 0) - s(0, 0)) * tx;
        let bottom = s(0, 1) + (s(1, 1) - s(0, 1)) * tx;
        top + (bottom - top) * tz
    }

    /// Surface height in voxels at a world column.
    pub fn height_at(&self, x: i32, z: i32) -> f64 {
        self.height_at_wide(x as i64, z as i64)
    }

    /// [`Self::height_at`] for the generator, whose chunk origins can pass i32.
    pub(crate) fn height_at_wide(&self, x: i64, z: i64) -> f64 {
        self.placement.base_y + self.interpolated_wide(x, z) * self.placement.vertical_scale
    }

    /// The highest surface height anywhere on the map (and so in the world).
    pub fn max_height(&self) -> f64 {
        self.placement.base_y + self.max_sample as f64 * self.placement.vertical_scale
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_and_edge_clamp() {
        let m = Heightmap::from_samples(2, 2, vec![0, 100, 200, 300])
            .unwrap()
            .with_placement(HeightmapPlacement {
                voxels_per_pixel: 4,
                vertical_scale: 1.0,
                ..Default::default()
            })
            .unwrap();
        assert_eq!(m.interpolated(0, 0), 0.0);
        assert_eq!(m.interpolated(2, 0), 50.0);
        assert_eq!(m.interpolated(2, 2), 150.0);
        assert_eq!(m.interpolated(4, 4), 300.0);
        assert_eq!(m.interpolated(-50, -50), 0.0);
        assert_eq!(m.interpolated(1000, 0), 100.0);
        assert_eq!(m.interpolated(1000, 2), 200.0);
        assert_eq!(m.max_height(), 300.0);
    }
}
