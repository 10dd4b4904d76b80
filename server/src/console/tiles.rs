//! Map tiles: `TILE_COLUMNS` x `TILE_COLUMNS` chunk columns drawn by the
//! offline map code (`admin::render_map`, the terrain's contours and
//! surface heights) at one pixel per voxel, as PNG. Each tile is cached
//! under the stamp of its columns (`versions.rs`), so an edit redraws only
//! the tiles it touched. The cache holds `[console] tile_cache` tiles and
//! drops the oldest first.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

use crate::admin::map::png::write_png;
use crate::admin::render_map::{slice_map, top_down_map, RenderMapError};
use crate::admin::world_source::WorldView;

use super::{TILE_COLUMNS, TILE_CONTOUR_INTERVAL};

/// What a tile shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum View {
    /// The surface from above, shaded by height, with height contours.
    Top,
    /// The horizontal slice at this y (caves).
    Slice(i32),
}

/// One tile: its view and its position in tiles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TileKey {
    pub view: View,
    pub tx: i32,
    pub tz: i32,
}

impl TileKey {
    /// The first chunk column (x, z) of the tile.
    pub fn first_column(&self) -> (i32, i32) {
        (self.tx * TILE_COLUMNS, self.tz * TILE_COLUMNS)
    }
}

/// Rendered tiles by key, each with the stamp it was drawn at.
#[derive(Debug)]
pub struct TileCache {
    max: usize,
    inner: Mutex<Inner>,
}

#[derive(Debug, Default)]
struct Inner {
    tiles: HashMap<TileKey, (u64, Arc<Vec<u8>>)>,
    /// Insertion order, for dropping the oldest.
    order: VecDeque<TileKey>,
}

impl TileCache {
    pub fn new(max: usize) -> Self {
        Self {
            max: max.max(1),
            inner: Mutex::default(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The tile if it was drawn at `stamp`.
    pub fn get(&self, key: &TileKey, stamp: u64) -> Option<Arc<Vec<u8>>> {
        let inner = self.lock();
        match inner.tiles.get(key) {
            Some((s, png)) if *s == stamp => Some(png.clone()),
            _ => None,
        }
    }

    pub fn put(&self, key: TileKey, stamp: u64, png: Arc<Vec<u8>>) {
        let mut inner = self.lock();
        if inner.tiles.insert(key, (stamp, png)).is_none() {
            inner.order.push_back(key);
        }
        while inner.tiles.len() > self.max {
            let Some(old) = inner.order.pop_front() else {
                break;
            };
            inner.tiles.remove(&old);
        }
    }

    /// Tiles held.
    pub(super) fn len(&self) -> usize {
        self.lock().tiles.len()
    }
}

/// Draws one tile as PNG bytes.
pub fn render(world: &dyn WorldView, key: TileKey) -> Result<Vec<u8>, RenderMapError> {
    let (x0, z0) = key.first_column();
    let cols = [x0, z0, x0 + TILE_COLUMNS - 1, z0 + TILE_COLUMNS - 1];
    let map = match key.view {
        View::Top => {
            // One shading range for every tile: the hills' own.
            let p = world.params();
            let (base, amp) = (p.base_height as f32, p.hill_amplitude as f32);
            let shade = Some((base - amp, base + amp));
            top_down_map(world, cols, TILE_CONTOUR_INTERVAL, 1, shade, false)?.0
        }
        View::Slice(y) => slice_map(world, cols, y, 1, false)?,
    };
    let mut png = Vec::new();
    write_png(&map, &mut png)?;
    Ok(png)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(tx: i32) -> TileKey {
        TileKey {
            view: View::Top,
            tx,
            tz: 0,
        }
    }

    #[test]
    fn cache_keeps_the_newest_and_checks_stamps() {
        let cache = TileCache::new(2);
        for tx in 0..3 {
            cache.put(key(tx), 7, Arc::new(vec![tx as u8]));
        }
        assert_eq!(cache.len(), 2);
        assert!(cache.get(&key(0), 7).is_none(), "the oldest was dropped");
        assert_eq!(cache.get(&key(2), 7).as_deref(), Some(&vec![2u8]));
        assert!(cache.get(&key(2), 8).is_none(), "a newer stamp misses");
        cache.put(key(2), 8, Arc::new(vec![9]));
        assert_eq!(cache.len(), 2);
        assert_eq!(cache.get(&key(2), 8).as_deref(), Some(&vec![9u8]));
    }
}
