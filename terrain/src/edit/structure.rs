//! Structure templates: voxel patterns stamped by `Edit::PlaceStructure`.
//!
//! File format (`.strs`, all integers little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 4 | magic `STRS` |
//! | 1 | format version, 1 |
//! | 2, 2, 2 | size x, y, z (each 1..=[`MAX_STRUCTURE_EDGE`]) |
//! | 1 | name length n |
//! | n | name, UTF-8 |
//! | x·y·z | density, x fastest, then y, then z |
//! | x·y·z | material, same order |
//!
//! A voxel with density 0 is "leave as is"; every other voxel replaces the
//! world voxel (unless the world voxel is indestructible).

use std::collections::BTreeMap;
use std::sync::Arc;

use thiserror::Error;

use crate::chunk::Voxel;

/// Identifies a template in a [`StructureLibrary`].
pub type StructureId = u32;

/// Largest template edge in voxels.
pub const MAX_STRUCTURE_EDGE: u16 = 128;
const MAGIC: &[u8; 4] = b"STRS";
const VERSION: u8 = 1;

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum StructureError {
    #[error("not a structure file (bad magic)")]
    BadMagic,
    #[error("unsupported structure format version {0}")]
    BadVersion(u8),
    #[error("structure file truncated: needs {needed} bytes, has {have}")]
    Truncated { needed: usize, have: usize },
    #[error("structure file has {0} trailing bytes")]
    TrailingBytes(usize),
    #[error("structure size {0:?} must be 1..={MAX_STRUCTURE_EDGE} on every axis")]
    BadSize([u16; 3]),
    #[error("structure name is not UTF-8")]
    BadName,
    #[error("plane length does not match size")]
    PlaneLength,
}

/// A voxel template.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Structure {
    pub name: String,
    size: [u16; 3],
    density: Vec<u8>,
    material: Vec<u8>,
    /// The distinct materials of its non-air cells, in the order they first
    /// occur: what an edit placing it checks (the first refused is the one
    /// a scan of the cells would meet first), without a scan per edit.
    placed: Vec<u8>,
}

impl Structure {
    /// Builds a template from planes in x-fastest order.
    pub fn new(
        name: impl Into<String>,
        size: [u16; 3],
        density: Vec<u8>,
        material: Vec<u8>,
    ) -> Result<Self, StructureError> {
        if size.iter().any(|&s| s == 0 || s > MAX_STRUCTURE_EDGE) {
            return Err(StructureError::BadSize(size));
        }
        let n = size.iter().map(|&s| s as usize).product::<usize>();
        if density.len() != n || material.len() != n {
            return Err(StructureError::PlaneLength);
        }
        let mut seen = [false; 256];
        let mut placed = Vec::new();
        for (d, m) in density.iter().zip(&material) {
            if *d > 0 && !std::mem::replace(&mut seen[*m as usize], true) {
                placed.push(*m);
            }
        }
        Ok(Self {
            name: name.into(),
            size,
            density,
            material,
            placed,
        })
    }

    /// Builds a template by evaluating `f(x, y, z)` for every cell.
    pub fn from_fn(
        name: impl Into<String>,
        size: [u16; 3],
        mut f: impl FnMut(u16, u16, u16) -> Voxel,
    ) -> Result<Self, StructureError> {
        if size.iter().any(|&s| s == 0 || s > MAX_STRUCTURE_EDGE) {
            return Err(StructureError::BadSize(size));
        }
        let (mut d, mut m) = (Vec::new(), Vec::new());
        for z in 0..size[2] {
            for y in 0..size[1] {
                for x in 0..size[0] {
                    let v = f(x, y, z);
                    d.push(v.density);
                    m.push(v.material);
                }
            }
        }
        Self::new(name, size, d, m)
    }

    pub fn size(&self) -> [u16; 3] {
        self.size
    }

    /// Footprint after `rotation` quarter turns about +Y.
    pub fn rotated_size(&self, rotation: u8) -> [u16; 3] {
        let [x, y, z] = self.size;
        if rotation % 2 == 1 {
            [z, y, x]
        } else {
            [x, y, z]
        }
    }

    /// Template voxel at footprint offset `(u, y, v)` after rotation.
    pub fn rotated_voxel(&self, rotation: u8, u: u16, y: u16, v: u16) -> Voxel {
        let [sx, _, sz] = self.size;
        let (x, z) = match rotation & 3 {
            0 => (u, v),
            1 => (sx - 1 - v, u),
            2 => (sx - 1 - u, sz - 1 - v),
            _ => (v, sz - 1 - u),
        };
        let i =
            x as usize + self.size[0] as usize * (y as usize + self.size[1] as usize * z as usize);
        Voxel::new(self.density[i], self.material[i])
    }

    /// The distinct materials this template places (of its non-air
    /// cells), in the order they first occur (x fastest, then y, then z).
    pub fn materials(&self) -> impl Iterator<Item = u8> + '_ {
        self.placed.iter().copied()
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        // At most 255 bytes, cut on a character boundary (it must read back).
        let mut end = self.name.len().min(255);
        while !self.name.is_char_boundary(end) {
            end -= 1;
        }
        let name = &self.name.as_bytes()[..end];
        let mut out = Vec::with_capacity(12 + name.len() + 2 * self.density.len());
        out.extend_from_slice(MAGIC);
        out.push(VERSION);
        for s in self.size {
            out.extend_from_slice(&s.to_le_bytes());
        }
        out.push(name.len() as u8);
        out.extend_from_slice(name);
        out.extend_from_slice(&self.density);
        out.extend_from_slice(&self.material);
        out
    }

    pub fn from_bytes(b: &[u8]) -> Result<Self, StructureError> {
        let need = |n: usize| {
            if b.len() < n {
                Err(StructureError::Truncated {
                    needed: n,
                    have: b.len(),
                })
            } else {
                Ok(())
            }
        };
        need(12)?;
        if &b[0..4] != MAGIC {
            return Err(StructureError::BadMagic);
        }
        if b[4] != VERSION {
            return Err(StructureError::BadVersion(b[4]));
        }
        let size = [0, 1, 2].map(|i| u16::from_le_bytes([b[5 + 2 * i], b[6 + 2 * i]]));
        if size.iter().any(|&s| s == 0 || s > MAX_STRUCTURE_EDGE) {
            return Err(StructureError::BadSize(size));
        }
        let name_len = b[11] as usize;
        let n = size.iter().map(|&s| s as usize).product::<usize>();
        let total = 12 + name_len + 2 * n;
        need(total)?;
        if b.len() > total {
            return Err(StructureError::TrailingBytes(b.len() - total));
        }
        let name =
            std::str::from_utf8(&b[12..12 + name_len]).map_err(|_| StructureError::BadName)?;
        let body = &b[12 + name_len..];
        Self::new(name, size, body[..n].to_vec(), body[n..].to_vec())
    }
}

/// Templates by id, shared read-only by everyone that applies edits.
#[derive(Debug, Clone, Default)]
pub struct StructureLibrary {
    by_id: BTreeMap<StructureId, Arc<Structure>>,
}

impl StructureLibrary {
    pub fn insert(&mut self, id: StructureId, s: Structure) {
        self.by_id.insert(id, Arc::new(s));
    }

    pub fn get(&self, id: StructureId) -> Option<&Arc<Structure>> {
        self.by_id.get(&id)
    }

    pub fn iter(&self) -> impl Iterator<Item = (StructureId, &Arc<Structure>)> {
        self.by_id.iter().map(|(k, v)| (*k, v))
    }

    pub fn len(&self) -> usize {
        self.by_id.len()
    }

    pub fn is_empty(&self) -> bool {
        self.by_id.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Structure {
        Structure::from_fn("L", [3, 2, 2], |x, y, z| {
            Voxel::new(x as u8 + 10 * y as u8 + 100 * z as u8 + 1, 7)
        })
        .unwrap()
    }

    #[test]
    fn file_round_trip_and_errors() {
        let s = sample();
        let bytes = s.to_bytes();
        assert_eq!(Structure::from_bytes(&bytes).unwrap(), s);
        assert_eq!(
            Structure::from_bytes(b"NOPE00000000"),
            Err(StructureError::BadMagic)
        );
        let mut v2 = bytes.clone();
        v2[4] = 9;
        assert_eq!(
            Structure::from_bytes(&v2),
            Err(StructureError::BadVersion(9))
        );
        assert!(matches!(
            Structure::from_bytes(&bytes[..bytes.len() - 1]),
            Err(StructureError::Truncated { .. })
        ));
        let mut long = bytes.clone();
        long.push(0);
        assert_eq!(
            Structure::from_bytes(&long),
            Err(StructureError::TrailingBytes(1))
        );
        let mut zero = bytes;
        zero[5] = 0;
        assert!(matches!(
            Structure::from_bytes(&zero),
            Err(StructureError::BadSize(_))
        ));
        assert!(Structure::new("x", [2, 2, 2], vec![0; 7], vec![0; 8]).is_err());
    }

    #[test]
    fn a_long_name_is_cut_on_a_character_boundary() {
        // 254 ASCII bytes then a 2-byte character: byte 255 is inside it.
        let name = format!("{}é", "a".repeat(254));
        let s = Structure::from_fn(name, [1, 1, 1], |_, _, _| Voxel::solid(7)).unwrap();
        let back = Structure::from_bytes(&s.to_bytes()).unwrap();
        assert_eq!(back.name, "a".repeat(254));
    }

    #[test]
    fn rotations_are_quarter_turns() {
        let s = sample();
        assert_eq!(s.rotated_size(1), [2, 2, 3]);
        // Four quarter turns of the footprint map each voxel back to itself.
        for r in 0..4u8 {
            let [fu, fy, fv] = s.rotated_size(r);
            let mut seen = Vec::new();
            for v in 0..fv {
                for y in 0..fy {
                    for u in 0..fu {
                        seen.push(s.rotated_voxel(r, u, y, v).density);
                    }
                }
            }
            seen.sort_unstable();
            let mut all = s.density.clone();
            all.sort_unstable();
            assert_eq!(seen, all, "rotation {r} is a permutation");
        }
        // Rotation 1: template +x runs along footprint -v, template +z along +u.
        assert_eq!(s.rotated_voxel(1, 0, 0, 2), s.rotated_voxel(0, 0, 0, 0));
        assert_eq!(s.rotated_voxel(1, 1, 0, 2), s.rotated_voxel(0, 0, 0, 1));
        assert_eq!(s.rotated_voxel(2, 2, 0, 1), s.rotated_voxel(0, 0, 0, 0));
    }

    #[test]
    fn materials_are_the_distinct_ones_of_non_air_cells() {
        // Air cells (density 0) carry material 9, which is never placed.
        let s = Structure::from_fn("m", [4, 4, 4], |x, y, z| match (x + y + z) % 3 {
            0 => Voxel::new(0, 9),
            1 => Voxel::new(200, 5),
            _ => Voxel::new(1, 2),
        })
        .unwrap();
        // Cell (0, 0, 0) is air, (1, 0, 0) material 5, (2, 0, 0) material 2.
        assert_eq!(s.materials().collect::<Vec<_>>(), vec![5, 2]);
        let back = Structure::from_bytes(&s.to_bytes()).unwrap();
        assert_eq!(back.materials().collect::<Vec<_>>(), vec![5, 2]);
    }
}
