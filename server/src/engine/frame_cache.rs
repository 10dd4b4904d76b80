//! Encoded snapshot and patch frames kept for reuse, by (chunk, version,
//! whole). Two tables: the frames any session may be sent (patches, and in
//! a world clients cannot regenerate every frame), and the whole frames
//! only clients that ask for them get (thin clients, `FullSnapshotRequest`),
//! so one client's requests cannot push out what everyone shares. A full
//! table evicts one frame at a time by second chance (a clock): a frame
//! used since the hand last passed it stays for another round.

use std::collections::{HashMap, VecDeque};

use bytes::Bytes;
use strata_protocol::WorldUpdate;
use strata_terrain::ChunkPos;

use super::fanout::encode_update;
use crate::metrics as m;

/// Default encoded frames kept for reuse (`[engine]
/// snapshot_cache_entries`): many sessions near one spot ask for the same
/// chunks.
pub const DEFAULT_SNAPSHOT_CACHE_ENTRIES: usize = 8192;

/// Default whole frames kept for the clients that ask for them, in a world
/// clients regenerate (`[engine] full_frame_cache_entries`).
pub const DEFAULT_FULL_FRAME_CACHE_ENTRIES: usize = 2048;

/// A frame's cache key: the chunk, its version, and whether it goes whole
/// (else as a patch against the generated chunk).
pub type FrameKey = (ChunkPos, u64, bool);

/// An encoded snapshot or patch and the update it encodes.
#[derive(Debug)]
struct Cached {
    update: WorldUpdate,
    frame: Bytes,
    /// Sent since the clock's hand last passed.
    used: bool,
}

/// Snapshot frames by (chunk, version, full data rather than a patch).
///
/// A frame carries its chunk's mesh hash, which also depends on the
/// neighbours, so a hit is reused only if that hash is still current; else
/// only the (small) frame is re-encoded, not the chunk or the patch.
#[derive(Debug)]
pub struct SnapshotCache {
    shared: FrameTable,
    requested: FrameTable,
    /// Clients regenerate version 0 themselves: whole frames go only to
    /// those who ask, and are kept apart.
    regenerable: bool,
}

/// The mesh hash a snapshot or patch carries.
fn mesh_hash_of(u: &mut WorldUpdate) -> Option<&mut u64> {
    match u {
        WorldUpdate::Snapshot { mesh_hash, .. } | WorldUpdate::Patched { mesh_hash, .. } => {
            Some(mesh_hash)
        }
        _ => None,
    }
}

impl SnapshotCache {
    /// At most `capacity` shared frames and `requested` whole ones (at
    /// least one each); `regenerable`: see [`super::StreamPolicy`].
    pub fn new(capacity: usize, requested: usize, regenerable: bool) -> Self {
        Self {
            shared: FrameTable::new(capacity, "evicted"),
            requested: FrameTable::new(requested, "evicted_requested"),
            regenerable,
        }
    }

    fn table(&self, key: FrameKey) -> &FrameTable {
        match self.regenerable && key.2 {
            true => &self.requested,
            false => &self.shared,
        }
    }

    fn table_mut(&mut self, key: FrameKey) -> &mut FrameTable {
        match self.regenerable && key.2 {
            true => &mut self.requested,
            false => &mut self.shared,
        }
    }

    /// The cached frame, re-encoded first if `mesh_hash` changed.
    pub fn get(&mut self, key: FrameKey, mesh_hash: u64) -> Option<Bytes> {
        let Some(c) = self.table_mut(key).frames.get_mut(&key) else {
            // Not counted: a miss is counted once, when its frame is
            // planned or built (a frame may wait for several ticks).
            return None;
        };
        metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => "hit").increment(1);
        c.used = true;
        let held = mesh_hash_of(&mut c.update)?;
        if *held != mesh_hash {
            *held = mesh_hash;
            c.frame = encode_update(&c.update);
        }
        Some(c.frame.clone())
    }

    /// Whether a frame for `key` is cached (its mesh hash may be stale).
    pub fn has(&self, key: FrameKey) -> bool {
        self.table(key).frames.contains_key(&key)
    }

    /// Keeps a frame, evicting one of its table's if it is full.
    pub fn put(&mut self, key: FrameKey, update: WorldUpdate, frame: Bytes) {
        self.table_mut(key).put(key, update, frame);
    }

    /// Evicts ahead for the frames of `keys` not cached yet, so a tick's
    /// frames are not evicted by their own puts (unless more than a table
    /// holds).
    pub fn make_room<'a>(&mut self, keys: impl IntoIterator<Item = &'a FrameKey>) {
        let (mut shared, mut requested) = (0, 0);
        for &key in keys {
            if self.has(key) {
                continue;
            }
            match self.regenerable && key.2 {
                true => requested += 1,
                false => shared += 1,
            }
        }
        self.shared.make_room(shared);
        self.requested.make_room(requested);
    }
}

/// One table of frames, at most `capacity`.
#[derive(Debug)]
struct FrameTable {
    capacity: usize,
    frames: HashMap<FrameKey, Cached>,
    /// Every cached key once, in the clock's order: the hand is the front.
    hand: VecDeque<FrameKey>,
    /// The `outcome` label of its evictions.
    evicted: &'static str,
}

impl FrameTable {
    fn new(capacity: usize, evicted: &'static str) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: HashMap::new(),
            hand: VecDeque::new(),
            evicted,
        }
    }

    fn put(&mut self, key: FrameKey, update: WorldUpdate, frame: Bytes) {
        if let Some(c) = self.frames.get_mut(&key) {
            (c.update, c.frame) = (update, frame);
            return;
        }
        self.make_room(1);
        let used = false;
        self.frames.insert(
            key,
            Cached {
                update,
                frame,
                used,
            },
        );
        self.hand.push_back(key);
    }

    /// Evicts until `n` more frames fit (at most the capacity).
    fn make_room(&mut self, n: usize) {
        let n = n.min(self.capacity);
        while self.frames.len() + n > self.capacity && self.evict_one() {}
    }

    /// Evicts the first frame under the hand not used since it last
    /// passed, clearing the marks it passes; false when empty. At most two
    /// rounds of the clock.
    fn evict_one(&mut self) -> bool {
        while let Some(key) = self.hand.pop_front() {
            let Some(c) = self.frames.get_mut(&key) else {
                continue;
            };
            if std::mem::take(&mut c.used) {
                self.hand.push_back(key);
                continue;
            }
            self.frames.remove(&key);
            metrics::counter!(m::SNAPSHOT_CACHE, "outcome" => self.evicted).increment(1);
            return true;
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::{Chunk, Voxel};

    fn patched(pos: ChunkPos, mesh_hash: u64) -> WorldUpdate {
        let at = |d: u8| Chunk::Uniform(Voxel::new(d, 1));
        let delta = ChunkDelta::encode(pos, 0, 1, &at(0), &at(9)).unwrap();
        WorldUpdate::Patched { delta, mesh_hash }
    }

    fn key(x: i32, full: bool) -> FrameKey {
        (ChunkPos::new(x, 0, 0), u64::from(!full), full)
    }

    fn put(cache: &mut SnapshotCache, k: FrameKey) {
        let u = patched(k.0, 7);
        let frame = encode_update(&u);
        cache.put(k, u, frame);
    }

    #[test]
    fn holds_at_most_its_capacity_and_refreshes_the_mesh_hash() {
        let mut cache = SnapshotCache::new(2, 2, true);
        for x in 0..2 {
            put(&mut cache, key(x, false));
        }
        let k = key(0, false);
        assert_eq!(cache.get(k, 7), Some(encode_update(&patched(k.0, 7))));
        // A changed neighbour changed the mesh hash: only the frame is redone.
        assert_eq!(cache.get(k, 8), Some(encode_update(&patched(k.0, 8))));
        assert_eq!(cache.get(key(5, false), 7), None);
        put(&mut cache, key(2, false));
        assert_eq!(cache.shared.frames.len(), 2);
        assert!(cache.get(key(2, false), 7).is_some(), "the newest is kept");
    }

    #[test]
    fn a_full_table_evicts_one_frame_and_spares_the_used_ones() {
        let mut cache = SnapshotCache::new(3, 1, true);
        for x in 0..3 {
            put(&mut cache, key(x, false));
        }
        // Frame 0 was sent again: the hand passes it by, and 1 goes.
        assert!(cache.get(key(0, false), 7).is_some());
        put(&mut cache, key(3, false));
        let held = |c: &SnapshotCache| (0..4).map(|x| c.has(key(x, false))).collect::<Vec<_>>();
        assert_eq!(held(&cache), [true, false, true, true], "not all cleared");
        // Room made ahead for two new frames: the unused ones go first.
        cache.make_room(&[key(8, false), key(9, false), key(3, false)]);
        assert_eq!(cache.shared.frames.len(), 1, "room for two, 3 cached");
        assert_eq!(cache.shared.hand.len(), cache.shared.frames.len());
    }

    #[test]
    fn requested_whole_frames_never_push_out_shared_ones() {
        let mut cache = SnapshotCache::new(4, 2, true);
        for x in 0..4 {
            put(&mut cache, key(x, false));
        }
        // One client asks for a thousand whole chunks (version 0).
        for x in 100..1100 {
            put(&mut cache, key(x, true));
        }
        assert!((0..4).all(|x| cache.has(key(x, false))), "patches kept");
        assert_eq!(cache.requested.frames.len(), 2, "within its own bound");
        assert!(cache.has(key(1099, true)));
        // Where clients cannot regenerate, every frame is whole and shared.
        let mut heightmap = SnapshotCache::new(4, 2, false);
        for x in 0..4 {
            put(&mut heightmap, key(x, true));
        }
        assert_eq!(heightmap.shared.frames.len(), 4);
        assert!(heightmap.requested.frames.is_empty());
    }
}
