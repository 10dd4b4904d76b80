//! Map colours: materials from the material table, air, shading, lines.

use strata_terrain::{MaterialId, MaterialTable};

use super::Rgb;

/// Open air (nothing solid above it) in a horizontal slice.
pub const AIR: Rgb = [0x1b, 0x20, 0x2b];
/// Cave air (solid somewhere above it) in a horizontal slice.
pub const CAVE_AIR: Rgb = [0x3a, 0x24, 0x18];
/// Columns without any ground in a top-down map.
pub const VOID: Rgb = [0x10, 0x10, 0x14];
/// Outline of solid ground in a slice.
pub const SOLID_OUTLINE: Rgb = [0x0a, 0x0a, 0x0a];
/// Outline of a cave (rock bordering cave air) in a slice.
pub const CAVE_OUTLINE: Rgb = [0xff, 0xc4, 0x1f];
/// Ordinary height contour.
pub const CONTOUR: Rgb = [0x3b, 0x2a, 0x1a];
/// Index contour (every [`INDEX_EVERY`]th level).
pub const INDEX_CONTOUR: Rgb = [0x14, 0x0c, 0x05];
/// Every this many contour levels is drawn heavier.
pub const INDEX_EVERY: i64 = 5;

/// The table's colour of a material, without alpha.
pub fn material(table: &MaterialTable, id: MaterialId) -> Rgb {
    let [r, g, b, _] = table.rgba(id);
    [r, g, b]
}

/// `c` scaled by `factor` (clamped to 0..=2), for relief shading.
pub fn shade(c: Rgb, factor: f32) -> Rgb {
    let f = factor.clamp(0.0, 2.0);
    c.map(|v| (f32::from(v) * f).round().clamp(0.0, 255.0) as u8)
}

/// `#rrggbb`.
pub fn hex(c: Rgb) -> String {
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours() {
        let table = MaterialTable::default();
        let stone = material(&table, strata_terrain::material::ids::STONE);
        assert_eq!(hex(stone), "#7d7d7d");
        assert_eq!(shade([100, 200, 10], 1.5), [150, 255, 15]);
        assert_eq!(shade([100, 200, 10], -1.0), [0, 0, 0]);
    }
}
