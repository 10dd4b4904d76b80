//! Every message round-trips; framing splits at any byte boundary; caps,
//! garbage and trailing bytes are typed errors, never panics.

use strata_protocol::limits::{MAX_CLIENT_FRAME, MAX_SERVER_FRAME};
use strata_protocol::*;
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::edit::{Edit, EditKind, Fixed, FixedVec3};
use strata_terrain::{Chunk, ChunkPos, Voxel};

fn client_messages() -> Vec<ClientMessage> {
    vec![
        ClientMessage::Hello(Hello {
            protocol_version: PROTOCOL_VERSION,
            token: "v1.abc.def".into(),
            capabilities: CAP_SNAPSHOTS | CAP_OP_REPLAY,
        }),
        ClientMessage::Subscribe {
            center: ChunkPos::new(-3, 0, 7),
            radius: 4,
        },
        ClientMessage::Edit(EditRequest {
            client_edit_id: 42,
            edit: Edit::Mine {
                center: FixedVec3::from_voxels(-5, 3, 9),
                radius: Fixed(768),
                strength: 200,
            },
        }),
        ClientMessage::ResyncRequest {
            pos: ChunkPos::new(1, 2, 3),
        },
        ClientMessage::FullSnapshotRequest {
            pos: ChunkPos::new(-1, -2, -3),
        },
        ClientMessage::Ping { nonce: u64::MAX },
        ClientMessage::Forget {
            chunks: vec![
                ChunkPos::new(1, -2, 3),
                ChunkPos::new(i32::MIN, 0, i32::MAX),
            ],
        },
    ]
}

fn server_messages() -> Vec<ServerMessage> {
    vec![
        ServerMessage::Welcome(Welcome {
            session: 7,
            player: "ana".into(),
            role: Role::Admin,
            world_seed: 99,
            generator_version: 1,
            generator_params: "seed = 99\n".into(),
            server_time: 1_700_000_000_000,
            view_radius: 6,
            last_seq: 12,
            start: Start::Spawn {
                x: -5,
                z: 9,
                radius: 2048,
            },
        }),
        ServerMessage::Welcome(Welcome {
            session: 8,
            player: "bo".into(),
            role: Role::Player,
            world_seed: 99,
            generator_version: 1,
            generator_params: String::new(),
            server_time: 1,
            view_radius: 2,
            last_seq: 0,
            start: Start::Resume {
                feet: FixedVec3::from_voxels(3, -4, 5),
            },
        }),
        ServerMessage::EditAccepted {
            client_edit_id: 1,
            seq: 2,
            changes: vec![ChunkVersion {
                pos: ChunkPos::new(-1, 0, 2),
                version: 300,
            }],
        },
        ServerMessage::EditRejected {
            client_edit_id: 3,
            reason: RejectReason::OutOfReach {
                distance: Fixed(9000),
                max: Fixed(2048),
            },
        },
        ServerMessage::EditRejected {
            client_edit_id: 4,
            reason: RejectReason::NotPermitted {
                kind: EditKind::Explode,
            },
        },
        ServerMessage::Error {
            code: ErrorCode::BadToken,
            message: "signature mismatch".into(),
        },
        ServerMessage::Pong {
            nonce: 5,
            server_time: 6,
        },
        ServerMessage::RequestRefused(Refusal::ForgetTooLarge {
            chunks: 5000,
            max: 1024,
        }),
        ServerMessage::PositionRefused {
            seq: u32::MAX,
            reason: PositionRefusal::OutsideSpawn {
                x: -4,
                z: 4,
                radius: 2048,
            },
            at: None,
        },
        ServerMessage::PositionRefused {
            seq: 1,
            reason: PositionRefusal::OutOfBounds,
            at: Some(FixedVec3::from_voxels(-3, 40, 7)),
        },
        ServerMessage::PositionRefused {
            seq: 2,
            reason: PositionRefusal::PathBlocked {
                voxel: strata_terrain::VoxelPos::new(-1, 2, 3),
            },
            at: Some(FixedVec3::from_voxels(0, 1, 3)),
        },
        ServerMessage::PositionRefused {
            seq: 3,
            reason: PositionRefusal::TooHigh {
                apex: Fixed::from_voxels(44),
            },
            at: Some(FixedVec3::from_voxels(0, 40, 3)),
        },
    ]
}

fn updates() -> Vec<WorldUpdate> {
    let base = Chunk::uniform(Voxel::solid(3));
    let mut target = base.clone();
    target.set(4, 5, 6, Voxel::AIR);
    let delta = ChunkDelta::encode(ChunkPos::new(0, -1, 0), 0, 1, &base, &target).unwrap();
    vec![
        WorldUpdate::Generated {
            pos: ChunkPos::new(1, 1, 1),
        },
        WorldUpdate::Snapshot {
            pos: ChunkPos::new(0, 0, 0),
            version: 3,
            hash: 4,
            mesh_hash: 5,
            data: encode_chunk(&target),
        },
        WorldUpdate::Delta(DeltaUpdate {
            delta,
            mesh_hash: 77,
            seq: 8,
        }),
        WorldUpdate::Unsubscribed {
            pos: ChunkPos::new(9, 9, 9),
        },
        WorldUpdate::TickEnd { last_seq: 41 },
        WorldUpdate::Op(OpUpdate {
            seq: 42,
            edit: Edit::Smooth {
                center: FixedVec3::from_voxels(-5, 3, 9),
                radius: Fixed(1024),
                strength: 128,
            },
            chunks: vec![OpChunk {
                pos: ChunkPos::new(-1, 0, 0),
                version: 7,
                hash: u64::MAX,
                mesh_hash: 1,
            }],
        }),
        WorldUpdate::InterestComplete {
            center: ChunkPos::new(-7, 2, 0),
            radius: 32,
        },
    ]
}

#[test]
fn messages_round_trip() {
    for m in client_messages() {
        let b = encode(&m, Direction::ClientToServer).unwrap();
        assert_eq!(
            decode::<ClientMessage>(&b, Direction::ClientToServer).unwrap(),
            m
        );
    }
    for m in server_messages() {
        let b = encode(&m, Direction::ServerToClient).unwrap();
        assert_eq!(
            decode::<ServerMessage>(&b, Direction::ServerToClient).unwrap(),
            m
        );
    }
    for m in updates() {
        let b = encode(&m, Direction::ServerToClient).unwrap();
        assert_eq!(
            decode::<WorldUpdate>(&b, Direction::ServerToClient).unwrap(),
            m
        );
    }
    let p = PositionUpdate {
        seq: 3,
        pos: FixedVec3::from_voxels(1, -2, 3),
    };
    let b = encode(&p, Direction::ClientToServer).unwrap();
    assert!(b.len() <= limits::MAX_DATAGRAM);
    assert_eq!(
        decode::<PositionUpdate>(&b, Direction::ClientToServer).unwrap(),
        p
    );
}

#[test]
fn golden_bytes_pin_the_wire_format() {
    // PROTOCOL.md walks through these bytes; changing them breaks clients.
    assert_eq!(PROTOCOL_VERSION, 11, "PROTOCOL.md names version 11");
    let hello = ClientMessage::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        token: "t".into(),
        capabilities: CAP_SNAPSHOTS | CAP_OP_REPLAY,
    });
    // Capabilities come last: varint 3.
    assert_eq!(
        encode_frame(&hello, Direction::ClientToServer).unwrap(),
        [5, 0, 0, 0, 0, 11, 1, b't', 3]
    );
    // Op: variant 7, seq, the edit as in `Edit`, then the chunk list.
    let op = WorldUpdate::Op(OpUpdate {
        seq: 9,
        edit: Edit::Mine {
            center: FixedVec3::from_voxels(1, 2, 3),
            radius: Fixed(768),
            strength: 255,
        },
        chunks: vec![OpChunk {
            pos: ChunkPos::new(0, -1, 0),
            version: 2,
            hash: 5,
            mesh_hash: 300,
        }],
    });
    assert_eq!(
        encode(&op, Direction::ServerToClient).unwrap(),
        [
            7, 9, 0, 0xfb, 0, 2, 0xfb, 0, 4, 0xfb, 0, 6, 0xfb, 0, 6, 0xff, 1, 0, 1, 0, 2, 5, 0xfb,
            0x2c, 1
        ]
    );
    let ping = ClientMessage::Ping { nonce: 300 };
    // Variant 5, then varint 300 = 0xfb + u16 LE.
    assert_eq!(
        encode(&ping, Direction::ClientToServer).unwrap(),
        [5, 0xfb, 0x2c, 0x01]
    );
    let sub = ClientMessage::Subscribe {
        center: ChunkPos::new(-1, 0, 1),
        radius: 2,
    };
    // Signed varints are zigzag encoded: -1 -> 1, 1 -> 2.
    assert_eq!(
        encode(&sub, Direction::ClientToServer).unwrap(),
        [1, 1, 0, 2, 2]
    );
    let accepted = ServerMessage::EditAccepted {
        client_edit_id: 1,
        seq: 2,
        changes: vec![ChunkVersion {
            pos: ChunkPos::new(-1, 0, 2),
            version: 300,
        }],
    };
    // Variant 1, id, seq, one change: pos (-1, 0, 2) zigzagged, version 300.
    assert_eq!(
        encode(&accepted, Direction::ServerToClient).unwrap(),
        [1, 1, 2, 1, 1, 0, 4, 0xfb, 0x2c, 0x01]
    );
    let mine = ClientMessage::Edit(EditRequest {
        client_edit_id: 7,
        edit: Edit::Mine {
            center: FixedVec3::new(Fixed(2688), Fixed(10240), Fixed(-768)),
            radius: Fixed(768),
            strength: 255,
        },
    });
    // Variant 2, id 7, Mine (0); each Fixed zigzagged (2688 -> 5376 =
    // fb 00 15, ...); strength is a u8, one raw byte.
    assert_eq!(
        encode(&mine, Direction::ClientToServer).unwrap(),
        [2, 7, 0, 0xfb, 0x00, 0x15, 0xfb, 0x00, 0x50, 0xfb, 0xff, 0x05, 0xfb, 0x00, 0x06, 0xff]
    );
    let position = PositionUpdate {
        seq: 1,
        pos: FixedVec3::new(Fixed(384), Fixed(10240), Fixed(-512)),
    };
    assert_eq!(
        encode(&position, Direction::ClientToServer).unwrap(),
        [1, 0xfb, 0x00, 0x03, 0xfb, 0x00, 0x50, 0xfb, 0xff, 0x03]
    );
}

#[test]
fn golden_bytes_of_version_4_messages() {
    // Added at the end of their enums: earlier variant indices are unchanged.
    let forget = ClientMessage::Forget {
        chunks: vec![ChunkPos::new(-1, 0, 1)],
    };
    // Variant 6, one chunk, zigzagged coordinates.
    assert_eq!(
        encode(&forget, Direction::ClientToServer).unwrap(),
        [6, 1, 1, 0, 2]
    );
    let too_fast = ServerMessage::PositionRefused {
        seq: 9,
        reason: PositionRefusal::TooFast {
            distance: Fixed(2560),
            allowed: Fixed(768),
        },
        at: None,
    };
    // Variant 6, seq 9, TooFast (0), 2560 -> 5120 = fb 00 14, 768 -> 1536,
    // no position held (0).
    assert_eq!(
        encode(&too_fast, Direction::ServerToClient).unwrap(),
        [6, 9, 0, 0xfb, 0x00, 0x14, 0xfb, 0x00, 0x06, 0]
    );
    let feet = FixedVec3::new(Fixed(384), Fixed(10240), Fixed(-512));
    let solid = ServerMessage::PositionRefused {
        seq: 2,
        reason: PositionRefusal::InsideSolid {
            voxel: strata_terrain::VoxelPos::new(1, -1, 0),
        },
        at: Some(feet),
    };
    // ... then Some (1) and the feet as in `PositionUpdate`.
    assert_eq!(
        encode(&solid, Direction::ServerToClient).unwrap(),
        [6, 2, 1, 2, 1, 0, 1, 0xfb, 0x00, 0x03, 0xfb, 0x00, 0x50, 0xfb, 0xff, 0x03]
    );
    let blocked = ServerMessage::PositionRefused {
        seq: 3,
        reason: PositionRefusal::PathBlocked {
            voxel: strata_terrain::VoxelPos::new(1, -1, 0),
        },
        at: None,
    };
    assert_eq!(
        encode(&blocked, Direction::ServerToClient).unwrap(),
        [6, 3, 4, 2, 1, 0, 0]
    );
    // Gravity's refusal (version 10): variant 5, then a Fixed (44 * 256 =
    // 11264, zigzag 22528 = fb 00 58).
    let high = ServerMessage::PositionRefused {
        seq: 4,
        reason: PositionRefusal::TooHigh {
            apex: Fixed::from_voxels(44),
        },
        at: None,
    };
    assert_eq!(
        encode(&high, Direction::ServerToClient).unwrap(),
        [6, 4, 5, 0xfb, 0x00, 0x58, 0]
    );
    let too_large = ServerMessage::RequestRefused(Refusal::ForgetTooLarge {
        chunks: 2000,
        max: 1024,
    });
    // Variant 5, Refusal 2, then two varints (2000 = fb d0 07).
    assert_eq!(
        encode(&too_large, Direction::ServerToClient).unwrap(),
        [5, 2, 0xfb, 0xd0, 0x07, 0xfb, 0x00, 0x04]
    );
    let complete = WorldUpdate::InterestComplete {
        center: ChunkPos::new(0, -1, 2),
        radius: 8,
    };
    // Variant 8 (after `Op`), centre zigzagged, radius a raw u8.
    assert_eq!(
        encode(&complete, Direction::ServerToClient).unwrap(),
        [8, 0, 1, 4, 8]
    );
    // The largest Forget fits one client frame.
    let widest = ClientMessage::Forget {
        chunks: vec![ChunkPos::new(i32::MIN, i32::MIN, i32::MIN); limits::MAX_FORGET_CHUNKS],
    };
    assert!(encode_frame(&widest, Direction::ClientToServer).is_ok());
}

#[test]
fn frames_split_at_every_boundary() {
    let mut stream = Vec::new();
    for m in updates() {
        stream.extend(encode_frame(&m, Direction::ServerToClient).unwrap());
    }
    for step in [1, 2, 3, 7, 64, stream.len()] {
        let mut fb = FrameBuffer::new(Direction::ServerToClient);
        let mut got = Vec::new();
        for piece in stream.chunks(step) {
            fb.extend(piece);
            while let Some(m) = fb.next_message::<WorldUpdate>().unwrap() {
                got.push(m);
            }
        }
        assert_eq!(got, updates(), "step {step}");
        assert_eq!(fb.pending(), 0);
    }
}

#[test]
fn frames_left_waiting_across_reads_come_out_in_order() {
    // Many small frames, read in pieces, at most one taken per piece: the
    // buffer keeps frames across reads and counts what it holds.
    let msgs: Vec<WorldUpdate> = (0..200).flat_map(|_| updates()).collect();
    let mut stream = Vec::new();
    for m in &msgs {
        stream.extend(encode_frame(m, Direction::ServerToClient).unwrap());
    }
    for step in [5, 61, 1000] {
        let mut fb = FrameBuffer::new(Direction::ServerToClient);
        let (mut got, mut fed) = (Vec::new(), 0);
        for piece in stream.chunks(step) {
            fb.extend(piece);
            fed += piece.len();
            if let Some(m) = fb.next_message::<WorldUpdate>().unwrap() {
                got.push(m);
            }
            let taken: usize = got
                .iter()
                .map(|m| encode_frame(m, Direction::ServerToClient).unwrap().len())
                .sum();
            assert_eq!(fb.pending(), fed - taken, "step {step}");
        }
        while let Some(m) = fb.next_message::<WorldUpdate>().unwrap() {
            got.push(m);
        }
        assert_eq!(got, msgs, "step {step}");
        assert_eq!(fb.pending(), 0);
    }
}

#[test]
fn oversized_frames_fail_at_the_header() {
    let mut fb = FrameBuffer::new(Direction::ClientToServer);
    fb.extend(&((MAX_CLIENT_FRAME + 1) as u32).to_le_bytes());
    assert!(
        matches!(fb.next_frame(), Err(FrameError::Oversized { len, max }) if len == MAX_CLIENT_FRAME + 1 && max == MAX_CLIENT_FRAME)
    );
    let mut fb = FrameBuffer::new(Direction::ServerToClient);
    fb.extend(&(MAX_SERVER_FRAME as u32).to_le_bytes());
    assert!(
        fb.next_frame().unwrap().is_none(),
        "a frame at the cap is allowed, waiting for its body"
    );
    let mut fb = FrameBuffer::new(Direction::ClientToServer);
    fb.extend(&[0, 0, 0, 0]);
    assert!(matches!(fb.next_frame(), Err(FrameError::Empty)));
    // A message too large for its direction does not encode.
    let big = ClientMessage::Hello(Hello {
        protocol_version: 1,
        token: "x".repeat(MAX_CLIENT_FRAME),
        capabilities: 0,
    });
    assert!(matches!(
        encode(&big, Direction::ClientToServer),
        Err(CodecError::TooLarge { .. }) | Err(CodecError::Encode(_))
    ));
}

#[test]
fn garbage_and_trailing_bytes_are_errors() {
    let mut b = encode(&ClientMessage::Ping { nonce: 1 }, Direction::ClientToServer).unwrap();
    b.push(0);
    assert!(matches!(
        decode::<ClientMessage>(&b, Direction::ClientToServer),
        Err(CodecError::Trailing(1))
    ));
    // Deterministic pseudo-random garbage: decode must return, not panic.
    let mut x = 0x9e3779b97f4a7c15u64;
    for len in 0..400usize {
        let bytes: Vec<u8> = (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        let _ = decode::<ClientMessage>(&bytes, Direction::ClientToServer);
        let _ = decode::<WorldUpdate>(&bytes, Direction::ServerToClient);
    }
    // A length prefix claiming a huge string is refused by the size limit.
    let lie = [0u8, 1, 0xfc, 0xff, 0xff, 0xff, 0x7f];
    assert!(decode::<ClientMessage>(&lie, Direction::ClientToServer).is_err());
    // So is a Forget claiming 2^32 - 1 chunks with one there (and room for
    // at most MAX_FORGET_CHUNKS is reserved first: `cautious.rs`).
    let one = ClientMessage::Forget {
        chunks: vec![ChunkPos::new(1, 2, 3)],
    };
    let b = encode(&one, Direction::ClientToServer).unwrap();
    assert_eq!(b[1], 1, "{b:?}");
    let mut lie = vec![b[0], 0xfc, 0xff, 0xff, 0xff, 0xff];
    lie.extend_from_slice(&b[2..]);
    assert!(decode::<ClientMessage>(&lie, Direction::ClientToServer).is_err());
}

#[test]
fn close_codes_round_trip() {
    for code in ErrorCode::ALL {
        assert_eq!(
            ErrorCode::from_close_code(code.close_code() as u64),
            Some(code)
        );
        assert_ne!(code.close_code(), 0, "0 is a normal close");
    }
    assert_eq!(ErrorCode::from_close_code(0), None);
    assert_eq!(
        ErrorCode::from_close_code(ErrorCode::ALL.len() as u64 + 1),
        None
    );
}

/// Frame bytes on the updates stream, through the real codec, on the
/// default world's surface: an edit's `Delta` frames against its `Op`
/// frame, and a view's `Generated` frames against thin clients'
/// `Snapshot`s. `cargo test -p strata-protocol --test wire -- --nocapture
/// wire_bytes` prints the tables in BENCHMARKS.md.
mod wire_bytes {
    use std::sync::Arc;

    use strata_protocol::*;
    use strata_terrain::chunk_codec::encode_chunk;
    use strata_terrain::delta::ChunkDelta;
    use strata_terrain::edit::StructureLibrary;
    use strata_terrain::gen::{GenParams, Generator};
    use strata_terrain::hash::chunk_hash;
    use strata_terrain::mesh::{mesh_chunk, MeshOptions, Neighborhood};
    use strata_terrain::{ChunkPos, Edit, EditContext, Fixed, FixedVec3, MaterialTable, World};

    fn frame(u: &WorldUpdate) -> usize {
        encode_frame(u, Direction::ServerToClient).unwrap().len()
    }

    fn mesh_hash(world: &mut World, pos: ChunkPos) -> u64 {
        let around: Vec<ChunkPos> = (0..27)
            .filter_map(|i| pos.offset(i % 3 - 1, i / 3 % 3 - 1, i / 9 - 1))
            .collect();
        world.load(around.iter().copied());
        let nb = Neighborhood::from_chunks(pos, |p| world.peek(p).map(|v| &*v.chunk));
        mesh_chunk(&nb, &MeshOptions::default()).hash()
    }

    /// (chunks, delta frame bytes, op frame bytes) of `edit` at the surface.
    fn edit_bytes(edit: impl Fn(FixedVec3) -> Edit, x: i32, z: i32) -> (usize, usize, usize) {
        let g = Generator::fractal(GenParams::default()).unwrap();
        let y = g.surface_height(x, z).floor() as i32;
        let mut world = World::new(Arc::new(g));
        let (materials, structures) = (MaterialTable::default(), StructureLibrary::default());
        let ctx = EditContext {
            materials: &materials,
            structures: &structures,
        };
        let edit = edit(FixedVec3::from_voxels(x, y, z));
        let out = edit.apply(&mut world, &ctx).unwrap();
        let (mut deltas, mut chunks) = (0, Vec::new());
        for ch in &out.changed {
            let after = world.peek(ch.pos).unwrap().chunk.clone();
            // As the sequencer encodes it.
            let delta =
                ChunkDelta::encode(ch.pos, ch.from_version, ch.to_version, &ch.before, &after)
                    .unwrap();
            let mesh_hash = mesh_hash(&mut world, ch.pos);
            chunks.push(OpChunk {
                pos: ch.pos,
                version: ch.to_version,
                hash: chunk_hash(&after),
                mesh_hash,
            });
            deltas += frame(&WorldUpdate::Delta(DeltaUpdate {
                delta,
                mesh_hash,
                seq: 123_456,
            }));
        }
        let op = frame(&WorldUpdate::Op(OpUpdate {
            seq: 123_456,
            edit,
            chunks,
        }));
        (out.changed.len(), deltas, op)
    }

    /// The edit a benchmark case names, centred on `center`.
    fn edit_at(name: &str, center: FixedVec3) -> Edit {
        let r = Fixed::from_voxels;
        match name.split(' ').next() {
            Some("Mine") => Edit::Mine {
                center,
                radius: r(3),
                strength: 255,
            },
            Some("Explode") => Edit::Explode {
                center,
                radius: r(8),
                power: 512,
            },
            _ => Edit::Smooth {
                center,
                radius: r(4),
                strength: 255,
            },
        }
    }

    #[test]
    fn op_frames_are_smaller_than_the_deltas_they_replace() {
        println!("| edit | chunks | Delta frames | Op frame | ratio |");
        println!("|---|---|---|---|---|");
        let cases = [
            ("Mine r=3", 10, 10),
            ("Mine r=3 on a chunk border", 96, 40),
            ("Explode r=8 on a chunk corner", 64, 64),
            ("Smooth r=4", 10, 10),
        ];
        for (name, x, z) in cases {
            let (n, deltas, op) = edit_bytes(|c| edit_at(name, c), x, z);
            println!(
                "| {name} | {n} | {deltas} B | {op} B | {:.1}× |",
                deltas as f64 / op as f64
            );
            assert!(op < deltas, "{name}: op {op} B, deltas {deltas} B");
        }
    }

    /// Chunks of a view of Chebyshev `radius` around the surface at
    /// (70, 40), clipped to the default rows -4..=7.
    fn view(radius: i32) -> Vec<ChunkPos> {
        let g = Generator::fractal(GenParams::default()).unwrap();
        let c = strata_terrain::VoxelPos::new(70, g.surface_height(70, 40) as i32 + 1, 40).chunk();
        let mut v = Vec::new();
        for y in (c.y - radius).max(-4)..=(c.y + radius).min(7) {
            for z in c.z - radius..=c.z + radius {
                for x in c.x - radius..=c.x + radius {
                    v.push(ChunkPos::new(x, y, z));
                }
            }
        }
        v
    }

    #[test]
    fn thin_view_loads_cost_whole_chunks() {
        println!("| view radius | chunks | normal (Generated) | thin (Snapshot) |");
        println!("|---|---|---|---|");
        for radius in [2, 4] {
            let mut world = World::new(Arc::new(Generator::fractal(GenParams::default()).unwrap()));
            let chunks = view(radius);
            let (mut normal, mut thin) = (0, 0);
            for &pos in &chunks {
                normal += frame(&WorldUpdate::Generated { pos });
                let mesh_hash = mesh_hash(&mut world, pos);
                let chunk = &world.peek(pos).unwrap().chunk;
                thin += frame(&WorldUpdate::Snapshot {
                    pos,
                    version: 0,
                    hash: chunk_hash(chunk),
                    mesh_hash,
                    data: encode_chunk(chunk),
                });
            }
            println!("| {radius} | {} | {normal} B | {thin} B |", chunks.len());
            assert!(normal < thin);
        }
    }
}
