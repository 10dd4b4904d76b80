//! Online snapshots through the copy-on-write path. A slow admin client
//! (a tiny QUIC receive window) stops reading early, which holds the
//! server's snapshot reader partway through a store of ~2000 modified
//! chunks; edits then change chunks it has not reached and create new
//! ones. The snapshot must still be exactly the world at its seq, and the
//! flow-control arithmetic proves those records were resolved after the
//! edits committed, so only their pre-images could have produced them.

use crate::common;
use crate::snapshot_common;

use std::fs::File;
use std::io::BufWriter;
use std::time::Duration;

use common::*;
use snapshot_common::{assert_snapshot_is_log_at, spot};
use strata_client_sim::{Client, Verdict};
use strata_protocol::admin::{
    AdminHello, AdminRequest, AdminResponse, ADMIN_ALPN, ADMIN_PROTOCOL_VERSION,
};
use strata_protocol::io::FramedReader;
use strata_protocol::{encode_frame, Direction, FrameBuffer, Role};
use strata_server::app;
use strata_server::client_tls::client_config_pinned_with_alpn;
use strata_server::net::admin_session::SNAPSHOT_STREAM_QUEUE;
use strata_server::snapshot::{verify, SnapshotHeader, SnapshotWriter};
use strata_server::store::ChunkStore;
use strata_terrain::material::ids;
use strata_terrain::{ChunkPos, Edit, VoxelPos};

/// Stream receive window of the slow snapshot client: the server can have
/// written at most this many bytes of the stream past what it has read.
const SLOW_WINDOW: u32 = 4 * 1024;
/// Snapshot records the slow client reads before it stops.
const READ_BEFORE_PAUSE: usize = 3;
/// Players that fill the world before the snapshot, one region each.
const BUILDERS: i32 = 6;
/// Width (x and z) of one player's region, in voxels: four 128-voxel boxes.
const REGION: i32 = 256;
/// Edge of the boxes that fill a region.
const EDGE: i32 = 128;

async fn start_builders_server(dir: &std::path::Path) -> app::Running {
    let mut cfg = test_config(dir);
    cfg.validation.edit_rate.capacity = 1000;
    cfg.validation.edit_rate.per_second = 1000;
    cfg.validation.volume_rate.capacity = 1 << 30;
    cfg.validation.volume_rate.per_second = 1 << 30;
    // The second edit of a post-snapshot pair aims 11 voxels up; a box's
    // collision surface sits half a voxel from a target on its face.
    cfg.validation.reach = 16.0;
    cfg.validation.los_tolerance = 2.0;
    cfg.interest.view_radius = 1;
    app::start(cfg).await.expect("server starts")
}

/// An admin-role player standing at the centre of region `i`, and the
/// lowest voxel y of the boxes above its head.
async fn builder(server: &app::Running, i: i32) -> (Client, VoxelPos, i32) {
    let c = connect(server, &format!("builder{i}"), Role::Admin).await;
    let (feet, ground) = spot(REGION * i + REGION / 2, REGION / 2);
    c.send_position(feet).unwrap();
    let here = ground.chunk();
    assert!(eventually(Duration::from_secs(10), || c.replica().get(here).is_some()).await);
    (c, ground, ground.y + 4)
}

/// Four `EDGE`-sized boxes filling the region around `ground`, from `y0`
/// up; each has a corner right above the player's head.
fn fill_region(ground: VoxelPos, y0: i32) -> Vec<Edit> {
    let (x, z) = (ground.x, ground.z);
    [(x - EDGE, z - EDGE), (x, z - EDGE), (x - EDGE, z), (x, z)]
        .into_iter()
        .map(|(x0, z0)| Edit::FillBox {
            min: VoxelPos::new(x0, y0, z0),
            max: VoxelPos::new(x0 + EDGE - 1, y0 + EDGE - 1, z0 + EDGE - 1),
            material: ids::STONE,
        })
        .collect()
}

/// Hollows the filled region above `ground`, then fills part of the hollow
/// again: the second edit changes chunks the first already changed.
fn carve_region(ground: VoxelPos, y0: i32) -> Vec<Edit> {
    let (x, z) = (ground.x, ground.z);
    vec![
        Edit::ClearBox {
            min: VoxelPos::new(x - 40, y0, z - 40),
            max: VoxelPos::new(x + 39, y0 + 60, z + 39),
        },
        Edit::FillBox {
            min: VoxelPos::new(x - 20, y0 + 10, z - 20),
            max: VoxelPos::new(x + 19, y0 + 30, z + 19),
            material: ids::DIRT,
        },
    ]
}

/// Sends the edits in order; returns their seqs (each must be accepted).
async fn apply(c: &Client, edits: Vec<Edit>) -> Vec<u64> {
    let mut seqs = Vec::new();
    for e in edits {
        match c.edit(e.clone()).await.unwrap() {
            Verdict::Accepted { seq } => seqs.push(seq),
            other => panic!("{e:?}: {other:?}"),
        }
    }
    seqs
}

/// An admin-protocol connection that reads only when asked, with a small
/// receive window so the server cannot run far ahead of it.
struct SlowAdmin {
    _endpoint: quinn::Endpoint,
    conn: quinn::Connection,
    /// Kept open: finishing it ends the session after the snapshot.
    _send: quinn::SendStream,
    reader: FramedReader<quinn::RecvStream>,
    /// Stream offset where each message read so far began, and its bytes.
    frames: Vec<(u64, AdminResponse)>,
    consumed: u64,
}

impl SlowAdmin {
    async fn connect(server: &app::Running, token: &str) -> Self {
        let cfg = client_config_pinned_with_alpn(&server.cert_der, ADMIN_ALPN).unwrap();
        let (endpoint, conn) = connect_small_window(server.addr, cfg, SLOW_WINDOW).await;
        let (mut send, recv) = conn.open_bi().await.unwrap();
        let hello = AdminRequest::Hello(AdminHello {
            protocol_version: ADMIN_PROTOCOL_VERSION,
            token: token.to_string(),
        });
        let snapshot = AdminRequest::Snapshot {
            max_pending_chunks: 0,
        };
        for req in [hello, snapshot] {
            let f = encode_frame(&req, Direction::ClientToServer).unwrap();
            send.write_all(&f).await.unwrap();
        }
        let mut me = SlowAdmin {
            _endpoint: endpoint,
            _send: send,
            conn,
            reader: FramedReader::new(recv, FrameBuffer::new(Direction::ServerToClient)),
            frames: Vec::new(),
            consumed: 0,
        };
        assert!(matches!(me.next().await, AdminResponse::Welcome(_)));
        me
    }

    /// The next message; its offset is recorded from its encoded length
    /// (framing is deterministic, so re-encoding gives the bytes sent).
    async fn next(&mut self) -> AdminResponse {
        let msg: AdminResponse = tokio::time::timeout(Duration::from_secs(20), self.reader.next())
            .await
            .expect("server answered in time")
            .unwrap()
            .expect("stream open");
        let len = encode_frame(&msg, Direction::ServerToClient).unwrap().len() as u64;
        self.frames.push((self.consumed, msg.clone()));
        self.consumed += len;
        msg
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn snapshot_reader_held_behind_edits_uses_their_pre_images() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        let tmp = tempfile::tempdir().unwrap();
        let data = tmp.path().join("data");
        let server = start_builders_server(&data).await;

        // Fill BUILDERS regions along +x: ~320 modified chunks each.
        let mut builders = Vec::new();
        for i in 0..BUILDERS {
            let (c, ground, y0) = builder(&server, i).await;
            apply(&c, fill_region(ground, y0)).await;
            builders.push((c, ground, y0));
        }
        // A player in a region past the others that edits only later.
        let (late, late_ground, late_y0) = builder(&server, BUILDERS).await;

        // Start the snapshot, read a few records, then stop reading.
        let mut admin = SlowAdmin::connect(&server, &token(&server, "root", Role::Admin)).await;
        let AdminResponse::SnapshotBegin(info) = admin.next().await else {
            panic!("no SnapshotBegin: {:?}", admin.frames);
        };
        let s = info.seq;
        for _ in 0..READ_BEFORE_PAUSE {
            assert!(matches!(admin.next().await, AdminResponse::SnapshotChunk { .. }));
        }
        let paused_at = admin.reader.bytes_read();
        // Let the server fill the window and its queue and block.
        tokio::time::sleep(Duration::from_millis(300)).await;

        // Change the last two regions (twice) and create the late region.
        let mut after = Vec::new();
        for (c, ground, y0) in &builders[builders.len() - 2..] {
            after.extend(apply(c, carve_region(*ground, *y0)).await);
        }
        after.extend(apply(&late, fill_region(late_ground, late_y0)).await);
        assert!(after.iter().all(|&q| q > s), "edits after the snapshot's seq");

        // Resume: the rest of the snapshot, written as `create` writes it.
        let file = tmp.path().join("world.snap");
        let header = SnapshotHeader {
            seed: info.world_seed,
            generator_version: info.generator_version,
            seq: s,
            generator_params: info.generator_params.clone(),
            zones: info.zones.clone(),
        };
        let mut w = SnapshotWriter::new(BufWriter::new(File::create(&file).unwrap()), &header).unwrap();
        let mut i = 0;
        let end = loop {
            while i < admin.frames.len() {
                if let (_, AdminResponse::SnapshotChunk { pos, version, data }) = &admin.frames[i] {
                    w.chunk(*pos, *version, data).unwrap();
                }
                i += 1;
            }
            match admin.next().await {
                AdminResponse::SnapshotEnd { chunks } => break chunks,
                AdminResponse::SnapshotChunk { .. } => {}
                other => panic!("unexpected {other:?}"),
            }
        };
        assert_eq!(end, w.records());
        let (f, _) = w.finish().unwrap();
        drop(f);
        assert_eq!(admin.consumed, admin.reader.bytes_read(), "frame accounting matches the stream");
        admin.conn.close(0u32.into(), b"done");
        for (c, _, _) in builders {
            c.close().await;
        }
        late.close().await;
        server.shutdown().await.unwrap();

        // Records in stream order with their offsets.
        let records: Vec<(u64, ChunkPos, u64)> = admin
            .frames
            .iter()
            .filter_map(|(at, m)| match m {
                AdminResponse::SnapshotChunk { pos, version, .. } => Some((*at, *pos, *version)),
                _ => None,
            })
            .collect();
        // While paused, the server's stream could hold bytes up to
        // `paused_at + SLOW_WINDOW`, its queue SNAPSHOT_STREAM_QUEUE frames,
        // and its reader one more: every later record was resolved only
        // after we resumed, i.e. after every edit above had committed.
        let early = records.iter().filter(|r| r.0 < paused_at + u64::from(SLOW_WINDOW)).count()
            + SNAPSHOT_STREAM_QUEUE
            + 1;
        assert!(early < records.len(), "the reader was held partway ({early} of {})", records.len());
        let first_late = records[early].1;

        let report = verify(&file, |_| {}).unwrap();
        assert!(report.is_ok(), "{:?}", report.issues);
        assert_eq!(report.chunks, end);

        // The snapshot equals the log replayed to S, chunk hash for chunk hash.
        let (store, _, versions) = assert_snapshot_is_log_at(&data, &file, s);
        assert!(versions.len() > 1500, "a large store: {} chunks", versions.len());

        // Every chunk an edit after S touched was read after those edits:
        // changed ones come out at their S state, new ones not at all.
        let (mut changed, mut created) = (0, 0);
        for q in &after {
            for (pos, v) in store.log_entry(*q).unwrap().unwrap().changes {
                assert!(pos >= first_late, "{pos:?} was reached after the edits");
                match versions.get(&pos) {
                    Some(&at_s) => {
                        assert!(at_s < v, "{pos:?} at its S version, not {v}");
                        changed += 1;
                    }
                    // Not in the snapshot (its chunk set is `versions`).
                    None => created += 1,
                }
            }
        }
        assert!(changed > 50 && created > 50, "changed {changed}, created {created}");
        eprintln!(
            "{} records, at most {early} resolved before the edits; {changed} changes and {created} new chunks after S",
            records.len()
        );
    })
    .await
    .expect("test finished in time");
}
