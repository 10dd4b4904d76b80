//! The masked layout: per plane, the bounding box of the changed voxels, a
//! bitmask of which ones changed, and one value byte per changed voxel.
//!
//! Edits are compact 3D shapes, so a box plus a bitmask describes *where*
//! far more cheaply than offsets along the x-fastest stream. The values are
//! stored in whichever form is most regular: the new bytes (mining writes
//! air, building writes one solid value), the XOR, or the wrapping
//! difference (a falloff that lowers density by a function of distance).
//! See the module docs of [`crate::delta`] for the exact bytes.

use super::stream::{next_nonzero, plane_mut, Plane};
use super::DeltaError;
use crate::chunk::DenseChunk;
use crate::pos::{index_local, local_index, CHUNK_SIZE, CHUNK_VOLUME};

/// Section op: the plane is unchanged; nothing follows.
pub const OP_KEEP: u8 = 0;
/// Section op: a value is the voxel's new byte.
pub const OP_REPLACE: u8 = 1;
/// Section op: new byte = old byte XOR value.
pub const OP_XOR: u8 = 2;
/// Section op: new byte = old byte + value, wrapping mod 256.
pub const OP_ADD: u8 = 3;

/// Largest masked body: two sections of op, box, a full mask and all values.
pub const MAX_MASKED_LEN: usize = 2 * (1 + 6 + CHUNK_VOLUME / 8 + CHUNK_VOLUME);

/// An inclusive box of local coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct LocalBox {
    min: [usize; 3],
    max: [usize; 3],
}

impl LocalBox {
    /// The box of the one voxel at local index `i`.
    fn of(i: usize) -> Self {
        let (x, y, z) = index_local(i);
        LocalBox {
            min: [x, y, z],
            max: [x, y, z],
        }
    }

    fn union(self, o: Self) -> Self {
        LocalBox {
            min: std::array::from_fn(|a| self.min[a].min(o.min[a])),
            max: std::array::from_fn(|a| self.max[a].max(o.max[a])),
        }
    }

    fn volume(&self) -> usize {
        (0..3).map(|a| self.max[a] - self.min[a] + 1).product()
    }

    /// Stream indices of the box's voxels, x fastest, then y, then z.
    fn indices(self) -> impl Iterator<Item = usize> {
        let [x0, y0, z0] = self.min;
        let [x1, y1, z1] = self.max;
        (z0..=z1).flat_map(move |z| {
            (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| local_index(x, y, z)))
        })
    }
}

/// Appends the masked body for both planes.
pub(super) fn encode_masked(base: [Plane<'_>; 2], target: [Plane<'_>; 2], x: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    for p in 0..2 {
        encode_section(
            &mut out,
            base[p],
            target[p],
            &x[p * CHUNK_VOLUME..(p + 1) * CHUNK_VOLUME],
        );
    }
    out
}

fn encode_section(out: &mut Vec<u8>, base: Plane<'_>, target: Plane<'_>, x: &[u8]) {
    let Some(bbox) = changed_box(x) else {
        out.push(OP_KEEP);
        return;
    };
    let mut mask = vec![0u8; bbox.volume().div_ceil(8)];
    let mut changed = Vec::new();
    for (k, i) in bbox.indices().enumerate() {
        if x[i] != 0 {
            mask[k / 8] |= 1 << (k % 8);
            changed.push((base.get(i), target.get(i)));
        }
    }
    write_section(out, bbox, &mask, &changed);
}

/// [`encode_masked`] from each plane's changed bytes, `(index, base,
/// target)` in increasing index order with `base != target`: the same
/// bytes, without the XOR stream.
pub(super) fn encode_masked_sparse(planes: [&[(u16, u8, u8)]; 2]) -> Vec<u8> {
    let mut out = Vec::new();
    for changes in planes {
        let Some(bbox) = changes
            .iter()
            .map(|&(i, _, _)| LocalBox::of(usize::from(i)))
            .reduce(LocalBox::union)
        else {
            out.push(OP_KEEP);
            continue;
        };
        let [x0, y0, z0] = bbox.min;
        let (w, h) = (bbox.max[0] - x0 + 1, bbox.max[1] - y0 + 1);
        let mut mask = vec![0u8; bbox.volume().div_ceil(8)];
        for &(i, _, _) in changes {
            // Increasing index order is the box's x-fastest order.
            let (x, y, z) = index_local(usize::from(i));
            let k = (x - x0) + w * ((y - y0) + h * (z - z0));
            mask[k / 8] |= 1 << (k % 8);
        }
        let changed: Vec<(u8, u8)> = changes.iter().map(|&(_, b, t)| (b, t)).collect();
        write_section(&mut out, bbox, &mask, &changed);
    }
    out
}

/// Appends a section that changes something: op, box, mask, values.
fn write_section(out: &mut Vec<u8>, bbox: LocalBox, mask: &[u8], changed: &[(u8, u8)]) {
    let op = choose_op(changed);
    out.reserve(7 + mask.len() + changed.len());
    out.push(op);
    out.extend(bbox.min.iter().chain(&bbox.max).map(|&c| c as u8));
    out.extend_from_slice(mask);
    out.extend(changed.iter().map(|&(b, t)| value_for(op, b, t)));
}

/// Tight bounding box of the non-zero bytes of one plane's XOR.
fn changed_box(x: &[u8]) -> Option<LocalBox> {
    let first = next_nonzero(x, 0)?;
    let mut b = LocalBox::of(first);
    let mut i = first + 1;
    while let Some(j) = next_nonzero(x, i) {
        b = b.union(LocalBox::of(j));
        i = j + 1;
    }
    Some(b)
}

fn value_for(op: u8, base: u8, target: u8) -> u8 {
    match op {
        OP_XOR => base ^ target,
        OP_ADD => target.wrapping_sub(base),
        _ => target,
    }
}

/// The op whose values change least often from one to the next: long runs
/// of equal values are what the compressors exploit. Ties keep the lower op.
fn choose_op(changed: &[(u8, u8)]) -> u8 {
    let breaks = |op: u8| {
        changed
            .windows(2)
            .filter(|w| value_for(op, w[0].0, w[0].1) != value_for(op, w[1].0, w[1].1))
            .count()
    };
    let mut best = (breaks(OP_REPLACE), OP_REPLACE);
    for op in [OP_XOR, OP_ADD] {
        let b = breaks(op);
        if b < best.0 {
            best = (b, op);
        }
    }
    best.1
}

/// Applies a masked body to `out` (a copy of the base). On error `out` is
/// partly written; callers discard it.
pub(super) fn apply_masked(body: &[u8], out: &mut DenseChunk) -> Result<(), DeltaError> {
    let mut at = 0;
    for p in 0..2 {
        apply_section(body, &mut at, plane_mut(out, p))?;
    }
    if at != body.len() {
        return Err(DeltaError::TrailingBytes(body.len() - at));
    }
    Ok(())
}

fn take<'a>(
    body: &'a [u8],
    at: &mut usize,
    n: usize,
    what: &'static str,
) -> Result<&'a [u8], DeltaError> {
    let s = body.get(*at..*at + n).ok_or(DeltaError::Truncated(what))?;
    *at += n;
    Ok(s)
}

fn apply_section(
    body: &[u8],
    at: &mut usize,
    plane: &mut [u8; CHUNK_VOLUME],
) -> Result<(), DeltaError> {
    let op = take(body, at, 1, "section op")?[0];
    match op {
        OP_KEEP => return Ok(()),
        OP_REPLACE | OP_XOR | OP_ADD => {}
        other => return Err(DeltaError::UnknownOp(other)),
    }
    let c = take(body, at, 6, "section box")?;
    let limit = CHUNK_SIZE as usize;
    if c.iter().any(|&v| v as usize >= limit) || (0..3).any(|a| c[a] > c[a + 3]) {
        return Err(DeltaError::BadBox([c[0], c[1], c[2], c[3], c[4], c[5]]));
    }
    let bbox = LocalBox {
        min: [c[0] as usize, c[1] as usize, c[2] as usize],
        max: [c[3] as usize, c[4] as usize, c[5] as usize],
    };
    let volume = bbox.volume();
    let mask = take(body, at, volume.div_ceil(8), "section mask")?;
    if volume % 8 != 0 && mask[volume / 8] >> (volume % 8) != 0 {
        return Err(DeltaError::MaskPadding);
    }
    let count = mask.iter().map(|b| b.count_ones() as usize).sum();
    let values = take(body, at, count, "section values")?;
    let mut values = values.iter();
    for (k, i) in bbox.indices().enumerate() {
        if mask[k / 8] & (1 << (k % 8)) != 0 {
            // The mask has exactly `count` set bits, so a value is there.
            let Some(&v) = values.next() else { break };
            plane[i] = match op {
                OP_REPLACE => v,
                OP_XOR => plane[i] ^ v,
                _ => plane[i].wrapping_add(v),
            };
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::chunk::Voxel;

    fn section_for(base: &[u8], target: &[u8]) -> Vec<u8> {
        let x: Vec<u8> = base.iter().zip(target).map(|(a, b)| a ^ b).collect();
        let mut out = Vec::new();
        encode_section(&mut out, Plane::Bytes(base), Plane::Bytes(target), &x);
        out
    }

    #[test]
    fn golden_section_bytes() {
        let base = vec![200u8; CHUNK_VOLUME];
        let mut target = base.clone();
        target[local_index(1, 2, 3)] = 0;
        target[local_index(2, 2, 3)] = 0;
        target[local_index(1, 3, 3)] = 0;
        // Box (1,2,3)-(2,3,3) holds 4 voxels; bits 0, 1, 2 set; replace by 0.
        assert_eq!(
            section_for(&base, &target),
            vec![OP_REPLACE, 1, 2, 3, 2, 3, 3, 0b0111, 0, 0, 0]
        );
        let unchanged = section_for(&base, &base);
        assert_eq!(unchanged, vec![OP_KEEP]);
    }

    #[test]
    fn op_follows_the_regular_form() {
        // Lowering varied densities by a constant: ADD values are constant.
        let base: Vec<u8> = (0..CHUNK_VOLUME).map(|i| 100 + (i % 50) as u8).collect();
        let mut target = base.clone();
        for v in &mut target[..64] {
            *v -= 30;
        }
        let s = section_for(&base, &target);
        assert_eq!(s[0], OP_ADD);
        assert!(s[s.len() - 64..].iter().all(|&v| v == 30u8.wrapping_neg()));
        let mut d = DenseChunk::from_planes(&base, &base).unwrap();
        let mut body = s;
        body.push(OP_KEEP);
        apply_masked(&body, &mut d).unwrap();
        assert_eq!(&d.density[..], &target[..]);
    }

    #[test]
    fn malformed_sections_give_typed_errors() {
        let mut d = DenseChunk::filled(Voxel::AIR);
        let e = |body: &[u8], d: &mut DenseChunk| apply_masked(body, d).unwrap_err();
        assert_eq!(e(&[7], &mut d), DeltaError::UnknownOp(7));
        assert!(matches!(e(&[OP_KEEP], &mut d), DeltaError::Truncated(_)));
        assert_eq!(
            e(&[OP_KEEP, OP_KEEP, 0], &mut d),
            DeltaError::TrailingBytes(1)
        );
        assert_eq!(
            e(&[1, 0, 0, 0, 32, 0, 0], &mut d),
            DeltaError::BadBox([0, 0, 0, 32, 0, 0])
        );
        assert_eq!(
            e(&[1, 5, 0, 0, 4, 0, 0], &mut d),
            DeltaError::BadBox([5, 0, 0, 4, 0, 0])
        );
        // A 1-voxel box whose mask byte sets a bit past the box.
        assert_eq!(
            e(&[1, 0, 0, 0, 0, 0, 0, 0b10], &mut d),
            DeltaError::MaskPadding
        );
        assert!(matches!(
            e(&[1, 0, 0, 0, 0, 0, 0, 1], &mut d),
            DeltaError::Truncated(_)
        ));
        assert!(matches!(
            e(&[1, 0, 0, 0, 1, 0, 0], &mut d),
            DeltaError::Truncated(_)
        ));
    }

    #[test]
    fn full_box_fits_the_bound() {
        let base = vec![0u8; CHUNK_VOLUME];
        let target = vec![1u8; CHUNK_VOLUME];
        assert_eq!(section_for(&base, &target).len(), MAX_MASKED_LEN / 2);
    }
}
