//! The edit pipeline in process: the engine thread with its sequencer,
//! worker pool and real sled store in a temp dir; no QUIC. Sessions are
//! the engine's own bounded queues, drained by one thread.
//!
//! `SPOTS` places far apart (one region each), each with one editor and
//! `WATCHERS` watchers subscribed around it, so every chunk an edit changes
//! is watched by `WATCHERS` sessions. Editors keep `IN_FLIGHT` edits
//! (mine and build, radius 4, alternating, so each one changes voxels)
//! queued, as fast as the engine takes them. For each worker count it
//! prints durable (acknowledged) edits/s, deltas queued to sessions per
//! second, and CPU ms of this process per edit.
//!
//! `cargo bench -p strata-server --bench pipeline` (1, 2, 4 and 8 workers)
//! or `... -- 1 2` for chosen counts; `STRATA_BENCH_SECONDS` sets the
//! measured time per count (default 6), `STRATA_BENCH_EDITS_PER_TICK` the
//! sequencer's `max_edits_per_tick` (default the server's, 256: with 10 ms
//! ticks a ceiling of 25,600 edits/s, which 2 workers reach on a fast
//! 2-core box), `STRATA_BENCH_IN_FLIGHT` the edits in flight (default 768,
//! or three ticks' worth if more; the sequencer's queue holds them all,
//! so that none is refused `Busy` and sent again). "ahead" is the share of batches applied while
//! the batch before them committed. The last columns split the time per
//! batch into the engine's phases (apply: the region lanes; commit:
//! encode, write, fsync, and any batch applied ahead meanwhile; mesh
//! wait: the tick's collision meshes still building; finish: the meshes
//! and hashes put in and the acks sent, on the engine thread; fanout: the
//! deltas, on the workers). The next splits each apply (wait for a
//! worker, prepare, the lanes in parallel, merge). The last column splits the process's CPU per edit
//! by thread: the workers, the engine thread, the commit thread, and the
//! rest (the bench's drain and feed, sled, the checkpointer), so that what
//! does not grow with the workers shows.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use bytes::Bytes;
use strata_protocol::{EditRequest, PositionUpdate, Role};
use strata_server::engine::{
    Command, Engine, EngineConfig, EngineHandle, LatestPosition, StreamPolicy,
};
use strata_server::interest::InterestConfig;
use strata_server::net::writer::FrameSender;
use strata_server::sequencer::{Sequencer, SequencerConfig, DEFAULT_QUEUE_CAPACITY};
use strata_server::store::{ChunkStore, SledStore, WorldMeta, STORE_FORMAT_VERSION};
use strata_server::validate::bounds::WorldBounds;
use strata_server::validate::ratelimit::BucketConfig;
use strata_server::validate::ValidationConfig;
use strata_terrain::edit::StructureLibrary;
use strata_terrain::material::ids;
use strata_terrain::world::FlatGenerator;
use strata_terrain::{ChunkPos, Edit, Fixed, FixedVec3, MaterialTable, Voxel, World};
use tokio::sync::mpsc::Receiver;

/// The server's allocator, so that the CPU per edit here is the server's.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

const SPOTS: i32 = 16;
const WATCHERS: usize = 50;
/// Edits sent but not yet acknowledged or refused, at most.
const IN_FLIGHT: u64 = 768;
const WARMUP: Duration = Duration::from_secs(2);
/// Each session's update queue, as `[net] writer_queue`'s default.
const SESSION_QUEUE: usize = 1024;

fn main() -> anyhow::Result<()> {
    let metrics = strata_server::metrics::install()?;
    let mut counts: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    if counts.is_empty() {
        counts = vec![1, 2, 4, 8];
    }
    let seconds: u64 = std::env::var("STRATA_BENCH_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(6);
    println!(
        "pipeline: {SPOTS} spots x ({WATCHERS} watchers + 1 editor), {seconds} s each, {} cores, at most {} edits a tick",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        edits_per_tick()
    );
    println!(
        "| workers | durable edits/s | deltas/s | deltas/edit | CPU ms/edit | lanes/tick | edits/tick | ahead | tick ms | apply / commit / mesh wait / finish / fanout ms | apply: wait / prepare / lanes / merge ms | CPU µs/edit: workers / engine / commit / rest |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    for workers in counts {
        let r = run(workers, Duration::from_secs(seconds), &metrics)?;
        let per_tick = |ms: f64| ms / r.ticks.max(1.0);
        println!(
            "| {workers} | {:.0} | {:.0} | {:.1} | {:.3} | {:.1} | {:.0} | {:.2} | {:.1} | {:.1} / {:.1} / {:.1} / {:.1} / {:.1} | {} | {} |",
            r.edits / r.secs,
            r.deltas / r.secs,
            r.deltas / r.edits.max(1.0),
            r.cpu_ms / r.edits.max(1.0),
            r.lanes,
            r.edits / r.ticks.max(1.0),
            r.ahead / r.ticks.max(1.0),
            per_tick(r.phase_ms[0]),
            per_tick(r.phase_ms[1]),
            per_tick(r.phase_ms[2]),
            per_tick(r.phase_ms[3]),
            per_tick(r.phase_ms[4]),
            per_tick(r.phase_ms[5]),
            r.apply_ms
                .map(|ms| format!("{:.1}", ms / r.applies.max(1.0)))
                .join(" / "),
            r.by_thread
                .map(|s| format!("{:.1}", s * 1e6 / r.edits.max(1.0)))
                .join(" / "),
        );
        if r.dropped > 0.0 {
            println!(
                "  ({workers} workers: {:.0} deltas dropped, their session queues full)",
                r.dropped
            );
        }
        if r.refused > 0.0 {
            println!(
                "  ({workers} workers: {:.0} edits refused, which the figures above pay for)",
                r.refused
            );
        }
    }
    Ok(())
}

/// Edits in flight: `STRATA_BENCH_IN_FLIGHT`, or [`IN_FLIGHT`] or three
/// ticks' worth if more.
fn in_flight() -> u64 {
    std::env::var("STRATA_BENCH_IN_FLIGHT")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(IN_FLIGHT.max(3 * edits_per_tick() as u64))
}

/// The sequencer's `max_edits_per_tick` for the runs.
fn edits_per_tick() -> usize {
    std::env::var("STRATA_BENCH_EDITS_PER_TICK")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(strata_server::sequencer::DEFAULT_MAX_EDITS_PER_TICK)
}

struct Result {
    edits: f64,
    /// Edits refused (any reason): each one is engine and feed work that
    /// no durable edit shows for.
    refused: f64,
    /// Deltas a full session queue lost (the drain fell behind).
    dropped: f64,
    deltas: f64,
    secs: f64,
    cpu_ms: f64,
    lanes: f64,
    /// Batches that committed edits.
    ticks: f64,
    /// Of them, applied while the one before committed.
    ahead: f64,
    /// Whole tick, apply, commit, mesh wait, finish, fanout: ms summed over `ticks`.
    phase_ms: [f64; 6],
    /// Each apply's wait, prepare, lanes and merge: ms summed over `applies`.
    apply_ms: [f64; 4],
    applies: f64,
    /// CPU seconds of the workers, the engine, the commit thread and the
    /// rest of the process.
    by_thread: [f64; 4],
}

/// One session's end of the engine's queues.
struct Session {
    id: u64,
    spot: (i32, i32),
}

fn run(
    workers: usize,
    measure: Duration,
    metrics: &metrics_exporter_prometheus::PrometheusHandle,
) -> anyhow::Result<Result> {
    let tmp = tempfile::tempdir()?;
    let store: Arc<dyn ChunkStore> = Arc::new(SledStore::open(&tmp.path().join("world.sled"))?);
    store.init_meta(&WorldMeta {
        format_version: STORE_FORMAT_VERSION,
        seed: 0,
        generator_version: 0,
        generator_params: "flat stone below y = 0".into(),
        last_seq: 0,
    })?;
    let lots = BucketConfig {
        capacity: 1 << 40,
        per_second: 0,
    };
    let validation = ValidationConfig {
        edit_rate: lots,
        volume_rate: lots,
        ..Default::default()
    };
    let generator = Arc::new(FlatGenerator {
        ground: Voxel::solid(ids::STONE),
    });
    // As the server does: new chunks are stored from generated.
    store.attach_generator(generator.clone());
    let world = World::new(generator);
    let seq = Sequencer::new(
        world,
        SequencerConfig {
            max_edits_per_tick: edits_per_tick(),
            // Room for every edit in flight: a refusal (`Busy`) would be
            // answered at once and the edit sent again, work no server
            // does at its queue's bound for long.
            queue_capacity: DEFAULT_QUEUE_CAPACITY.max(in_flight() as usize),
            ..SequencerConfig::default()
        },
        validation.clone(),
        0,
        MaterialTable::default(),
        StructureLibrary::default(),
        Vec::new(),
    );
    let engine = Engine::new(
        seq,
        store,
        EngineConfig {
            workers,
            ..Default::default()
        },
        StreamPolicy {
            send_budget: 1 << 20,
            regenerable: true,
        },
        InterestConfig::default(),
        WorldBounds::default(),
        Default::default(),
    )?;
    let (engine, thread) = engine.spawn(|| {})?;

    let mut queues: Vec<(Receiver<Bytes>, bool)> = Vec::new();
    let mut kicks = Vec::new();
    let mut editors = Vec::new();
    let mut next_id = 1;
    for s in 0..SPOTS {
        // 512 voxels apart: two 8-chunk regions.
        let spot = ((s % 4) * 512 + 100, (s / 4) * 512 + 100);
        for w in 0..=WATCHERS {
            let id = next_id;
            next_id += 1;
            let session = join(&engine, id, spot, w == 0, &mut queues, &mut kicks)?;
            if w == 0 {
                editors.push(session);
            }
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    let verdicts = Arc::new(AtomicU64::new(0));
    let drain = {
        let (stop, verdicts) = (stop.clone(), verdicts.clone());
        std::thread::spawn(move || drain(queues, &stop, &verdicts))
    };

    let in_flight = in_flight();
    let mut sent = 0u64;
    let mut feed = |until: Instant| {
        while Instant::now() < until {
            let done = verdicts.load(Ordering::Relaxed);
            while sent < done + in_flight {
                let e = &editors[(sent % editors.len() as u64) as usize];
                if !engine.try_send(Command::Edit {
                    session: e.id,
                    request: edit(e.spot, sent),
                    received: Instant::now(),
                }) {
                    break;
                }
                sent += 1;
            }
            std::thread::sleep(Duration::from_micros(500));
        }
    };
    feed(Instant::now() + WARMUP);
    let before = Counters::read(metrics);
    let started = Instant::now();
    feed(started + measure);
    let after = Counters::read(metrics);
    let secs = started.elapsed().as_secs_f64();

    engine.stop();
    thread
        .join()
        .map_err(|_| anyhow::anyhow!("engine panicked"))??;
    stop.store(true, Ordering::Relaxed);
    drain
        .join()
        .map_err(|_| anyhow::anyhow!("drain panicked"))?;
    drop(kicks);
    Ok(Result {
        edits: after.accepted - before.accepted,
        refused: after.refused - before.refused,
        dropped: after.dropped - before.dropped,
        deltas: after.deltas - before.deltas,
        secs,
        cpu_ms: (after.cpu - before.cpu) * 1e3,
        lanes: (after.lanes_sum - before.lanes_sum)
            / (after.lanes_count - before.lanes_count).max(1.0),
        ticks: after.lanes_count - before.lanes_count,
        ahead: after.ahead - before.ahead,
        phase_ms: std::array::from_fn(|i| (after.phases[i] - before.phases[i]) * 1e3),
        apply_ms: std::array::from_fn(|i| (after.apply_parts[i] - before.apply_parts[i]) * 1e3),
        applies: after.applies - before.applies,
        by_thread: std::array::from_fn(|i| after.threads[i] - before.threads[i]),
    })
}

/// Joins a session at `spot`: an editor stands there, a watcher subscribes
/// around the chunk its edits change.
fn join(
    engine: &EngineHandle,
    id: u64,
    spot: (i32, i32),
    editor: bool,
    queues: &mut Vec<(Receiver<Bytes>, bool)>,
    kicks: &mut Vec<tokio::sync::oneshot::Receiver<strata_server::engine::Kick>>,
) -> anyhow::Result<Session> {
    let (control, control_rx) = FrameSender::channel(SESSION_QUEUE);
    let (updates, updates_rx) = FrameSender::channel(SESSION_QUEUE);
    // An editor's control queue carries only its edits' verdicts.
    queues.extend([(control_rx, editor), (updates_rx, false)]);
    let (reply, reply_rx) = tokio::sync::oneshot::channel();
    let (kick, kick_rx) = tokio::sync::oneshot::channel();
    kicks.push(kick_rx);
    let position = Arc::new(LatestPosition::default());
    send(
        engine,
        Command::Join {
            session: id,
            player: format!("{}{id}", if editor { "e" } else { "w" }),
            role: Role::Player,
            control,
            updates,
            reply,
            kick,
            position: position.clone(),
            capabilities: 0,
            stored: None,
        },
    );
    reply_rx.blocking_recv()?;
    if editor {
        position.offer(PositionUpdate {
            seq: 1,
            pos: FixedVec3::from_voxels(spot.0, 0, spot.1),
        });
        send(engine, Command::Position { session: id });
    } else {
        send(
            engine,
            Command::Subscribe {
                session: id,
                center: ChunkPos::new(spot.0.div_euclid(32), 0, (spot.1 + 5).div_euclid(32)),
                radius: 1,
            },
        );
    }
    Ok(Session { id, spot })
}

fn send(engine: &EngineHandle, mut cmd: Command) {
    loop {
        match engine.offer(cmd) {
            Ok(()) => return,
            Err(std::sync::mpsc::TrySendError::Full(back)) => cmd = back,
            Err(e) => panic!("engine gone: {e}"),
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Mine and build in turn at one place in front of the editor.
fn edit(spot: (i32, i32), n: u64) -> EditRequest {
    let center = FixedVec3::from_voxels(spot.0, 0, spot.1 + 5);
    let radius = Fixed::from_voxels(4);
    let edit = if (n / SPOTS as u64) % 2 == 0 {
        Edit::Mine {
            center,
            radius,
            strength: 255,
        }
    } else {
        Edit::Build {
            center,
            radius,
            material: ids::DIRT,
            strength: 255,
        }
    };
    EditRequest {
        client_edit_id: n,
        edit,
    }
}

/// Drain rounds (1 ms apart) between two polls of the update queues: a
/// session gets at most one frame batch a tick (10 ms or more), and its
/// queue holds [`SESSION_QUEUE`].
const UPDATE_POLL_ROUNDS: u64 = 5;

/// Empties every session queue until `stop`, counting the frames of
/// queues marked as verdicts.
fn drain(mut queues: Vec<(Receiver<Bytes>, bool)>, stop: &AtomicBool, verdicts: &AtomicU64) {
    let mut round = 0u64;
    while !stop.load(Ordering::Relaxed) {
        round += 1;
        for (q, counted) in &mut queues {
            // Verdicts every millisecond (the feed waits on them), updates
            // every `UPDATE_POLL_ROUNDS`: polling all of them each round
            // cost this thread a sixth of a core, which on a 2-core box
            // the workers paid for.
            if !*counted && round % UPDATE_POLL_ROUNDS != 0 {
                continue;
            }
            let mut n = 0;
            while q.try_recv().is_ok() {
                n += 1;
            }
            if *counted && n > 0 {
                verdicts.fetch_add(n, Ordering::Relaxed);
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

struct Counters {
    accepted: f64,
    refused: f64,
    dropped: f64,
    deltas: f64,
    cpu: f64,
    lanes_sum: f64,
    lanes_count: f64,
    ahead: f64,
    phases: [f64; 6],
    apply_parts: [f64; 4],
    /// Applies with edits (each batch, ahead or not).
    applies: f64,
    threads: [f64; 4],
}

/// Series summed into [`Counters::phases`].
const PHASES: [&str; 6] = [
    "strata_tick_seconds_sum",
    "strata_tick_phase_seconds_sum{phase=\"apply\"}",
    "strata_tick_phase_seconds_sum{phase=\"commit\"}",
    "strata_tick_phase_seconds_sum{phase=\"mesh_wait\"}",
    "strata_tick_phase_seconds_sum{phase=\"finish\"}",
    "strata_tick_phase_seconds_sum{phase=\"fanout\"}",
];

/// Series summed into [`Counters::apply_parts`].
const APPLY_PARTS: [&str; 4] = [
    "strata_apply_part_seconds_sum{part=\"wait\"}",
    "strata_apply_part_seconds_sum{part=\"prepare\"}",
    "strata_apply_part_seconds_sum{part=\"lanes\"}",
    "strata_apply_part_seconds_sum{part=\"merge\"}",
];

impl Counters {
    fn read(m: &metrics_exporter_prometheus::PrometheusHandle) -> Self {
        Counters {
            accepted: counter(m, "strata_edits_accepted_total"),
            refused: counter(m, "strata_edits_rejected_total"),
            dropped: counter(m, "strata_deltas_dropped_total"),
            deltas: counter(m, "strata_deltas_sent_total"),
            cpu: process_cpu_seconds(),
            lanes_sum: counter(m, "strata_tick_lanes_sum"),
            lanes_count: counter(m, "strata_tick_lanes_count"),
            ahead: counter(m, "strata_ticks_applied_ahead_total"),
            phases: PHASES.map(|p| counter(m, p)),
            apply_parts: APPLY_PARTS.map(|p| counter(m, p)),
            applies: counter(m, "strata_apply_part_seconds_count{part=\"lanes\"}"),
            threads: threads_cpu_seconds(),
        }
    }
}

/// The sum of every series of `name` in the Prometheus text.
fn counter(m: &metrics_exporter_prometheus::PrometheusHandle, name: &str) -> f64 {
    m.render()
        .lines()
        .filter(|l| {
            l.strip_prefix(name).is_some_and(|rest| {
                rest.starts_with(' ') || (rest.starts_with('{') && !name.ends_with('}'))
            })
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

/// User plus system CPU seconds of this process, all threads.
fn process_cpu_seconds() -> f64 {
    cpu_seconds(&std::fs::read_to_string("/proc/self/stat").unwrap_or_default())
}

/// CPU seconds of the live threads: workers, engine, commit, the rest.
/// (Each measured run's threads live through both readings.)
fn threads_cpu_seconds() -> [f64; 4] {
    let mut by = [0.0; 4];
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return by;
    };
    for task in tasks.flatten() {
        let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
        let name = stat
            .split_once('(')
            .and_then(|(_, r)| r.rsplit_once(')'))
            .map_or("", |(n, _)| n);
        let group = match name {
            n if n.starts_with("strata-worker") => 0,
            "strata-engine" => 1,
            "strata-commit" => 2,
            _ => 3,
        };
        by[group] += cpu_seconds(&stat);
    }
    by
}

/// User plus system CPU seconds from a `stat` line of `/proc`.
fn cpu_seconds(stat: &str) -> f64 {
    // Fields after the command name (which may hold spaces) start at ')'.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    // utime and stime: fields 14 and 15 of the line, 11 and 12 after ')'.
    (ticks(11) + ticks(12)) / 100.0
}
