//! Prediction reconciled on replica-level data: the edits are applied to a
//! server-side `World` exactly as the sequencer does, and their deltas and
//! verdicts are fed to a replica and its prediction in chosen orders
//! (including orders a real network only produces by chance).

use std::sync::Arc;

use strata_client_sim::prediction::Touched;
use strata_client_sim::{Prediction, PredictionStats, Replica, Verdict};
use strata_protocol::{ChunkVersion, DeltaUpdate, RejectReason, WorldUpdate};
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::hash::chunk_hash;
use strata_terrain::material::ids;
use strata_terrain::{
    ChunkGenerator, ChunkPos, Edit, EditContext, Fixed, FixedVec3, MaterialTable, VoxelPos, World,
};

/// The server's side: a world the edits are sequenced into.
struct Server {
    world: World,
    materials: MaterialTable,
    structures: StructureLibrary,
    next_seq: u64,
}

/// One sequenced edit: its verdict and the deltas it broadcasts.
struct Sequenced {
    verdict: Verdict,
    changes: Vec<ChunkVersion>,
    deltas: Vec<WorldUpdate>,
}

impl Server {
    fn new(g: Arc<Generator>) -> Self {
        Self {
            world: World::new(g),
            materials: MaterialTable::default(),
            structures: StructureLibrary::default(),
            next_seq: 1,
        }
    }

    fn apply(&mut self, edit: &Edit) -> Sequenced {
        let ctx = EditContext {
            materials: &self.materials,
            structures: &self.structures,
        };
        let out = edit.apply(&mut self.world, &ctx).unwrap();
        let seq = self.next_seq;
        self.next_seq += 1;
        let mut s = Sequenced {
            verdict: Verdict::Accepted { seq },
            changes: Vec::new(),
            deltas: Vec::new(),
        };
        for c in out.changed {
            let after = &self.world.peek(c.pos).unwrap().chunk;
            let delta =
                ChunkDelta::encode(c.pos, c.from_version, c.to_version, &c.before, after).unwrap();
            s.changes.push(ChunkVersion {
                pos: c.pos,
                version: c.to_version,
            });
            s.deltas.push(WorldUpdate::Delta(DeltaUpdate {
                delta,
                mesh_hash: 0,
                seq,
            }));
        }
        s
    }
}

/// A client: its replica and prediction, updated as `Client` does.
struct Local {
    replica: Replica,
    prediction: Prediction,
}

impl Local {
    fn new(g: Arc<Generator>, center: ChunkPos, cap: usize) -> Self {
        let mut replica = Replica::new(Some(g as Arc<dyn ChunkGenerator>));
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let pos = center.offset(dx, dy, dz).unwrap();
                    assert_eq!(replica.apply(WorldUpdate::Generated { pos }), None);
                }
            }
        }
        Self {
            replica,
            prediction: Prediction::new(Arc::new(StructureLibrary::default()), cap),
        }
    }

    fn update(&mut self, u: WorldUpdate) {
        let t = Touched::of(&u);
        assert_eq!(self.replica.apply(u), None);
        if let Some(t) = t {
            self.prediction.after_update(t, &self.replica);
        }
    }

    fn deltas(&mut self, s: &Sequenced) {
        for d in &s.deltas {
            self.update(d.clone());
        }
    }

    fn verdict(&mut self, id: u64, s: &Sequenced) {
        self.prediction
            .verdict(id, &s.verdict, &s.changes, &self.replica);
    }

    fn stats(&self) -> PredictionStats {
        self.prediction.stats()
    }

    /// The predicted view shows nothing the replica does not.
    fn assert_view_is_authoritative(&self, server: &World) {
        assert_eq!(self.prediction.predicted_chunks().count(), 0);
        for (pos, held) in self.replica.chunks() {
            let predicted = self.prediction.chunk(pos, &self.replica).unwrap();
            assert_eq!(*predicted, *held.chunk, "{pos:?}");
            if let Some(s) = server.peek(pos) {
                assert_eq!(held.version, s.version);
                assert_eq!(*held.chunk, *s.chunk);
            }
        }
    }
}

/// A server, a client holding the chunks around a surface voxel in the
/// middle of its chunk (at most `cap` predictions pending), and the voxel.
fn setup(cap: usize) -> (Server, Local, VoxelPos) {
    let g = Arc::new(Generator::fractal(GenParams::default()).unwrap());
    let (x, z) = (16 + 32 * 3, 16 + 32 * 2);
    let ground = VoxelPos::new(x, g.surface_height(x, z).floor() as i32, z);
    let local = Local::new(g.clone(), ground.chunk(), cap);
    (Server::new(g), local, ground)
}

fn mine(at: VoxelPos, radius: i32) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(at.x, at.y, at.z),
        radius: Fixed::from_voxels(radius),
        strength: 255,
    }
}

fn build(at: VoxelPos, radius: i32, material: u8) -> Edit {
    Edit::Build {
        center: FixedVec3::from_voxels(at.x, at.y, at.z),
        radius: Fixed::from_voxels(radius),
        material,
        strength: 255,
    }
}

/// Two overlapping builds in the air above `ground` (brick, then stone)
/// and the chunk they share.
fn overlapping_builds(ground: VoxelPos) -> (Edit, Edit, ChunkPos) {
    let above = VoxelPos::new(ground.x, ground.y + 4, ground.z);
    let first = build(above, 3, ids::BRICK);
    let second = build(VoxelPos::new(above.x + 2, above.y, above.z), 2, ids::STONE);
    (first, second, above.chunk())
}

#[test]
fn an_accepted_edit_is_shown_at_once_then_counted_exact() {
    let (mut server, mut c, ground) = setup(8);
    let edit = mine(ground, 3);
    let before = c.replica.voxel(ground).unwrap();
    assert!(c.prediction.predict(1, edit.clone(), &c.replica));
    let shown = c.prediction.voxel(ground, &c.replica).unwrap();
    assert!(shown.density < before.density, "{shown:?} vs {before:?}");
    assert_eq!(c.replica.voxel(ground), Some(before), "replica untouched");
    assert_eq!(c.stats().pending, 1);

    let s = server.apply(&edit);
    c.verdict(1, &s);
    assert_eq!(c.stats().pending, 1, "waits for the delta");
    // The view still shows the edit between verdict and delta.
    assert_eq!(c.prediction.voxel(ground, &c.replica), Some(shown));
    c.deltas(&s);
    let st = c.stats();
    assert_eq!((st.made, st.exact, st.pending), (1, 1, 0), "{st:?}");
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn a_delta_ahead_of_its_verdict_is_matched_by_seq() {
    let (mut server, mut c, ground) = setup(8);
    // Two of our edits on the same voxels, both in flight.
    let (e1, e2) = (mine(ground, 3), build(ground, 2, ids::BRICK));
    assert!(c.prediction.predict(1, e1.clone(), &c.replica));
    assert!(c.prediction.predict(2, e2.clone(), &c.replica));
    let (s1, s2) = (server.apply(&e1), server.apply(&e2));
    // The first edit's deltas arrive before its verdict: the view must not
    // apply it twice once the verdict says they were ours.
    c.deltas(&s1);
    c.verdict(1, &s1);
    let mid = c.prediction.chunk(ground.chunk(), &c.replica).unwrap();
    assert_eq!(*mid, *server.world.peek(ground.chunk()).unwrap().chunk);
    c.verdict(2, &s2);
    c.deltas(&s2);
    let st = c.stats();
    assert_eq!((st.made, st.exact, st.pending), (2, 2, 0), "{st:?}");
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn another_edit_sequenced_first_is_a_misprediction_and_the_view_rebases() {
    let (mut server, mut c, ground) = setup(8);
    let (theirs, ours, pos) = overlapping_builds(ground);
    // We predict on the state we hold; the server orders their edit first.
    assert!(c.prediction.predict(1, ours.clone(), &c.replica));
    let s_theirs = server.apply(&theirs);
    let s_ours = server.apply(&ours);
    // Their delta arrives: the view is rolled back and replayed on it, and
    // now equals what the server made of both edits.
    c.deltas(&s_theirs);
    assert_eq!(
        *c.prediction.chunk(pos, &c.replica).unwrap(),
        *server.world.peek(pos).unwrap().chunk
    );
    c.verdict(1, &s_ours);
    c.deltas(&s_ours);
    let st = c.stats();
    assert_eq!(
        (st.made, st.exact, st.mispredicted, st.pending),
        (1, 0, 1, 0),
        "{st:?}"
    );
    assert_eq!(st.mispredicted_outside_box, 0, "the builds overlap");
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn another_edit_elsewhere_in_the_chunk_mispredicts_outside_the_box() {
    let (mut server, mut c, ground) = setup(8);
    let o = ground.chunk().origin();
    let corner = VoxelPos::new(o.x + 1, ground.y, o.z + 1);
    let theirs = Edit::FillBox {
        min: corner,
        max: VoxelPos::new(corner.x + 1, corner.y, corner.z + 1),
        material: ids::BRICK,
    };
    let ours = mine(ground, 2);
    assert!(c.prediction.predict(1, ours.clone(), &c.replica));
    let s_theirs = server.apply(&theirs);
    let s_ours = server.apply(&ours);
    assert!(s_theirs.changes.iter().any(|ch| ch.pos == ground.chunk()));
    c.deltas(&s_theirs);
    c.deltas(&s_ours);
    c.verdict(1, &s_ours);
    let st = c.stats();
    assert_eq!(
        (st.mispredicted, st.mispredicted_outside_box, st.pending),
        (1, 1, 0),
        "{st:?}"
    );
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn a_rejected_edit_rolls_back_and_a_later_one_built_on_it_mispredicts() {
    let (mut server, mut c, ground) = setup(8);
    let (refused, ours, pos) = overlapping_builds(ground);
    assert!(c.prediction.predict(1, refused, &c.replica));
    assert!(c.prediction.predict(2, ours.clone(), &c.replica));
    c.prediction.verdict(
        1,
        &Verdict::Rejected(RejectReason::NoLineOfSight),
        &[],
        &c.replica,
    );
    assert_eq!(c.stats().rolled_back, 1);
    // The view now holds only the second edit, on the replica's state:
    // what the server makes of it.
    let s = server.apply(&ours);
    assert_eq!(
        *c.prediction.chunk(pos, &c.replica).unwrap(),
        *server.world.peek(pos).unwrap().chunk
    );
    c.deltas(&s);
    c.verdict(2, &s);
    let st = c.stats();
    assert_eq!(
        (st.made, st.rolled_back, st.mispredicted, st.pending),
        (2, 1, 1, 0),
        "{st:?}"
    );
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn a_chunk_resent_whole_leaves_the_edit_unverified() {
    let (mut server, mut c, ground) = setup(8);
    let edit = mine(ground, 3);
    assert!(c.prediction.predict(1, edit.clone(), &c.replica));
    let s = server.apply(&edit);
    c.verdict(1, &s);
    // The deltas were lost; the chunks come back as snapshots.
    for ch in &s.changes {
        let chunk = &server.world.peek(ch.pos).unwrap().chunk;
        c.update(WorldUpdate::Snapshot {
            pos: ch.pos,
            version: ch.version,
            hash: chunk_hash(chunk),
            mesh_hash: 0,
            data: encode_chunk(chunk),
        });
    }
    let st = c.stats();
    assert_eq!((st.made, st.unverified, st.pending), (1, 1, 0), "{st:?}");
    c.assert_view_is_authoritative(&server.world);
}

#[test]
fn predictions_are_capped_and_need_every_chunk_they_read() {
    let (_, mut c, ground) = setup(2);
    let far = VoxelPos::new(ground.x + 200, ground.y, ground.z);
    assert!(!c.prediction.predict(1, mine(far, 2), &c.replica));
    let huge = Edit::Mine {
        center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
        radius: Fixed::from_voxels(1000),
        strength: 255,
    };
    assert!(!c.prediction.predict(2, huge, &c.replica));
    for id in 3..6 {
        c.prediction.predict(id, mine(ground, 2), &c.replica);
    }
    let st = c.stats();
    assert_eq!((st.made, st.pending, st.skipped), (2, 2, 3), "{st:?}");
    // An edit whose verdict never comes is dropped from the view.
    c.prediction.abandon(3, &c.replica);
    c.prediction.abandon(4, &c.replica);
    let st = c.stats();
    assert_eq!((st.rolled_back, st.pending), (2, 0), "{st:?}");
    assert_eq!(c.prediction.predicted_chunks().count(), 0);
}
