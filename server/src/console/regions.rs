//! `GET /api/regions?x0&z0&x1&z1`: who writes each region over a box of
//! chunk columns, for the map's overlay. On a cluster the store answers
//! from its lease book, its cache or one query per renewal period
//! (`ChunkStore::region_holders`); alone on its store the node writes
//! every region.

use serde_json::{json, Value};
use thiserror::Error;

use crate::sequencer::regions::{RegionId, RegionSpan};
use crate::store::{ChunkStore, RegionHolder, StoreError};
use strata_terrain::ChunkPos;

/// Default most regions one request may ask about (`[console]
/// regions_per_request`; a map view shows a few dozen).
pub const DEFAULT_REGIONS_PER_REQUEST: usize = 1024;

#[derive(Debug, Error)]
pub enum RegionsError {
    #[error("the box holds {regions} regions; at most {max}")]
    TooMany { regions: u64, max: usize },
    #[error("the box must have x0 <= x1 and z0 <= z1")]
    Inverted,
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// The regions over chunk columns `(x0, z0)..=(x1, z1)` and their holders.
pub fn holders(
    store: &dyn ChunkStore,
    side: u32,
    ((x0, z0), (x1, z1)): ((i32, i32), (i32, i32)),
    max: usize,
) -> Result<Value, RegionsError> {
    if x0 > x1 || z0 > z1 {
        return Err(RegionsError::Inverted);
    }
    let span = RegionSpan::of_chunks(ChunkPos::new(x0, 0, z0), ChunkPos::new(x1, 0, z1), side);
    let count = |a: i32, b: i32| (i64::from(b) - i64::from(a) + 1) as u64;
    let regions = count(span.min.x, span.max.x) * count(span.min.z, span.max.z);
    if regions > max as u64 {
        return Err(RegionsError::TooMany { regions, max });
    }
    let wanted = span.regions().collect();
    let list: Vec<Value> = store
        .region_holders_read(&wanted)?
        .into_iter()
        .map(|(RegionId { x, z }, h)| match h {
            RegionHolder::Here => json!({ "x": x, "z": z, "holder": "here" }),
            RegionHolder::Free => json!({ "x": x, "z": z, "holder": "free" }),
            RegionHolder::Node { owner, addr } => {
                json!({ "x": x, "z": z, "holder": "node", "node": owner, "addr": addr })
            }
        })
        .collect();
    Ok(json!({ "region_chunks": side, "regions": list }))
}
