//! The material table: loaded from data (TOML), with shipped defaults.

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// A material id stored per voxel.
pub type MaterialId = u8;

/// Ids of the default materials. The generator uses these; a custom table
/// must keep them (checked by [`MaterialTable::require_defaults`]).
pub mod ids {
    use super::MaterialId;
    pub const AIR: MaterialId = 0;
    pub const GRASS: MaterialId = 1;
    pub const DIRT: MaterialId = 2;
    pub const STONE: MaterialId = 3;
    pub const SAND: MaterialId = 4;
    pub const BEDROCK: MaterialId = 5;
    pub const ORE: MaterialId = 6;
    pub const BRICK: MaterialId = 7;
}

/// Hardness of dirt: the reference for mining speed.
pub const REFERENCE_HARDNESS: u8 = 16;

/// The shipped default table, as TOML.
pub const DEFAULT_TABLE_TOML: &str = include_str!("../data/materials.toml");

/// One material's properties.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Material {
    pub id: MaterialId,
    pub name: String,
    /// Mining resistance, 1..=255; mining removes `strength * 16 / hardness`.
    pub hardness: u8,
    /// Never changed by any edit (bedrock).
    #[serde(default)]
    pub indestructible: bool,
    /// Display colour `#rrggbb` or `#rrggbbaa`, for maps and exports.
    #[serde(default = "default_color")]
    pub color: String,
}

fn default_color() -> String {
    "#ff00ff".to_string()
}

#[derive(Debug, Error, PartialEq, Eq)]
pub enum MaterialError {
    #[error("material table is not valid TOML: {0}")]
    Parse(String),
    #[error("material id {0} is defined twice")]
    DuplicateId(MaterialId),
    #[error("material {name:?}: hardness must be 1..=255, got 0")]
    ZeroHardness { name: String },
    #[error("material {name:?}: colour {color:?} is not #rrggbb or #rrggbbaa")]
    BadColor { name: String, color: String },
    #[error("default material {0:?} (id {1}) is missing or renamed")]
    MissingDefault(&'static str, MaterialId),
}

#[derive(Deserialize)]
struct TableFile {
    material: Vec<Material>,
}

/// Materials indexed by id; unknown ids behave as destructible, hardness 16.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MaterialTable {
    by_id: Vec<Option<Material>>,
}

impl Default for MaterialTable {
    fn default() -> Self {
        Self::from_toml(DEFAULT_TABLE_TOML).expect("shipped material table is valid")
    }
}

impl MaterialTable {
    /// Parses a table from TOML text (`[[material]]` entries).
    pub fn from_toml(text: &str) -> Result<Self, MaterialError> {
        let file: TableFile = toml::from_str(text).map_err(|e| MaterialError::Parse(e.to_string()))?;
        let mut by_id: Vec<Option<Material>> = vec![None; 256];
        for m in file.material {
            if m.hardness == 0 {
                return Err(MaterialError::ZeroHardness { name: m.name });
            }
            if parse_color(&m.color).is_none() {
                return Err(MaterialError::BadColor { name: m.name, color: m.color });
            }
            let slot = &mut by_id[m.id as usize];
            if slot.is_some() {
                return Err(MaterialError::DuplicateId(m.id));
            }
            *slot = Some(m);
        }
        let table = Self { by_id };
        table.require_defaults()?;
        Ok(table)
    }

    /// Checks that the default ids carry their default names.
    pub fn require_defaults(&self) -> Result<(), MaterialError> {
        const DEFAULTS: [(&str, MaterialId); 8] = [
            ("air", ids::AIR),
            ("grass", ids::GRASS),
            ("dirt", ids::DIRT),
            ("stone", ids::STONE),
            ("sand", ids::SAND),
            ("bedrock", ids::BEDROCK),
            ("ore", ids::ORE),
            ("brick", ids::BRICK),
        ];
        for (name, id) in DEFAULTS {
            match self.get(id) {
                Some(m) if m.name == name => {}
                _ => return Err(MaterialError::MissingDefault(name, id)),
            }
        }
        Ok(())
    }

    pub fn get(&self, id: MaterialId) -> Option<&Material> {
        self.by_id[id as usize].as_ref()
    }

    pub fn by_name(&self, name: &str) -> Option<&Material> {
        self.iter().find(|m| m.name == name)
    }

    pub fn iter(&self) -> impl Iterator<Item = &Material> {
        self.by_id.iter().flatten()
    }

    #[inline]
    pub fn is_indestructible(&self, id: MaterialId) -> bool {
        self.by_id[id as usize].as_ref().is_some_and(|m| m.indestructible)
    }

    #[inline]
    pub fn hardness(&self, id: MaterialId) -> u8 {
        self.by_id[id as usize].as_ref().map_or(REFERENCE_HARDNESS, |m| m.hardness)
    }

    /// RGBA colour of a material; magenta for unknown ids.
    pub fn rgba(&self, id: MaterialId) -> [u8; 4] {
        self.get(id).and_then(|m| parse_color(&m.color)).unwrap_or([255, 0, 255, 255])
    }
}

fn parse_color(s: &str) -> Option<[u8; 4]> {
    let hex = s.strip_prefix('#')?;
    if !(hex.len() == 6 || hex.len() == 8) || !hex.is_ascii() {
        return None;
    }
    let byte = |i: usize| u8::from_str_radix(&hex[i..i + 2], 16).ok();
    let a = if hex.len() == 8 { byte(6)? } else { 255 };
    Some([byte(0)?, byte(2)?, byte(4)?, a])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_load() {
        let t = MaterialTable::default();
        assert!(t.is_indestructible(ids::BEDROCK));
        assert!(!t.is_indestructible(ids::STONE));
        assert_eq!(t.by_name("ore").unwrap().id, ids::ORE);
        assert_eq!(t.rgba(ids::GRASS), [0x4f, 0x9a, 0x3a, 255]);
        assert_eq!(t.iter().count(), 8);
    }

    #[test]
    fn rejects_bad_tables() {
        let dup = format!("{DEFAULT_TABLE_TOML}\n[[material]]\nid = 3\nname = \"x\"\nhardness = 1\n");
        assert_eq!(MaterialTable::from_toml(&dup), Err(MaterialError::DuplicateId(3)));
        let renamed = DEFAULT_TABLE_TOML.replace("\"bedrock\"", "\"rock\"");
        assert_eq!(
            MaterialTable::from_toml(&renamed),
            Err(MaterialError::MissingDefault("bedrock", ids::BEDROCK))
        );
        let zero = DEFAULT_TABLE_TOML.replace("hardness = 8", "hardness = 0");
        assert!(matches!(MaterialTable::from_toml(&zero), Err(MaterialError::ZeroHardness { .. })));
        assert!(matches!(MaterialTable::from_toml("not toml ["), Err(MaterialError::Parse(_))));
        let color = DEFAULT_TABLE_TOML.replace("#d8c88a", "sandy");
        assert!(matches!(MaterialTable::from_toml(&color), Err(MaterialError::BadColor { .. })));
    }

    #[test]
    fn extra_materials_allowed() {
        let more = format!(
            "{DEFAULT_TABLE_TOML}\n[[material]]\nid = 42\nname = \"glass\"\nhardness = 4\ncolor = \"#aaddff80\"\n"
        );
        let t = MaterialTable::from_toml(&more).unwrap();
        assert_eq!(t.hardness(42), 4);
        assert_eq!(t.rgba(42), [0xaa, 0xdd, 0xff, 0x80]);
        assert_eq!(t.hardness(200), REFERENCE_HARDNESS);
    }
}
