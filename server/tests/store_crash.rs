//! Crash safety: a process that commits in a loop is SIGKILLed; every seq
//! it saw acknowledged must survive, and the store must hold exactly a
//! prefix of whole batches (no torn batch, `check` clean). Chunks stored
//! before a batch go as deltas, as the server commits them, so the reopened
//! store replays deltas.
//!
//! The test re-executes its own binary as the child: when
//! [`CHILD_DIR_VAR`] is set, the same test body commits instead of
//! supervising.

use crate::store_common;

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use store_common::{terrain_chunk, Seq};
use strata_server::store::{ChunkStore, CommitBatch, SledStore, WorldMeta};
use strata_terrain::{Chunk, ChunkPos};

const CHILD_DIR_VAR: &str = "STRATA_STORE_CRASH_CHILD_DIR";
/// The test's name in the integration binary (the child runs it alone).
const TEST_NAME: &str = "store_crash::acknowledged_commits_survive_sigkill";
/// How long the child commits before it is killed.
const RUN_FOR: Duration = Duration::from_millis(1000);
/// The child stops by itself after this many batches if never killed.
const CHILD_MAX_BATCHES: u64 = 50_000;
const MARK: &str = "COMMITTED ";

/// Batch `k` of the deterministic workload: 1 to 3 edits over 6 chunks,
/// dense and uniform states mixed.
fn workload_batch(seq: &mut Seq, k: u64) -> CommitBatch {
    let pos = |i: u64| ChunkPos::new((i % 3) as i32 - 1, -((i % 2) as i32), (i % 6) as i32 * -7);
    let edits: Vec<Vec<(ChunkPos, Chunk)>> = (0..1 + k % 3)
        .map(|e| {
            let a = pos(k + e);
            let b = pos(k + e + 2);
            let state = |salt: u64| {
                if salt % 4 == 0 {
                    Chunk::default()
                } else {
                    terrain_chunk(salt as u32)
                }
            };
            vec![(a, state(k * 7 + e)), (b, state(k * 11 + e + 1))]
        })
        .collect();
    seq.delta_batch(&edits)
}

fn run_child(dir: &Path) {
    let store = SledStore::open(dir).unwrap();
    store.init_meta(&WorldMeta::new(77, 1, "")).unwrap();
    let mut seq = Seq::default();
    let out = std::io::stdout();
    for k in 0..CHILD_MAX_BATCHES {
        let b = workload_batch(&mut seq, k);
        store.commit_batch(&b).unwrap();
        // Acknowledge only after commit_batch returned (durable).
        let mut o = out.lock();
        writeln!(o, "{MARK}{}", b.last_seq).unwrap();
        o.flush().unwrap();
    }
}

#[test]
fn acknowledged_commits_survive_sigkill() {
    if let Some(dir) = std::env::var_os(CHILD_DIR_VAR) {
        return run_child(Path::new(&dir));
    }
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([TEST_NAME, "--exact", "--nocapture", "--test-threads", "1"])
        .env(CHILD_DIR_VAR, dir.path())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let acked = Arc::new(Mutex::new(Vec::<u64>::new()));
    let reader = {
        let acked = Arc::clone(&acked);
        let stdout = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Some(s) = line.strip_prefix(MARK) {
                    acked.lock().unwrap().push(s.trim().parse().unwrap());
                }
            }
        })
    };
    let start = Instant::now();
    while start.elapsed() < RUN_FOR {
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL on Unix: no destructors, no flush.
    child.wait().unwrap();
    reader.join().unwrap();
    let acked = acked.lock().unwrap().clone();
    assert!(
        acked.len() >= 3,
        "child acknowledged only {} batches",
        acked.len()
    );
    let max_acked = *acked.last().unwrap();

    let store = SledStore::open(dir.path()).unwrap();
    let last = store.last_seq().unwrap();
    assert!(
        last >= max_acked,
        "store ends at seq {last}, child acked {max_acked}"
    );
    for &s in &acked {
        assert!(store.log_entry(s).unwrap().is_some(), "acked seq {s} lost");
    }
    // Replay the workload to the store's last_seq: the store must hold
    // exactly that prefix of whole batches.
    let mut seq = Seq::default();
    let mut entries = Vec::new();
    let mut k = 0;
    while seq.last_seq < last {
        let b = workload_batch(&mut seq, k);
        entries.extend(b.entries);
        k += 1;
    }
    // Whole states and deltas alike: each chunk as the prefix leaves it.
    let expected: std::collections::BTreeMap<_, _> = seq
        .versions
        .iter()
        .map(|(p, v)| (*p, (*v, seq.states[p].clone())))
        .collect();
    assert_eq!(seq.last_seq, last, "store ends inside batch {k}");
    let log: Vec<_> = store
        .edit_log(1..=u64::MAX)
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(log, entries);
    for (p, (v, c)) in &expected {
        let got = store.load_chunk(*p).unwrap().unwrap();
        assert_eq!((got.version, &got.chunk), (*v, c), "chunk {p:?}");
    }
    assert_eq!(store.chunk_count().unwrap(), expected.len() as u64);
    let report = store.check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    eprintln!(
        "crash test: {} batches acked, store at seq {last}",
        acked.len()
    );
}
