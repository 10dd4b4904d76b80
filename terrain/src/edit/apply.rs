//! Validation and application of edits to a chunked [`World`] or a [`Region`].

use std::sync::Arc;

use super::error::EditError;
use super::fixed::{Fixed, FixedVec3, COORD_LIMIT_VOXELS, ONE};
use super::kernel::{apply_voxel, beyond};
use super::limits::*;
use super::region::Region;
use super::structure::{Structure, StructureLibrary};
use super::Edit;
use crate::chunk::Chunk;
use crate::material::{MaterialId, MaterialTable};
use crate::pos::{local_index, ChunkPos, VoxelBox, VoxelPos};
use crate::world::{VoxelRead, World};

/// What an edit needs besides the world: the material table and templates.
#[derive(Debug, Clone, Copy)]
pub struct EditContext<'a> {
    pub materials: &'a MaterialTable,
    pub structures: &'a StructureLibrary,
}

/// One chunk an edit changed.
#[derive(Debug, Clone)]
pub struct ChunkChange {
    pub pos: ChunkPos,
    pub from_version: u64,
    pub to_version: u64,
    /// The chunk before the edit (the base of its delta), as the world
    /// held it.
    pub before: Arc<Chunk>,
    /// Local indices of the voxels that changed, increasing: what
    /// [`crate::delta::ChunkDelta::encode_changed`] needs.
    pub voxels: Vec<u16>,
}

/// The result of applying an edit.
#[derive(Debug, Clone)]
pub struct EditOutcome {
    /// Chunks whose voxels changed, in (z, y, x) order.
    pub changed: Vec<ChunkChange>,
    /// Every voxel the edit may touch.
    pub bbox: VoxelBox,
    /// Voxels whose value changed.
    pub voxels_changed: u64,
}

fn check_coord(p: VoxelPos) -> Result<(), EditError> {
    let ok = |v: i32| v.unsigned_abs() < COORD_LIMIT_VOXELS as u32;
    if ok(p.x) && ok(p.y) && ok(p.z) {
        Ok(())
    } else {
        Err(EditError::CoordinateOutOfRange {
            limit: COORD_LIMIT_VOXELS,
        })
    }
}

fn sphere_box(center: FixedVec3, radius: Fixed) -> Result<VoxelBox, EditError> {
    if !center.in_coord_range() {
        return Err(EditError::CoordinateOutOfRange {
            limit: COORD_LIMIT_VOXELS,
        });
    }
    if radius < MIN_RADIUS || radius > MAX_RADIUS {
        return Err(EditError::RadiusOutOfRange {
            radius,
            min: MIN_RADIUS,
            max: MAX_RADIUS,
        });
    }
    // Open on every side: a voxel a whole radius from the centre along one
    // axis lies at the radius or beyond, where no sphere brush changes it
    // (so a radius-1 edit at the world's top row stays inside it).
    let lo = |c: Fixed| Fixed(c.0 - radius.0).floor_voxel() + 1;
    let hi = |c: Fixed| Fixed(c.0 + radius.0).ceil_voxel() - 1;
    let b = VoxelBox {
        min: VoxelPos::new(lo(center.x), lo(center.y), lo(center.z)),
        max: VoxelPos::new(hi(center.x), hi(center.y), hi(center.z)),
    };
    // A radius under half a voxel between voxel centres holds none.
    if b.min.x > b.max.x || b.min.y > b.max.y || b.min.z > b.max.z {
        return Err(EditError::NoVoxel);
    }
    check_coord(b.min)?;
    check_coord(b.max)?;
    // Nor does one whose box's voxel nearest the centre lies at the radius
    // or beyond, where every sphere brush's weight is 0: the edit would
    // change nothing (and be charged, numbered and logged for it).
    let near = |c: Fixed, lo: i32, hi: i32| Fixed(c.0 + ONE / 2).floor_voxel().clamp(lo, hi);
    let nearest = VoxelPos::new(
        near(center.x, b.min.x, b.max.x),
        near(center.y, b.min.y, b.max.y),
        near(center.z, b.min.z, b.max.z),
    );
    if beyond(center, nearest, radius) {
        return Err(EditError::NoVoxel);
    }
    Ok(b)
}

fn check_placeable(m: MaterialId, materials: &MaterialTable) -> Result<(), EditError> {
    if materials.get(m).is_none() {
        return Err(EditError::UnknownMaterial(m));
    }
    if materials.is_indestructible(m) {
        return Err(EditError::IndestructibleMaterial(m));
    }
    Ok(())
}

impl Edit {
    /// Checks the edit against the core limits and returns the box of voxels
    /// it may change. A refused edit changes nothing.
    pub fn validate(&self, ctx: &EditContext<'_>) -> Result<VoxelBox, EditError> {
        match *self {
            Edit::Mine {
                center,
                radius,
                strength,
            }
            | Edit::Smooth {
                center,
                radius,
                strength,
            } => {
                if strength == 0 {
                    return Err(EditError::ZeroStrength);
                }
                sphere_box(center, radius)
            }
            Edit::Explode {
                center,
                radius,
                power,
            } => {
                if power > MAX_POWER {
                    return Err(EditError::PowerOutOfRange {
                        power,
                        max: MAX_POWER,
                    });
                }
                if power == 0 {
                    return Err(EditError::ZeroStrength);
                }
                sphere_box(center, radius)
            }
            Edit::Build {
                center,
                radius,
                material,
                strength,
            } => {
                if strength == 0 {
                    return Err(EditError::ZeroStrength);
                }
                // Solid air would be an invisible wall (admins' `FillBox`
                // may still make it).
                if material == crate::material::ids::AIR {
                    return Err(EditError::AirBuild);
                }
                check_placeable(material, ctx.materials)?;
                sphere_box(center, radius)
            }
            Edit::FillBox { min, max, .. } | Edit::ClearBox { min, max } => {
                if let Edit::FillBox { material, .. } = *self {
                    check_placeable(material, ctx.materials)?;
                }
                check_coord(min)?;
                check_coord(max)?;
                if min.x > max.x || min.y > max.y || min.z > max.z {
                    return Err(EditError::InvertedBox);
                }
                let edge = [(min.x, max.x), (min.y, max.y), (min.z, max.z)]
                    .iter()
                    .map(|(a, b)| *b as i64 - *a as i64 + 1)
                    .max()
                    .unwrap_or(0);
                if edge > MAX_BOX_EDGE as i64 {
                    return Err(EditError::BoxTooLarge {
                        edge,
                        max: MAX_BOX_EDGE,
                    });
                }
                Ok(VoxelBox { min, max })
            }
            Edit::PlaceStructure {
                structure,
                origin,
                rotation,
            } => {
                if rotation > 3 {
                    return Err(EditError::BadRotation(rotation));
                }
                let s = ctx
                    .structures
                    .get(structure)
                    .ok_or(EditError::UnknownStructure(structure))?;
                for m in s.materials() {
                    check_placeable(m, ctx.materials)?;
                }
                let [sx, sy, sz] = s.rotated_size(rotation);
                check_coord(origin)?;
                let max = VoxelPos::new(
                    origin.x + sx as i32 - 1,
                    origin.y + sy as i32 - 1,
                    origin.z + sz as i32 - 1,
                );
                check_coord(max)?;
                Ok(VoxelBox { min: origin, max })
            }
        }
    }

    fn structure<'a>(&self, ctx: &EditContext<'a>) -> Option<&'a Structure> {
        match self {
            Edit::PlaceStructure { structure, .. } => ctx.structures.get(*structure).map(|s| &**s),
            _ => None,
        }
    }

    /// Validates and applies the edit to a chunked world. Changed chunks get
    /// their version raised by one; unchanged chunks keep theirs.
    pub fn apply(
        &self,
        world: &mut World,
        ctx: &EditContext<'_>,
    ) -> Result<EditOutcome, EditError> {
        let bbox = self.validate(ctx)?;
        let m = self.read_margin();
        let read_box = VoxelBox {
            min: VoxelPos::new(bbox.min.x - m, bbox.min.y - m, bbox.min.z - m),
            max: VoxelPos::new(bbox.max.x + m, bbox.max.y + m, bbox.max.z + m),
        };
        world.load(read_box.chunks());
        // An edit that reads around the voxels it changes (Smooth: 27 reads
        // each) reads a flat copy of its read box, not the chunk map.
        let margin_copy = (m > 0).then(|| Region::from_loaded(world, read_box));
        let structure = self.structure(ctx);
        let mut pending = Vec::new();
        let mut voxels_changed = 0u64;
        for cpos in bbox.chunks() {
            // `validate` returns no empty box; one would touch nothing.
            let Some(sub) = bbox.within_chunk(cpos) else {
                continue;
            };
            let before = &world.peek(cpos).expect("loaded above").chunk;
            let mut after = Chunk::clone(before);
            // Visited z, then y, then x: increasing local index.
            // At most the box's part of the chunk: reserved once.
            let mut voxels = Vec::with_capacity(sub.volume() as usize);
            for_each_voxel(sub, |p| {
                let (x, y, z) = p.local();
                let old = before.get(x, y, z);
                let src: &dyn VoxelRead = match &margin_copy {
                    Some(r) => r,
                    None => &*world,
                };
                let new = apply_voxel(self, structure, ctx.materials, p, old, src, bbox.min);
                if new != old {
                    after.set(x, y, z, new);
                    voxels.push(local_index(x, y, z) as u16);
                }
            });
            if !voxels.is_empty() {
                voxels_changed += voxels.len() as u64;
                pending.push((cpos, after, voxels));
            }
        }
        // A chunk at the last version (only stored bytes can put one
        // there) takes no edit: its `+ 1` would leave what stores hold.
        if let Some((pos, ..)) = pending.iter().find(|(pos, ..)| {
            world.peek(*pos).expect("loaded").version >= crate::world::MAX_CHUNK_VERSION
        }) {
            return Err(EditError::VersionExhausted { pos: *pos });
        }
        // The world's own copy becomes each change's `before`: no clone.
        let changed = pending
            .into_iter()
            .map(|(pos, after, voxels)| {
                let from_version = world.peek(pos).expect("loaded").version;
                let (to_version, before) = world.commit_replace(pos, after);
                ChunkChange {
                    pos,
                    from_version,
                    to_version,
                    before,
                    voxels,
                }
            })
            .collect();
        Ok(EditOutcome {
            changed,
            bbox,
            voxels_changed,
        })
    }

    /// Validates and applies the edit to one flat region (the reference
    /// path; also used for client-side prediction). Voxels outside the
    /// region are left alone. Returns the box and the changed voxel count.
    pub fn apply_region(
        &self,
        region: &mut Region,
        ctx: &EditContext<'_>,
    ) -> Result<(VoxelBox, u64), EditError> {
        let bbox = self.validate(ctx)?;
        let structure = self.structure(ctx);
        let src = region.clone();
        let mut n = 0;
        if let Some(sub) = bbox.intersect(&region.bounds()) {
            for_each_voxel(sub, |p| {
                let old = src.voxel(p);
                let new = apply_voxel(self, structure, ctx.materials, p, old, &src, bbox.min);
                if new != old {
                    region.set(p, new);
                    n += 1;
                }
            });
        }
        Ok((bbox, n))
    }
}

fn for_each_voxel(b: VoxelBox, mut f: impl FnMut(VoxelPos)) {
    for z in b.min.z..=b.max.z {
        for y in b.min.y..=b.max.y {
            for x in b.min.x..=b.max.x {
                f(VoxelPos::new(x, y, z));
            }
        }
    }
}
