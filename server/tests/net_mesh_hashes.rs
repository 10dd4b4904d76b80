//! A snapshot (or patch) carries its chunk's mesh hash, and a chunk's mesh
//! reads its neighbours' voxels. The server reuses encoded snapshot frames,
//! so a neighbour's change must retire them: a client that asks for a chunk
//! after its neighbour changed gets the hash of the mesh as it now stands.

use crate::common;

use std::time::Duration;

use common::*;
use strata_client_sim::{Client, Verdict};
use strata_protocol::Role;
use strata_terrain::gen::{GenParams, Generator};
use strata_terrain::{ChunkPos, Edit, FixedVec3, VoxelPos};

/// Standing position on the surface at (x, z), and that surface voxel.
fn ground(g: &Generator, x: i32, z: i32) -> (FixedVec3, VoxelPos) {
    let y = g.surface_height(x, z);
    (
        at(x as f64, y + 1.0, z as f64),
        VoxelPos::new(x, y.floor() as i32, z),
    )
}

fn mine(center: [f64; 3], radius: f64) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_f64(center).unwrap(),
        radius: r(radius),
        strength: 255,
    }
}

async fn accepted(c: &Client, e: Edit) -> u64 {
    match c.edit(e).await.unwrap() {
        Verdict::Accepted { seq } => seq,
        v => panic!("edit refused: {v:?}"),
    }
}

/// Whether `c` holds `pos` and its 26 neighbours.
fn holds_around(c: &Client, pos: ChunkPos) -> bool {
    let r = c.replica();
    (-1..=1).all(|dz| {
        (-1..=1).all(|dy| (-1..=1).all(|dx| r.get(pos.offset(dx, dy, dz).unwrap()).is_some()))
    })
}

#[tokio::test]
async fn resent_chunks_carry_the_mesh_hash_of_their_current_neighbours() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let dir = tempfile::tempdir().unwrap();
        let server = start(dir.path()).await;
        let g = Generator::fractal(GenParams::default()).unwrap();
        // Chunk x = 2 spans world x 64..=95; its apron holds x = 96 and 97.
        let (feet, near) = ground(&g, 93, 40);
        let t = near.chunk();
        assert_eq!(t.x, 2);
        let (far_feet, far) = ground(&g, 140, 40);

        let a = connect(&server, "ana", Role::Player).await;
        let c = connect(&server, "cy", Role::Player).await;
        let d = connect(&server, "dee", Role::Player).await;
        for cl in [&a, &c] {
            cl.send_position(feet).unwrap();
        }
        d.send_position(far_feet).unwrap();
        assert!(eventually(Duration::from_secs(20), || holds_around(&c, t)).await);

        // 1. Modify the chunk itself, so it is sent as a patch from now on.
        let y = |x: i32| g.surface_height(x, 40);
        accepted(&a, mine([88.0, y(88), 40.0], 2.0)).await;
        // 2. A newcomer's patch of it gets encoded (and kept for reuse).
        let b = connect(&server, "bo", Role::Player).await;
        b.send_position(feet).unwrap();
        assert!(
            eventually(Duration::from_secs(20), || b
                .replica()
                .get(t)
                .is_some_and(|h| h.version == 1))
            .await
        );
        assert!(
            b.replica().stats.patched >= 1,
            "a modified chunk comes as a patch"
        );
        // 3. Dig only in the neighbour (x 96..=99), inside the chunk's apron:
        //    its voxels and version stay, its mesh changes.
        let seq = accepted(&a, mine([97.5, y(97), 40.0], 1.5)).await;
        assert!(eventually(Duration::from_secs(10), || c.replica().last_seq() >= seq).await);
        assert_eq!(c.replica().get(t).unwrap().version, 1);
        // 4. Ask for the chunk again: the server must not resend the frame
        //    it encoded before the neighbour changed.
        let before = c.replica().stats;
        c.resync(t).await.unwrap();
        assert!(
            eventually(Duration::from_secs(10), || c.replica().stats.snapshots
                > before.snapshots)
            .await
        );
        // 5. A change two chunks away ends a tick for this client, which then
        //    meshes the resent chunk and compares hashes.
        let seq = accepted(&d, mine([140.0, y(140), 40.0], 2.0)).await;
        assert!(far.chunk().x - t.x >= 2);
        assert!(eventually(Duration::from_secs(10), || c.replica().last_seq() >= seq).await);
        let stats = c.replica().stats;
        assert!(
            stats.meshes_checked > before.meshes_checked,
            "the resent chunk's mesh was checked: {stats:?}"
        );
        assert_eq!(
            stats.mesh_mismatches,
            0,
            "{:?}",
            c.replica().mesh_mismatches()
        );
        for cl in [a, b, c, d] {
            cl.close().await;
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test finished in time");
}
