//! Helpers shared by the store tests: realistic chunks, a tiny stand-in
//! for the sequencer that numbers edits and versions chunks, and the
//! backends a conformance test runs on ([`places`]).
#![allow(dead_code)]

use std::collections::BTreeMap;

use strata_server::store::pg::PgConfig;
use strata_server::store::{ChunkStore, CommitBatch, LogEntry, PgStore, SledStore};
use strata_terrain::chunk::DenseChunk;
use strata_terrain::chunk_codec::encode_chunk;
use strata_terrain::delta::ChunkDelta;
use strata_terrain::material::ids;
use strata_terrain::{Chunk, ChunkGenerator, ChunkPos, Edit, Fixed, FixedVec3, Voxel, CHUNK_SIZE};
use strata_tests::postgres::PgDb;

use crate::common::{test_config, Backend};
use strata_server::config::ServerConfig;

/// A dense chunk with a rolling surface: grass over dirt over stone, a
/// density ramp at the surface, varied by `salt` so chunks differ.
pub fn terrain_chunk(salt: u32) -> Chunk {
    let mut d = DenseChunk::filled(Voxel::AIR);
    let n = CHUNK_SIZE as usize;
    for z in 0..n {
        for x in 0..n {
            let h = 12 + ((x as u32 * 7 + z as u32 * 3 + salt * 5) % 9) as usize;
            for y in 0..n {
                let i = x | (y << 5) | (z << 10);
                let density = if y + 1 < h {
                    255
                } else if y < h + 1 {
                    (128 + salt % 100) as u8
                } else {
                    0
                };
                let material = match h.saturating_sub(y) {
                    0 => ids::AIR,
                    1 => ids::GRASS,
                    2..=4 => ids::DIRT,
                    _ => ids::STONE,
                };
                d.set(
                    i,
                    Voxel::new(density, if density == 0 { ids::AIR } else { material }),
                );
            }
        }
    }
    Chunk::Dense(d)
}

pub fn mine_at(x: i32, y: i32, z: i32) -> Edit {
    Edit::Mine {
        center: FixedVec3::from_voxels(x, y, z),
        radius: Fixed::from_voxels(3),
        strength: 200,
    }
}

/// Numbers edits and versions chunks the way the sequencer does.
#[derive(Debug, Default)]
pub struct Seq {
    pub last_seq: u64,
    pub versions: BTreeMap<ChunkPos, u64>,
    /// Each chunk's last state, for [`Seq::delta_batch`].
    pub states: BTreeMap<ChunkPos, Chunk>,
}

impl Seq {
    /// A batch of edits; edit `i` changes the chunks in `edits[i]` to the
    /// given states. The batch holds each chunk's last state.
    pub fn batch(&mut self, edits: &[Vec<(ChunkPos, Chunk)>]) -> CommitBatch {
        self.build(edits, false)
    }

    /// Like [`Seq::batch`], but as the server commits: chunks stored before
    /// the batch go as one delta per change, only new ones whole.
    pub fn delta_batch(&mut self, edits: &[Vec<(ChunkPos, Chunk)>]) -> CommitBatch {
        self.build(edits, true)
    }

    /// Like [`Seq::delta_batch`], but as a tick's lanes store them: one
    /// delta per stored chunk, across all of the batch's changes of it.
    pub fn span_batch(&mut self, edits: &[Vec<(ChunkPos, Chunk)>]) -> CommitBatch {
        let before = self.states.clone();
        let mut b = self.build(edits, true);
        let mut spans: BTreeMap<ChunkPos, (u64, u64)> = BTreeMap::new();
        for d in &b.deltas {
            spans
                .entry(d.pos)
                .and_modify(|s| s.1 = d.to_version)
                .or_insert((d.from_version, d.to_version));
        }
        b.deltas = spans
            .into_iter()
            .map(|(pos, (from, to))| {
                ChunkDelta::encode(pos, from, to, &before[&pos], &self.states[&pos]).unwrap()
            })
            .collect();
        b
    }

    /// Like [`Seq::delta_batch`], and each new chunk also as its change
    /// from `generator`'s output (`CommitBatch::generated`), as the
    /// sequencer hands a first touch to the store.
    pub fn generated_batch(
        &mut self,
        edits: &[Vec<(ChunkPos, Chunk)>],
        generator: &dyn ChunkGenerator,
    ) -> CommitBatch {
        let mut b = self.build(edits, true);
        b.generated = b
            .chunks
            .iter()
            .map(|(pos, v, c)| {
                ChunkDelta::encode(*pos, 0, *v, &generator.generate(*pos), c).unwrap()
            })
            .collect();
        b
    }

    fn build(&mut self, edits: &[Vec<(ChunkPos, Chunk)>], as_deltas: bool) -> CommitBatch {
        let stored_before: BTreeMap<ChunkPos, u64> = self.versions.clone();
        let mut deltas = Vec::new();
        let mut latest: BTreeMap<ChunkPos, (u64, Chunk)> = BTreeMap::new();
        let mut entries = Vec::new();
        for changes in edits {
            self.last_seq += 1;
            let mut logged = Vec::new();
            for (pos, chunk) in changes {
                let v = self.versions.entry(*pos).or_insert(0);
                *v += 1;
                logged.push((*pos, *v));
                if as_deltas && stored_before.get(pos).is_some_and(|&b| b > 0) {
                    let before = &self.states[pos];
                    deltas.push(ChunkDelta::encode(*pos, *v - 1, *v, before, chunk).unwrap());
                } else {
                    latest.insert(*pos, (*v, chunk.clone()));
                }
                self.states.insert(*pos, chunk.clone());
            }
            // Aim the edit at the first chunk (clamped: any centre will do).
            let p = changes.first().map_or(ChunkPos::new(0, 0, 0), |c| c.0);
            let at = |v: i32| v.clamp(-1000, 1000) * 32 + 5;
            entries.push(LogEntry {
                seq: self.last_seq,
                player: format!("player-{}", self.last_seq % 3),
                time_ms: 1_700_000_000_000 + self.last_seq,
                edit: mine_at(at(p.x), at(p.y), at(p.z)),
                changes: logged,
            });
        }
        CommitBatch {
            entries,
            chunks: latest
                .into_iter()
                .map(|(p, (v, c))| (p, v, c.into()))
                .collect(),
            deltas,
            generated: Vec::new(),
            last_seq: self.last_seq,
            epochs: None,
        }
    }
}

/// A dense chunk of pseudo-random densities 1..=16: about 16 KB compressed,
/// so a leaf of 16 is over a 512 KiB segment's inline limit (128 KiB) and
/// under the default's (512 KiB).
pub fn noisy_chunk(salt: u64) -> Chunk {
    let mut x = salt.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut d = strata_terrain::chunk::DenseChunk::filled(Voxel::AIR);
    for i in 0..strata_terrain::CHUNK_VOLUME {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        d.set(i, Voxel::new((x % 16) as u8 + 1, ids::STONE));
    }
    Chunk::Dense(d)
}

/// Where a store under test lives; [`Place::open`] opens it (again).
#[derive(Debug)]
pub enum Place {
    Sled(tempfile::TempDir),
    Postgres(PgDb),
}

impl Place {
    /// A new handle on the same store (a reopen, as after a restart).
    pub fn open(&self) -> Box<dyn ChunkStore> {
        match self {
            Place::Sled(dir) => Box::new(SledStore::open(dir.path()).unwrap()),
            Place::Postgres(db) => Box::new(pg_store(db)),
        }
    }

    pub fn backend(&self) -> &'static str {
        match self {
            Place::Sled(_) => "sled",
            Place::Postgres(_) => "postgres",
        }
    }
}

/// The PostgreSQL store on `db`, with the default region size.
pub fn pg_store(db: &PgDb) -> PgStore {
    let cfg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    PgStore::open(
        &cfg,
        strata_server::sequencer::regions::DEFAULT_REGION_CHUNKS,
    )
    .unwrap()
}

/// The rows of `pg_locks` for servers' serving locks (`SERVING_LOCK`,
/// shared; 91621622371393 is its key) in the test's own database:
/// `SELECT count(*) ` it, say.
pub const SERVING_LOCK_ROWS: &str = "FROM pg_locks WHERE locktype = 'advisory' \
    AND mode = 'ShareLock' \
    AND (classid::int8 << 32) + objid::int8 = 91621622371393 \
    AND database = (SELECT oid FROM pg_database WHERE datname = current_database())";

/// An empty store of every backend: sled, and PostgreSQL (a database of
/// its own in the test process's cluster) unless it is missing outside CI.
pub fn places(test: &str) -> Vec<Place> {
    let mut v = vec![Place::Sled(tempfile::tempdir().unwrap())];
    v.extend(strata_tests::postgres::database(test).map(Place::Postgres));
    v
}

/// Runs `sql` on `db` with a plain client; returns each row's first
/// column as text.
pub fn sql(db: &PgDb, sql: &str) -> Vec<String> {
    sql_url(&db.url(), sql)
}

/// [`sql`] on the database at `url` (off any runtime: it starts one).
pub fn sql_url(url: &str, sql: &str) -> Vec<String> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let (client, conn) = tokio_postgres::connect(url, tokio_postgres::NoTls)
            .await
            .unwrap();
        let driver = tokio::spawn(conn);
        let rows = client.simple_query(sql).await.unwrap();
        drop(client);
        let _ = driver.await;
        rows.into_iter()
            .filter_map(|m| match m {
                tokio_postgres::SimpleQueryMessage::Row(r) => r.get(0).map(str::to_string),
                _ => None,
            })
            .collect()
    })
}

/// What every read of `pos` must say.
pub fn assert_reads(store: &dyn ChunkStore, pos: ChunkPos, version: u64, chunk: &Chunk) {
    let loaded = store.load_chunk(pos).unwrap().unwrap();
    assert_eq!((loaded.version, &loaded.chunk), (version, chunk));
    let raw = store.raw_chunk(pos).unwrap().unwrap();
    assert_eq!((raw.version, raw.encoded), (version, encode_chunk(chunk)));
    let listed: Vec<_> = store.modified_chunks().map(|r| r.unwrap()).collect();
    assert!(listed.contains(&(pos, version)), "{listed:?}");
    let walked: Vec<_> = store.raw_chunks().map(|r| r.unwrap()).collect();
    assert!(walked
        .iter()
        .any(|r| r.pos == pos && r.version == version && r.encoded == encode_chunk(chunk)));
}

/// Locks `db`'s world row from a session of its own (as a single node
/// paused inside its commit holds it), returns once it is locked, and
/// lets it go (ending that transaction with `end`) when `until` returns,
/// on the returned thread.
pub fn hold_world_row(
    db: &PgDb,
    end: &'static str,
    until: impl FnOnce() + Send + 'static,
) -> std::thread::JoinHandle<()> {
    hold_rows(
        db,
        "SELECT 1 FROM world WHERE id = 1 FOR UPDATE",
        end,
        until,
    )
}

/// Runs `lock` in a transaction of its own until the returned sender
/// sends (or drops), then rolls it back; join the handle to wait for that.
pub fn hold_until_told(
    db: &PgDb,
    lock: &str,
) -> (std::sync::mpsc::Sender<()>, std::thread::JoinHandle<()>) {
    let (done_tx, done) = std::sync::mpsc::channel::<()>();
    let holder = hold_rows(db, lock, "ROLLBACK", move || {
        let _ = done.recv();
    });
    (done_tx, holder)
}

/// Runs `lock` (statements taking row locks) in a transaction of its
/// own, returns once they ran, and ends it with `end` when `until`
/// returns, on the returned thread.
pub fn hold_rows(
    db: &PgDb,
    lock: &str,
    end: &'static str,
    until: impl FnOnce() + Send + 'static,
) -> std::thread::JoinHandle<()> {
    let lock = format!("BEGIN; {lock}");
    let url = db.url();
    let (locked_tx, locked) = std::sync::mpsc::channel();
    let holder = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let (client, conn) = tokio_postgres::connect(&url, tokio_postgres::NoTls)
                .await
                .unwrap();
            let driver = tokio::spawn(conn);
            client.batch_execute(&lock).await.unwrap();
            locked_tx.send(()).unwrap();
            tokio::task::spawn_blocking(until).await.unwrap();
            client.batch_execute(end).await.unwrap();
            drop(client);
            let _ = driver.await;
        });
    });
    locked.recv().unwrap();
    holder
}

/// Closes `db` to the server's connections (theirs ended) and returns what
/// opens it again.
pub async fn close_db(db: &strata_tests::postgres::PgDb) -> impl FnOnce() -> Vec<String> {
    let admin_url = db.cluster().url("postgres");
    let name = db.name().to_string();
    let close = format!(
        "ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS false; \
         SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = '{name}'"
    );
    let url = admin_url.clone();
    tokio::task::spawn_blocking(move || sql_url(&url, &close))
        .await
        .unwrap();
    let open = format!("ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS true");
    move || sql_url(&admin_url, &open)
}

/// PostgreSQL for `test` (`None`: it does not run here), a data dir, and
/// a config on them checkpointing every `checkpoint_ms` (0: never).
pub fn on_postgres(
    test: &str,
    checkpoint_ms: u64,
) -> Option<(
    strata_tests::postgres::PgDb,
    tempfile::TempDir,
    ServerConfig,
)> {
    let backend = Backend::postgres(test)?;
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path());
    backend.apply(&mut cfg);
    cfg.store.checkpoint_ms = checkpoint_ms;
    let Backend::Postgres(db) = backend else {
        unreachable!("asked for PostgreSQL")
    };
    Some((db, dir, cfg))
}
