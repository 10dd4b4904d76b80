//! `strata-admin snapshot create|verify|restore|diff`.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use strata_protocol::admin::{AdminRequest, AdminResponse, SnapshotInfo, ZoneSpec};

use super::remote::{
    block_on, connect_target, data_dir_config, offline_config, open_offline_store_as, progress,
    Target, TargetArgs,
};
use super::world_source::DATA_DIR_CONFIG_NAME;
use crate::app::ZONES_BLOB;
use crate::app::{recorded_params, world_generator};
use crate::auth::ACCESS_BLOB;
use crate::config::ServerConfig;
use crate::datadir::DataDir;
use crate::engine::admin::zone_spec;
use crate::sequencer::Sequencer;
use crate::snapshot::diff::{diff, DiffReport};
use crate::snapshot::restore::import;
use crate::snapshot::{verify, SnapshotHeader, SnapshotReader, SnapshotWriter, VerifyReport};
use crate::store::{
    compare_meta, with_suffix, ChunkStore, PgStore, SledStore, StoreBackend, WorldLock, WorldMeta,
    REPLACED_SUFFIX, RESTORING_SUFFIX,
};
use crate::validate::zones::Zone;
use strata_terrain::gen::GENERATOR_VERSION;

#[derive(Debug, Subcommand)]
pub enum SnapshotCommand {
    /// Write a consistent snapshot of the world at one sequence number.
    /// Online, edits keep flowing while it runs; offline, the server must be stopped.
    Create(CreateArgs),
    /// Check every checksum and decode every chunk; names each bad record.
    Verify(VerifyArgs),
    /// Turn a snapshot into a data dir a server can start on.
    Restore(RestoreArgs),
    /// List the chunks that differ between two snapshots.
    Diff(DiffArgs),
}

#[derive(Debug, Args)]
pub struct CreateArgs {
    /// Snapshot file to write (replaced only once complete).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub target: TargetArgs,
    /// Online: abort if more chunks than this change while the snapshot
    /// runs (0: the server's default).
    #[arg(long, default_value_t = 0)]
    pub max_pending_chunks: u32,
    /// Offline: the server's config: its [store] is the one read, and its
    /// spawn protection is a world's whose zones never changed [default:
    /// the data dir's strata.toml, else the defaults].
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct VerifyArgs {
    pub file: PathBuf,
}

#[derive(Debug, Args)]
pub struct RestoreArgs {
    pub file: PathBuf,
    /// Data dir to create. Its certificate and auth secret are kept if present.
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Replace the world of a data dir (or PostgreSQL store) that already
    /// has one.
    #[arg(long)]
    pub force: bool,
    /// With --force, replace a sled world that does not open even though
    /// its bans and revocations are then lost (a restore keeps them: the
    /// snapshot holds none).
    #[arg(long)]
    pub drop_access: bool,
    /// Server config naming the store to restore into. With `[store]
    /// backend = "postgres"` the world goes into that database in one
    /// transaction (every node stopped; `--force` replaces a world there,
    /// freeing its regions) and the data dir keeps only the certificate
    /// and secret. It is also checked that its server would start on the
    /// snapshot's world [default: the data dir's strata.toml, else the
    /// data dir's world.sled with nothing checked].
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct DiffArgs {
    pub a: PathBuf,
    pub b: PathBuf,
}

/// The file header of an online snapshot the server registered.
impl From<SnapshotInfo> for SnapshotHeader {
    fn from(info: SnapshotInfo) -> Self {
        SnapshotHeader {
            seed: info.world_seed,
            generator_version: info.generator_version,
            seq: info.seq,
            generator_params: info.generator_params,
            zones: info.zones,
        }
    }
}

/// What `create` wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Created {
    pub seq: u64,
    pub chunks: u64,
    pub bytes: u64,
}

/// Creates a `.partial` file beside `out`, named for this process and
/// new (two runs writing the same `out` never share one).
fn create_partial(out: &Path) -> anyhow::Result<(PathBuf, File)> {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    super::stale_outputs::clear_for(out);
    loop {
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let tmp = with_suffix(out, &format!(".{}-{n}.partial", std::process::id()));
        match File::create_new(&tmp) {
            Ok(file) => {
                super::stale_outputs::hold(&file)
                    .with_context(|| format!("locking {}", tmp.display()))?;
                return Ok((tmp, file));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e).with_context(|| format!("creating {}", tmp.display())),
        }
    }
}

/// Writes through a `.partial` file renamed into place only on success.
pub(crate) fn write_atomically(
    out: &Path,
    f: impl FnOnce(BufWriter<File>) -> anyhow::Result<(BufWriter<File>, Created)>,
) -> anyhow::Result<Created> {
    let (tmp, file) = create_partial(out)?;
    let result = f(BufWriter::new(file)).and_then(|(w, created)| {
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        Ok((created, file))
    });
    // Held (`stale_outputs::hold`) until renamed into place or removed.
    match result {
        Ok((created, file)) => {
            let settled = settle(&tmp, out, Ok(created));
            drop(file);
            settled
        }
        Err(e) => settle(&tmp, out, Err(e)),
    }
}

/// Renames a complete (synced) `.partial` file into place and syncs its
/// directory, or removes a failed one.
fn settle(tmp: &Path, out: &Path, result: anyhow::Result<Created>) -> anyhow::Result<Created> {
    match result {
        Ok(created) => match crate::durable::rename(tmp, out) {
            Ok(()) => Ok(created),
            Err(e) => {
                // Not left beside it (`--out` a directory, say): a whole
                // snapshot's size that no later run would remove.
                let _ = std::fs::remove_file(tmp);
                Err(e).with_context(|| format!("renaming into {}", out.display()))
            }
        },
        Err(e) => {
            let _ = std::fs::remove_file(tmp);
            Err(e)
        }
    }
}

/// Snapshot of a stopped server's store. A world whose zones were never
/// changed has the default ones `cfg` gives (the spawn protection), as the
/// server would: the snapshot holds those, so its restore keeps them.
pub fn create_offline(
    store: &dyn ChunkStore,
    out: &Path,
    cfg: &ServerConfig,
) -> anyhow::Result<Created> {
    let Some(meta) = store.load_meta()? else {
        bail!("the store has no world yet (start the server once)");
    };
    let zones: Vec<Zone> = match store.get_blob(ZONES_BLOB)? {
        Some(b) => serde_json::from_slice::<Vec<Zone>>(&b)
            .context("stored protected zones do not parse")?,
        None => Sequencer::default_zones(&cfg.validation),
    };
    let zones: Vec<ZoneSpec> = zones.iter().map(zone_spec).collect();
    let header = SnapshotHeader {
        seed: meta.seed,
        generator_version: meta.generator_version,
        seq: meta.last_seq,
        generator_params: meta.generator_params,
        zones,
    };
    let bar = progress(
        Some(store.chunk_count()?),
        "snapshot {bar:40} {pos}/{len} chunks {eta}",
    );
    write_atomically(out, |file| {
        let mut w = SnapshotWriter::new(file, &header)?;
        for c in store.raw_chunks() {
            let c = c?;
            w.chunk(c.pos, c.version, &c.encoded)?;
            bar.inc(1);
        }
        // Held alone all along, or the file is not one moment.
        store.still_alone()?;
        let chunks = w.records();
        let (file, bytes) = w.finish()?;
        bar.finish_and_clear();
        Ok((
            file,
            Created {
                seq: header.seq,
                chunks,
                bytes,
            },
        ))
    })
}

/// Snapshot of a running server over the admin protocol.
/// Longest silence of the server during an online snapshot before the
/// snapshot is given up (a stalled server must not hold a backup forever).
pub const SNAPSHOT_IDLE: std::time::Duration = std::time::Duration::from_secs(120);

pub async fn create_online(
    c: &mut super::remote::AdminClient,
    out: &Path,
    max_pending_chunks: u32,
) -> anyhow::Result<Created> {
    let req = AdminRequest::Snapshot { max_pending_chunks };
    let info = match c.request(&req).await? {
        AdminResponse::SnapshotBegin(i) => i,
        AdminResponse::Refused { message } => bail!("server refused the snapshot: {message}"),
        other => bail!("unexpected answer {other:?}"),
    };
    let modified_chunks = info.modified_chunks;
    let header = SnapshotHeader::from(info);
    let bar = progress(
        Some(modified_chunks),
        "snapshot {bar:40} {pos}/{len} chunks {eta}",
    );
    let (tmp, file) = create_partial(out)?;
    let result = async {
        let mut w = SnapshotWriter::new(BufWriter::new(file), &header)?;
        loop {
            let next = tokio::time::timeout(SNAPSHOT_IDLE, c.next())
                .await
                .with_context(|| {
                    format!("the server sent nothing for {} s", SNAPSHOT_IDLE.as_secs())
                })??;
            match next {
                AdminResponse::SnapshotChunk { pos, version, data } => {
                    w.chunk(pos, version, &data)?;
                    bar.inc(1);
                }
                AdminResponse::SnapshotEnd { chunks } => {
                    if chunks != w.records() {
                        bail!("server sent {} chunks but says {chunks}", w.records());
                    }
                    break;
                }
                AdminResponse::Refused { message } => bail!("{message}"),
                other => bail!("unexpected answer {other:?}"),
            }
        }
        let chunks = w.records();
        let (file, bytes) = w.finish()?;
        file.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        anyhow::Ok(Created {
            seq: header.seq,
            chunks,
            bytes,
        })
    }
    .await;
    bar.finish_and_clear();
    settle(&tmp, out, result)
}

pub fn create(args: &CreateArgs) -> anyhow::Result<Created> {
    match args.target.target()? {
        Target::Offline(dir) => {
            // The store `--config` names, if given, as for its zones.
            let config = args.config.as_deref();
            let store = open_offline_store_as(&dir, config)?;
            // One moment of the world: no server writes it meanwhile.
            store.hold_alone()?;
            create_offline(&*store, &args.out, &offline_config(&dir, config)?)
        }
        Target::Online {
            server,
            cert,
            token,
        } => block_on(async move {
            let mut c = connect_target(server, &cert, &token).await?;
            let created = create_online(&mut c, &args.out, args.max_pending_chunks).await?;
            c.close().await;
            Ok(created)
        }),
    }
}

/// Verifies with a progress bar over the file's bytes.
pub fn verify_file(path: &Path) -> anyhow::Result<VerifyReport> {
    let len = std::fs::metadata(path)
        .with_context(|| format!("reading {}", path.display()))?
        .len();
    let bar = progress(Some(len), "verify {bar:40} {bytes}/{total_bytes} {eta}");
    let report = verify(path, |at| bar.set_position(at))?;
    bar.finish_and_clear();
    Ok(report)
}

fn is_empty_dir(dir: &Path) -> anyhow::Result<bool> {
    match std::fs::read_dir(dir) {
        Ok(mut entries) => Ok(entries.next().is_none()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(true),
        Err(e) => Err(e).with_context(|| format!("reading {}", dir.display())),
    }
}

/// Verifies the snapshot, then writes its world into the data dir. Returns
/// the chunks imported.
pub fn restore(args: &RestoreArgs) -> anyhow::Result<u64> {
    let report = verify_file(&args.file)?;
    if !report.is_ok() {
        bail!(
            "{} is corrupt, nothing restored:\n{}",
            args.file.display(),
            report.issues.join("\n")
        );
    }
    // The server's config: `--config`, else the data dir's own.
    let cfg = match &args.config {
        Some(path) => Some(
            ServerConfig::load(Some(path))
                .with_context(|| format!("loading {}", path.display()))?,
        ),
        None => {
            let found = args.data_dir.join(DATA_DIR_CONFIG_NAME);
            found
                .is_file()
                .then(|| data_dir_config(&args.data_dir))
                .transpose()?
        }
    };
    if cfg.is_none() {
        eprintln!(
            "warning: no --config and no {} in the data dir: the snapshot's world is not checked \
             against the server's config (seed, generator, store)",
            DATA_DIR_CONFIG_NAME
        );
    }
    if let Some(cfg) = &cfg {
        refuse_other_generation(&args.file, cfg)?;
        if cfg.store.backend == StoreBackend::Postgres {
            return restore_postgres(args, cfg, report.chunks);
        }
    }
    if !is_empty_dir(&args.data_dir)? && !args.force {
        bail!(
            "{} is not empty; pass --force to replace its world (its certificate and secret are kept)",
            args.data_dir.display()
        );
    }
    // A data dir with a server's files but no sled world and no config:
    // a PostgreSQL node's (its strata.toml kept elsewhere), or a sled one
    // whose restore was cut short or whose world was removed. Restored
    // all the same, with a warning (nothing tells the two apart).
    let sled_world = args.data_dir.join(crate::datadir::WORLD_DB_NAME);
    let no_world = cfg.is_none()
        && !is_empty_dir(&args.data_dir)?
        && !sled_world.exists()
        && !with_suffix(&sled_world, REPLACED_SUFFIX).exists();
    let names = cfg.as_ref().map_or(&[][..], |c| &c.tls.extra_names[..]);
    let (dd, _) = DataDir::open_or_init(&args.data_dir, names)
        .with_context(|| format!("preparing data dir {}", args.data_dir.display()))?;
    let bar = progress(
        Some(report.chunks),
        "restore {bar:40} {pos}/{len} chunks {eta}",
    );
    // The new store is made as the server's config makes one (its segment
    // size is recorded for good at creation).
    let store_cfg = cfg.as_ref().map(|c| c.store.clone()).unwrap_or_default();
    let n = replace_world(&dd.world_db_path(), &store_cfg, args.drop_access, |store| {
        Ok(import(&args.file, store, ZONES_BLOB, |n| {
            bar.set_position(n)
        })?)
    })?;
    bar.finish_and_clear();
    if no_world {
        eprintln!(
            "warning: {} held a server's files but no {}: restored there; if its server keeps \
             its world in PostgreSQL, no server reads this one: restore again with the \
             server's --config",
            args.data_dir.display(),
            crate::datadir::WORLD_DB_NAME
        );
    }
    Ok(n)
}

fn remove_dir_if_present(dir: &Path) -> anyhow::Result<()> {
    match std::fs::remove_dir_all(dir) {
        Ok(()) => Ok(crate::durable::sync_parent(dir)?),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e).with_context(|| format!("removing {}", dir.display())),
    }
}

/// fsyncs every file and directory under `dir`.
fn sync_tree(dir: &Path) -> std::io::Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        if entry.file_type()?.is_dir() {
            sync_tree(&entry.path())?;
        } else {
            File::open(entry.path())?.sync_all()?;
        }
    }
    crate::durable::sync_dir(dir)
}

/// Fills a new sled store beside `db` (`world.sled.restoring`) with
/// `fill`, makes it durable, then moves it into `db`'s place; the old
/// world is removed only once the new one is there. A failure before the
/// swap leaves `db` as it was. Holds `db`'s [`WorldLock`] throughout, so
/// it refuses a world a server or a tool has open, and neither opens one
/// half swapped. Returns what `fill` returned.
/// The bans and revocations of the world at `db`, which a restore keeps
/// (a snapshot holds none: restoring an old world must not let a banned
/// player or a revoked token back in). A world that does not open is
/// refused unless `drop_access` (restoring is how such a world is mended,
/// once the operator knows its bans go; said on stderr).
fn kept_access(db: &Path, drop_access: bool) -> anyhow::Result<Option<Vec<u8>>> {
    if !db.exists() {
        return Ok(None);
    }
    // Read as is: a failed restore leaves an older build's world one that
    // build still opens.
    match crate::store::read_blob_as_is(db, ACCESS_BLOB) {
        Ok(access) => Ok(access),
        Err(e) if drop_access => {
            eprintln!(
                "warning: the replaced world's bans and revocations are not kept ({} does not read: {e})",
                db.display()
            );
            Ok(None)
        }
        Err(e) => Err(e).with_context(|| {
            format!(
                "{} does not read, so its bans and revocations cannot be kept; nothing restored \
                 (pass --drop-access to restore without them)",
                db.display()
            )
        }),
    }
}

/// Refuses a snapshot of a world the configured server would refuse to
/// start on (another seed, generator or parameters), before anything is
/// touched.
fn refuse_other_generation(file: &Path, cfg: &ServerConfig) -> anyhow::Result<()> {
    let header = SnapshotReader::open(file)?.header().clone();
    let snapshot = WorldMeta::new(
        header.seed,
        header.generator_version,
        header.generator_params,
    );
    let (_, params) = world_generator(cfg)?;
    let configured = WorldMeta::new(
        cfg.world.generator.seed,
        GENERATOR_VERSION,
        recorded_params(params, Some(&snapshot)),
    );
    compare_meta(&snapshot, &configured).context(
        "the server's config would refuse this snapshot's world, nothing restored \
         (restore with the config the world was made with)",
    )
}

pub fn replace_world(
    db: &Path,
    store_cfg: &crate::store::StoreConfig,
    drop_access: bool,
    fill: impl FnOnce(&SledStore) -> anyhow::Result<u64>,
) -> anyhow::Result<u64> {
    let _lock = WorldLock::take(db).with_context(|| format!("{} is unchanged", db.display()))?;
    let staging = with_suffix(db, RESTORING_SUFFIX);
    let old = with_suffix(db, REPLACED_SUFFIX);
    // A swap cut short between its renames: the old world goes back first.
    if !db.exists() && old.exists() {
        crate::durable::rename(&old, db)
            .with_context(|| format!("moving {} back", old.display()))?;
    }
    remove_dir_if_present(&staging)?;
    remove_dir_if_present(&old)?;
    let access = kept_access(db, drop_access)?;
    let filled = SledStore::open_with(&staging, store_cfg)
        .map_err(anyhow::Error::from)
        .and_then(|store| {
            let n = fill(&store)?;
            if let Some(access) = &access {
                store.put_blob(ACCESS_BLOB, access)?;
            }
            drop(store);
            sync_tree(&staging)?;
            Ok(n)
        });
    let n = match filled {
        Ok(n) => n,
        Err(e) => {
            let _ = remove_dir_if_present(&staging);
            return Err(e.context(format!("{} is unchanged", db.display())));
        }
    };
    if db.exists() {
        if let Err(e) = crate::durable::rename(db, &old) {
            let _ = remove_dir_if_present(&staging);
            return Err(e).with_context(|| format!("moving {} aside", db.display()));
        }
    }
    if let Err(e) = crate::durable::rename(&staging, db) {
        let _ = crate::durable::rename(&old, db);
        return Err(e).with_context(|| format!("moving the restored world into {}", db.display()));
    }
    // Restored: the old world's copy is only left over (the next restore
    // removes it), not a failure.
    if let Err(e) = remove_dir_if_present(&old) {
        eprintln!(
            "warning: the world was restored, but removing the old one at {} failed: {e:#}",
            old.display()
        );
    }
    Ok(n)
}

/// `restore` into the PostgreSQL store `cfg` names.
fn restore_postgres(args: &RestoreArgs, cfg: &ServerConfig, total: u64) -> anyhow::Result<u64> {
    let store = PgStore::open_admin(&cfg.store.postgres, cfg.sequencer.region_chunks)
        .context("opening the PostgreSQL store")?;
    let holds = store.holds_world()?;
    if let (Some(why), false) = (&holds, args.force) {
        bail!(
            "the PostgreSQL store already holds a world ({why}); pass --force to replace it, \
             keeping its bans and revocations (stop every node first)"
        );
    }
    // One transaction: cut short, the store keeps the world it had.
    let target = store.import_in_one_transaction(args.force);
    let bar = progress(Some(total), "restore {bar:40} {pos}/{len} chunks {eta}");
    let n =
        import(&args.file, &target, ZONES_BLOB, |n| bar.set_position(n)).with_context(|| {
            if target.commit_unknown() {
                "the restore's COMMIT got no answer: the store holds either the old world or the \
                 restored one; look with `strata-admin check --data-dir DIR --config FILE`"
            } else {
                "the PostgreSQL store is unchanged"
            }
        })?;
    bar.finish_and_clear();
    // Only once restored (a refused or failed restore makes nothing): a
    // world already there was replaced with it, and a data dir without a
    // certificate and secret gets new ones (a lost node's recovery), which
    // every other node must then be given.
    let (_, made) =
        DataDir::open_or_init(&args.data_dir, &cfg.tls.extra_names).with_context(|| {
            format!(
                "the world was restored, but preparing data dir {} failed",
                args.data_dir.display()
            )
        })?;
    if made.created_anything() && holds.is_some() {
        eprintln!(
            "warning: {} had no certificate or secret; new ones were made: copy them to every \
             other node of this world ({made})",
            args.data_dir.display()
        );
    }
    Ok(n)
}

pub fn diff_files(args: &DiffArgs) -> anyhow::Result<DiffReport> {
    Ok(diff(&args.a, &args.b)?)
}

/// One line per differing chunk: `x y z a_version a_hash b_version b_hash`,
/// `-` for a chunk a side does not store.
pub fn render_diff(d: &DiffReport) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    if !d.same_world {
        out.push_str("warning: the snapshots are of different worlds (seed or generator)\n");
    }
    let _ = writeln!(
        out,
        "seq {} vs {}: {} chunks differ",
        d.seq_a,
        d.seq_b,
        d.chunks.len()
    );
    let side =
        |s: Option<(u64, u64)>| s.map_or("- -".to_string(), |(v, h)| format!("{v} {h:016x}"));
    for c in &d.chunks {
        let _ = writeln!(
            out,
            "{} {} {} {} {}",
            c.pos.x,
            c.pos.y,
            c.pos.z,
            side(c.a),
            side(c.b)
        );
    }
    out
}
