//! Regions: fixed square blocks of chunk columns (`[sequencer]
//! region_chunks` on a side, every height). A region is the unit of
//! ordering, and the unit a cluster leases to a server process.
//!
//! A tick groups its edits into lanes: the regions one edit's footprint
//! (its box, read margin and mesh apron) spans belong to one lane, and so,
//! transitively, do the edits that share any of them. Lanes hold disjoint
//! chunks, so they apply on separate threads and the result does not depend
//! on how many run at once.

use std::collections::HashMap;

use strata_terrain::ChunkPos;

/// Default region side, in chunks (256 voxels).
pub const DEFAULT_REGION_CHUNKS: u32 = 8;
/// Largest allowed region side, in chunks.
pub const MAX_REGION_CHUNKS: u32 = 1 << 16;

/// A region's coordinates: chunk x and z divided (floor) by the side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RegionId {
    pub x: i32,
    pub z: i32,
}

impl RegionId {
    /// The region holding `pos`, for regions `side` chunks wide (at least 1).
    pub fn of(pos: ChunkPos, side: u32) -> Self {
        let side = side.clamp(1, MAX_REGION_CHUNKS) as i32;
        RegionId {
            x: pos.x.div_euclid(side),
            z: pos.z.div_euclid(side),
        }
    }
}

/// The regions of a box of chunks, `min..=max`, as an inclusive range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegionSpan {
    pub min: RegionId,
    pub max: RegionId,
}

impl RegionSpan {
    pub fn of_chunks(min: ChunkPos, max: ChunkPos, side: u32) -> Self {
        RegionSpan {
            min: RegionId::of(min, side),
            max: RegionId::of(max, side),
        }
    }

    pub fn regions(&self) -> impl Iterator<Item = RegionId> + '_ {
        (self.min.z..=self.max.z)
            .flat_map(move |z| (self.min.x..=self.max.x).map(move |x| RegionId { x, z }))
    }
}

/// Groups items (by index) into lanes: items whose spans share a region,
/// directly or through others, share a lane. Items keep their order within
/// a lane; lanes are ordered by their first item. `None` spans (items that
/// read nothing) each get a lane of their own.
pub fn lanes(spans: &[Option<RegionSpan>]) -> Vec<Vec<usize>> {
    let mut node: HashMap<RegionId, usize> = HashMap::new();
    let mut parent: Vec<usize> = Vec::new();
    let mut first_node: Vec<Option<usize>> = Vec::with_capacity(spans.len());
    for span in spans {
        let Some(span) = span else {
            first_node.push(None);
            continue;
        };
        let mut first = None;
        for r in span.regions() {
            let n = *node.entry(r).or_insert_with(|| {
                parent.push(parent.len());
                parent.len() - 1
            });
            match first {
                None => first = Some(n),
                Some(f) => union(&mut parent, f, n),
            }
        }
        first_node.push(first);
    }
    let mut lane_of_root: HashMap<usize, usize> = HashMap::new();
    let mut out: Vec<Vec<usize>> = Vec::new();
    for (i, n) in first_node.into_iter().enumerate() {
        let lane = match n {
            Some(n) => {
                let root = find(&mut parent, n);
                *lane_of_root.entry(root).or_insert_with(|| {
                    out.push(Vec::new());
                    out.len() - 1
                })
            }
            None => {
                out.push(Vec::new());
                out.len() - 1
            }
        };
        out[lane].push(i);
    }
    out
}

fn find(parent: &mut [usize], mut n: usize) -> usize {
    while parent[n] != n {
        parent[n] = parent[parent[n]];
        n = parent[n];
    }
    n
}

fn union(parent: &mut [usize], a: usize, b: usize) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        parent[ra.max(rb)] = ra.min(rb);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn span(x0: i32, z0: i32, x1: i32, z1: i32) -> Option<RegionSpan> {
        Some(RegionSpan {
            min: RegionId { x: x0, z: z0 },
            max: RegionId { x: x1, z: z1 },
        })
    }

    #[test]
    fn region_of_negative_chunks_floors() {
        let r = |x, z| RegionId::of(ChunkPos::new(x, 5, z), 8);
        assert_eq!(r(0, 0), RegionId { x: 0, z: 0 });
        assert_eq!(r(7, 7), RegionId { x: 0, z: 0 });
        assert_eq!(r(8, -1), RegionId { x: 1, z: -1 });
        assert_eq!(r(-8, -9), RegionId { x: -1, z: -2 });
        // Height never matters; a side of 0 is taken as 1.
        assert_eq!(
            RegionId::of(ChunkPos::new(3, -40, 2), 0),
            RegionId { x: 3, z: 2 }
        );
    }

    #[test]
    fn lanes_join_through_shared_regions_and_keep_order() {
        let spans = [
            span(0, 0, 0, 0), // 0: A
            span(5, 5, 5, 5), // 1: B
            span(0, 0, 1, 0), // 2: A and C
            None,             // 3: alone
            span(1, 0, 1, 0), // 4: C, so A's lane
            span(5, 5, 5, 5), // 5: B
            span(9, 9, 9, 9), // 6: D
        ];
        assert_eq!(
            lanes(&spans),
            vec![vec![0, 2, 4], vec![1, 5], vec![3], vec![6]]
        );
    }

    #[test]
    fn a_late_bridge_merges_two_lanes() {
        let spans = [span(0, 0, 0, 0), span(2, 0, 2, 0), span(0, 0, 2, 0)];
        assert_eq!(lanes(&spans), vec![vec![0, 1, 2]]);
    }
}
