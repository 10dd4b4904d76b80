//! Region leases and fenced commits on a real PostgreSQL: claims and
//! renewals, takeover of an expired lease with a new epoch, commits with
//! a stale epoch refused and changing nothing, and nodes racing.

use crate::store_common;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Barrier};
use std::time::Duration;

use store_common::{sql, terrain_chunk, Seq};
use strata_server::cluster::ClusterConfig;
use strata_server::cluster::DEFAULT_SEQ_BLOCK as SEQ_BLOCK;
use strata_server::sequencer::regions::{RegionId, DEFAULT_REGION_CHUNKS};
use strata_server::store::pg::PgConfig;
use strata_server::store::{
    ChunkStore, CommitBatch, LogCursor, PgStore, RegionAccess, SegmentsAlso, StoreError, WorldMeta,
};
use strata_terrain::ChunkPos;
use strata_tests::postgres::{database, PgDb};

const SIDE: i32 = DEFAULT_REGION_CHUNKS as i32;

/// A node on `db` named `id`, leases of `lease_ms` renewed every `renew_ms`.
fn node_with(db: &PgDb, id: &str, lease_ms: u64, renew_ms: u64) -> PgStore {
    open_node(
        db,
        &ClusterConfig {
            node_id: id.into(),
            lease_ms,
            renew_ms,
            // Adoption is tested on its own (`adopt_regions`).
            adopt: false,
            ..ClusterConfig::default()
        },
    )
}

/// A node on `db` with these settings, the world's metadata written.
fn open_node(db: &PgDb, cluster: &ClusterConfig) -> PgStore {
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let store = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, cluster).unwrap();
    store.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
    store.register_node().unwrap();
    store
}

/// A node with a long lease: only the tests expire it.
fn node(db: &PgDb, id: &str) -> PgStore {
    node_with(db, id, 60_000, 10_000)
}

/// `store` may write region `r` (claiming it if free).
fn granted(store: &PgStore, r: RegionId) {
    assert_eq!(
        store.acquire_regions(&regions(&[r])).unwrap(),
        RegionAccess::Granted,
        "{r:?}"
    );
}

fn region(x: i32, z: i32) -> RegionId {
    RegionId { x, z }
}

/// A chunk of region `r`.
fn chunk_in(r: RegionId, y: i32) -> ChunkPos {
    ChunkPos::new(r.x * SIDE, y, r.z * SIDE)
}

/// Runs the lease of `r` out, as if its owner stopped renewing long ago.
fn expire(db: &PgDb, r: RegionId) {
    sql(
        db,
        &format!(
            "UPDATE regions SET lease_expires = now() - interval '1 second' \
             WHERE region_x = {} AND region_z = {}",
            r.x, r.z
        ),
    );
}

/// A copy of the sequencer state, to build a batch that may be refused.
fn fork(s: &Seq) -> Seq {
    Seq {
        last_seq: s.last_seq,
        versions: s.versions.clone(),
        states: s.states.clone(),
    }
}

/// What a refused commit must leave as it was.
#[derive(Debug, PartialEq)]
struct Footprint {
    last_seq: u64,
    log: Vec<String>,
    chunks: Vec<String>,
    deltas: Vec<String>,
}

fn footprint(db: &PgDb, store: &PgStore) -> Footprint {
    Footprint {
        last_seq: store.last_seq().unwrap(),
        log: sql(db, "SELECT seq FROM edit_log ORDER BY seq"),
        chunks: sql(
            db,
            "SELECT x || ',' || y || ',' || z || '@' || version || ':' || md5(body) \
             FROM chunks ORDER BY x, y, z",
        ),
        deltas: sql(
            db,
            "SELECT x || ',' || y || ',' || z || '@' || to_version FROM chunk_deltas \
             ORDER BY x, y, z, to_version",
        ),
    }
}

fn edit(seq: &mut Seq, chunks: &[ChunkPos], salt: u32) -> CommitBatch {
    let changes = chunks.iter().map(|&p| (p, terrain_chunk(salt))).collect();
    seq.delta_batch(&[changes])
}

fn fenced(err: StoreError) -> (RegionId, Option<u64>, Option<u64>, Option<String>) {
    match err {
        StoreError::Fenced {
            region,
            held_epoch,
            current_epoch,
            owner,
        } => (region, held_epoch, current_epoch, owner),
        other => panic!("expected Fenced, got {other}"),
    }
}

#[test]
fn claims_are_exclusive_and_renewals_extend_the_lease() {
    let Some(db) = database("lease_claims") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let (r0, r1) = (region(0, 0), region(-1, 3));
    let got = a.claim_regions(&[r0, r1]).unwrap();
    assert_eq!(got, BTreeMap::from([(r0, 1), (r1, 1)]));
    // Held live by a: b gets nothing, and a's claim again changes nothing.
    assert!(b.claim_regions(&[r0, r1]).unwrap().is_empty());
    assert_eq!(a.claim_regions(&[r0]).unwrap(), BTreeMap::from([(r0, 1)]));
    let expiry = "SELECT lease_expires FROM regions WHERE region_x = 0 AND region_z = 0";
    let before = sql(&db, expiry);
    std::thread::sleep(Duration::from_millis(20));
    assert!(a.renew_leases().unwrap().is_empty());
    assert!(sql(&db, expiry) > before, "the renewal moved the expiry on");
    assert_eq!(
        sql(
            &db,
            "SELECT owner || ' ' || epoch FROM regions ORDER BY region_x"
        ),
        ["a 1", "a 1"]
    );
    let leases = a.leases().unwrap();
    assert_eq!(leases.node_id(), "a");
    assert_eq!(leases.held(), BTreeMap::from([(r0, 1), (r1, 1)]));
    assert!(leases.lost().is_empty());
}

/// A commit holding one region's row (slow: a stalled disk, say) does not
/// hold up the renewal of the node's other regions, nor make the renewal
/// count the held one lost; the commit renews what it holds itself.
#[test]
fn a_slow_commit_holds_up_no_other_regions_renewal() {
    let Some(db) = database("lease_renew_beside_commit") else {
        return;
    };
    let a = node(&db, "a");
    let (r0, r1) = (region(0, 0), region(1, 0));
    let mut world = Seq::default();
    a.commit_batch(&edit(&mut world, &[chunk_in(r0, 0), chunk_in(r1, 0)], 1))
        .unwrap();
    let expiry = |r: RegionId| {
        sql(
            &db,
            &format!(
                "SELECT lease_expires FROM regions WHERE region_x = {} AND region_z = {}",
                r.x, r.z
            ),
        )
    };
    let before = (expiry(r0), expiry(r1));
    // As a commit of a's stuck inside its transaction holds it.
    let (release, holder) = store_common::hold_until_told(
        &db,
        "SELECT 1 FROM regions WHERE region_x = 0 AND region_z = 0 FOR UPDATE",
    );
    std::thread::sleep(Duration::from_millis(20));
    let started = std::time::Instant::now();
    assert!(a.renew_leases().unwrap().is_empty(), "nothing lost");
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "the renewal waited {:?}",
        started.elapsed()
    );
    assert!(expiry(r1) > before.1, "the other region was renewed");
    assert_eq!(expiry(r0), before.0, "the held one was skipped");
    assert_eq!(a.leases().unwrap().held().len(), 2);
    release.send(()).unwrap();
    holder.join().unwrap();
    // A commit renews the regions it fences.
    std::thread::sleep(Duration::from_millis(20));
    a.commit_batch(&edit(&mut world, &[chunk_in(r0, 0)], 2))
        .unwrap();
    assert!(expiry(r0) > before.0, "the commit renewed its region");
}

#[test]
fn an_expired_lease_goes_to_the_next_claimer_and_fences_the_old_owner() {
    let Some(db) = database("lease_takeover") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let r = region(2, -1);
    let pos = chunk_in(r, 0);
    let mut world = Seq::default();
    // a's first write claims the region.
    a.commit_batch(&edit(&mut world, &[pos], 1)).unwrap();
    a.commit_batch(&edit(&mut world, &[pos], 2)).unwrap();
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(r, 1)]));
    expire(&db, r);
    assert_eq!(b.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));

    // a wakes up with epoch 1: its batch is refused whole.
    let before = footprint(&db, &a);
    let err = a
        .commit_batch(&edit(&mut fork(&world), &[pos], 3))
        .unwrap_err();
    assert_eq!(fenced(err), (r, Some(1), Some(2), Some("b".into())));
    assert_eq!(footprint(&db, &a), before);
    assert!(a.leases().unwrap().held().is_empty());
    assert_eq!(a.leases().unwrap().lost(), BTreeMap::from([(r, 1)]));

    // b writes on from what is stored.
    b.commit_batch(&edit(&mut world, &[pos], 4)).unwrap();
    assert_eq!(b.load_chunk(pos).unwrap().unwrap().version, 3);
    // Lost for good: even once b lets go, a does not take the region back.
    assert_eq!(b.release_leases().unwrap(), 1);
    let before = footprint(&db, &a);
    let err = a
        .commit_batch(&edit(&mut fork(&world), &[pos], 5))
        .unwrap_err();
    assert_eq!(fenced(err), (r, Some(1), Some(2), None));
    assert_eq!(footprint(&db, &a), before);
}

/// `edit` as the engine builds it: under epoch `epoch` of `r`.
fn built_under(mut batch: CommitBatch, r: RegionId, epoch: u64) -> CommitBatch {
    batch.epochs = Some(BTreeMap::from([(r, epoch)]));
    batch
}

/// The engine takes a lost region back once no node holds it: reported
/// fresh with its new epoch (the engine reloads it). A batch built under
/// the old epoch is refused and leaves the new lease held; one built under
/// the new epoch commits.
#[test]
fn a_lost_region_is_taken_back_on_request_and_older_batches_are_fenced() {
    let Some(db) = database("lease_retake") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let r = region(4, -4);
    let pos = chunk_in(r, 0);
    let mut world = Seq::default();
    let mine = regions(&[r]);
    assert_eq!(a.acquire_regions(&mine).unwrap(), RegionAccess::Granted);
    assert_eq!(a.take_fresh_regions(), [(r, Some(1))]);
    a.commit_batch(&built_under(edit(&mut world, &[pos], 1), r, 1))
        .unwrap();
    expire(&db, r);
    assert_eq!(b.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));
    b.commit_batch(&edit(&mut world, &[pos], 2)).unwrap();
    let err = a
        .commit_batch(&built_under(edit(&mut fork(&world), &[pos], 3), r, 1))
        .unwrap_err();
    assert_eq!(fenced(err), (r, Some(1), Some(2), Some("b".into())));
    assert_eq!(a.leases().unwrap().lost(), BTreeMap::from([(r, 1)]));

    assert_eq!(b.release_leases().unwrap(), 1);
    assert_eq!(a.acquire_regions(&mine).unwrap(), RegionAccess::Granted);
    assert_eq!(a.take_fresh_regions(), [(r, Some(3))]);
    assert!(a.leases().unwrap().lost().is_empty());
    // Built on the copy from before the reload: refused, the lease kept.
    let before = footprint(&db, &a);
    let err = a
        .commit_batch(&built_under(edit(&mut fork(&world), &[pos], 4), r, 1))
        .unwrap_err();
    assert_eq!(fenced(err), (r, Some(1), Some(3), Some("a".into())));
    assert_eq!(footprint(&db, &a), before);
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(r, 3)]));
    // Built on the reloaded copy: written.
    a.commit_batch(&built_under(edit(&mut world, &[pos], 5), r, 3))
        .unwrap();
    assert_eq!(a.load_chunk(pos).unwrap().unwrap().version, 3);
}

/// `max_held_regions`: an edit that would claim past it is refused, and
/// past half of it the renewal thread lets go of the regions no edit asked
/// for in a whole lease, least recently used first, down to half.
#[test]
fn a_node_holds_at_most_max_held_regions_and_lets_idle_ones_go() {
    let Some(db) = database("lease_max_held") else {
        return;
    };
    let cluster = ClusterConfig {
        node_id: "a".into(),
        lease_ms: 400,
        renew_ms: 100,
        adopt: false,
        max_held_regions: 4,
        ..ClusterConfig::default()
    };
    let a = open_node(&db, &cluster);
    let rs: Vec<RegionId> = (0..5).map(|i| region(i, 0)).collect();
    for r in &rs[..4] {
        granted(&a, *r);
    }
    assert_eq!(
        a.acquire_regions(&regions(&[rs[4]])).unwrap(),
        RegionAccess::AtCapacity { held: 4, max: 4 }
    );
    assert_eq!(
        a.region_leases().unwrap().len(),
        4,
        "nothing claimed past it"
    );
    // At the cap, a region another node holds is still named: the edit
    // belongs there, not on some node with room.
    let b = open_node(
        &db,
        &ClusterConfig {
            node_id: "b".into(),
            ..cluster.clone()
        },
    );
    let theirs = region(9, 0);
    granted(&b, theirs);
    let named = a.acquire_regions(&regions(&[rs[4], theirs])).unwrap();
    assert!(
        matches!(&named, RegionAccess::Elsewhere { region, owner, .. }
            if *region == theirs && owner == "b"),
        "{named:?}"
    );
    b.close().unwrap();
    // rs[0] stays in use; the others idle past a lease. The book lets
    // them go before the rows do (b let go of its region as it closed).
    let free = || -> Vec<RegionId> {
        a.region_leases()
            .unwrap()
            .into_iter()
            .filter(|l| l.owner.is_none() && l.region != theirs)
            .map(|l| l.region)
            .collect()
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while a.leases().unwrap().held().len() > 2 || free().len() < 2 {
        assert!(std::time::Instant::now() < deadline, "nothing let go");
        granted(&a, rs[0]);
        std::thread::sleep(Duration::from_millis(50));
    }
    let held = a.leases().unwrap().held();
    assert!(
        held.contains_key(&rs[0]),
        "the region in use is kept: {held:?}"
    );
    assert_eq!(held.len(), 2, "down to half: {held:?}");
    let free = free();
    assert_eq!(free.len(), 2, "{free:?}");
    assert!(!free.contains(&rs[0]));
    // Let go: reported to the engine as no longer held.
    let fresh = a.take_fresh_regions();
    for r in &free {
        assert!(fresh.contains(&(*r, None)), "{fresh:?}");
    }
    granted(&a, rs[4]);
}

/// `release_idle_ms`: a region no edit asked for in that long is let go
/// however few the node holds, and then another node may claim it.
#[test]
fn a_region_idle_for_release_idle_ms_is_let_go_for_any_node_to_claim() {
    let Some(db) = database("lease_release_idle") else {
        return;
    };
    let cluster = ClusterConfig {
        node_id: "a".into(),
        lease_ms: 400,
        renew_ms: 100,
        adopt: false,
        release_idle_ms: 800,
        ..ClusterConfig::default()
    };
    let a = open_node(&db, &cluster);
    let (busy, quiet) = (region(0, 0), region(1, 0));
    for r in [busy, quiet] {
        granted(&a, r);
    }
    a.take_fresh_regions();
    let b = open_node(
        &db,
        &ClusterConfig {
            node_id: "b".into(),
            ..cluster.clone()
        },
    );
    let named = b.acquire_regions(&regions(&[quiet])).unwrap();
    assert!(
        matches!(&named, RegionAccess::Elsewhere { owner, .. } if owner == "a"),
        "{named:?}"
    );
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while a.leases().unwrap().held().contains_key(&quiet) {
        assert!(
            std::time::Instant::now() < deadline,
            "the quiet region kept"
        );
        granted(&a, busy);
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        a.leases().unwrap().held().contains_key(&busy),
        "the region in use is kept"
    );
    assert!(a.take_fresh_regions().contains(&(quiet, None)));
    // Node b's refusal is believed a renewal period at most, and the row
    // is freed just after the book: b takes the region soon.
    loop {
        assert!(std::time::Instant::now() < deadline, "b never took it");
        if b.acquire_regions(&regions(&[quiet])).unwrap() == RegionAccess::Granted {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(b.leases().unwrap().held().len(), 1);
}

/// A release that fails (the database out of reach) keeps the region in
/// the book: renewals keep its lease and a later pass lets it go, where it
/// used to stay leased to this node, unrenewed, until its lease ran out.
#[test]
fn a_release_that_fails_keeps_the_region_until_one_succeeds() {
    let Some(db) = database("lease_release_fails") else {
        return;
    };
    let a = open_node(
        &db,
        &ClusterConfig {
            node_id: "a".into(),
            lease_ms: 2_000,
            renew_ms: 100,
            adopt: false,
            release_idle_ms: 2_000,
            ..ClusterConfig::default()
        },
    );
    let allow = |yes: bool| {
        let name = db.name();
        store_common::sql_url(
            &db.cluster().url("postgres"),
            &format!(
                "ALTER DATABASE \"{name}\" WITH ALLOW_CONNECTIONS {yes}; \
                 SELECT pg_terminate_backend(pid) FROM pg_stat_activity \
                 WHERE datname = '{name}' AND pid <> pg_backend_pid()"
            ),
        )
    };
    let r = region(4, 0);
    granted(&a, r);
    a.take_fresh_regions();
    // Closed before the region idles (well before: closing takes a while
    // on a loaded machine): every release (the renewal thread's, every
    // 100 ms, and this one) fails.
    allow(false);
    std::thread::sleep(Duration::from_millis(2_500));
    // The renewal thread's own tries take it out of the book while they
    // run: this one may find nothing to release.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    loop {
        match a.release_idle_regions() {
            Err(_) if a.leases().unwrap().held().contains_key(&r) => break,
            Ok(gone) => assert!(gone.is_empty(), "released while closed"),
            Err(_) => {}
        }
        assert!(std::time::Instant::now() < deadline, "never kept");
        std::thread::sleep(Duration::from_millis(20));
    }
    allow(true);
    let owner = || region_text(&db, r, "owner");
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while owner() != [""] {
        assert!(std::time::Instant::now() < deadline, "never released");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(!a.leases().unwrap().held().contains_key(&r));
}

/// A region another node asks for (an edit of its own reaches into it)
/// is handed over once this node's edits have left it alone for
/// `handoff_idle_ms`: one in use is kept until then, the asker's claim
/// clears the ask, an ask older than a lease counts for nothing, and a
/// node asks for a region at most once a renewal period.
#[test]
fn a_region_asked_for_is_handed_over_once_left_alone() {
    let Some(db) = database("lease_handoff") else {
        return;
    };
    let cfg = |id: &str| ClusterConfig {
        node_id: id.into(),
        lease_ms: 60_000,
        renew_ms: 10_000,
        adopt: false,
        handoff_idle_ms: 1_000,
        ..ClusterConfig::default()
    };
    let (a, b) = (open_node(&db, &cfg("a")), open_node(&db, &cfg("b")));
    let (busy, quiet) = (region(0, 0), region(1, 0));
    for r in [busy, quiet] {
        granted(&a, r);
    }
    a.take_fresh_regions();
    let quiet_for = Duration::from_millis(1_100);
    std::thread::sleep(quiet_for);
    assert!(a.hand_over_regions().unwrap().is_empty(), "nobody asked");
    let wanted = || {
        sql(
            &db,
            "SELECT wanted_by FROM regions ORDER BY region_x, region_z",
        )
    };
    b.want_regions(&regions(&[busy, quiet])).unwrap();
    assert_eq!(wanted(), ["b", "b"]);

    granted(&a, busy);
    assert_eq!(a.hand_over_regions().unwrap(), [quiet], "the busy one kept");
    assert!(a.take_fresh_regions().contains(&(quiet, None)));
    assert!(!a.leases().unwrap().held().contains_key(&quiet));
    granted(&b, quiet);
    assert_eq!(wanted(), ["b"], "the claim cleared the ask");
    std::thread::sleep(quiet_for);
    assert_eq!(a.hand_over_regions().unwrap(), [busy]);
    granted(&b, busy);

    // Node a takes nothing back by asking twice within a renewal period.
    a.want_regions(&regions(&[busy])).unwrap();
    sql(&db, "UPDATE regions SET wanted_by = NULL, wanted_at = NULL");
    a.want_regions(&regions(&[busy])).unwrap();
    assert!(wanted().is_empty(), "asked again within a renewal period");
    // An ask older than two renewal periods (20 s here; the lease is a
    // minute) is not acted on: its player has stopped trying.
    sql(
        &db,
        "UPDATE regions SET wanted_by = 'a', wanted_at = now() - interval '30 seconds' \
         WHERE region_x = 0 AND region_z = 0",
    );
    std::thread::sleep(quiet_for);
    assert!(
        b.hand_over_regions().unwrap().is_empty(),
        "a stale ask acted on"
    );
    assert_eq!(b.leases().unwrap().held().len(), 2);
}

#[test]
fn a_region_another_node_holds_is_not_written() {
    let Some(db) = database("lease_live_other") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let r = region(0, 5);
    let mut world = Seq::default();
    a.commit_batch(&edit(&mut world, &[chunk_in(r, 1)], 1))
        .unwrap();
    let before = footprint(&db, &b);
    let err = b
        .commit_batch(&edit(&mut fork(&world), &[chunk_in(r, 1)], 2))
        .unwrap_err();
    assert_eq!(fenced(err), (r, None, Some(1), Some("a".into())));
    assert_eq!(footprint(&db, &b), before);
    assert!(b.leases().unwrap().held().is_empty());
}

#[test]
fn a_batch_across_regions_is_refused_whole_when_one_is_lost() {
    let Some(db) = database("lease_across") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let (r0, r1) = (region(0, 0), region(1, 0));
    let (p0, p1) = (chunk_in(r0, 0), chunk_in(r1, 0));
    let mut world = Seq::default();
    a.commit_batch(&edit(&mut world, &[p0, p1], 1)).unwrap();
    expire(&db, r1);
    b.claim_regions(&[r1]).unwrap();
    let before = footprint(&db, &a);
    let err = a
        .commit_batch(&edit(&mut fork(&world), &[p0, p1], 2))
        .unwrap_err();
    assert_eq!(fenced(err), (r1, Some(1), Some(2), Some("b".into())));
    // Nothing of it, r0's chunk included.
    assert_eq!(footprint(&db, &a), before);
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(r0, 1)]));
    // The region still held stays writable.
    a.commit_batch(&edit(&mut world, &[p0], 3)).unwrap();
}

#[test]
fn a_node_restarted_under_its_name_fences_its_previous_process() {
    let Some(db) = database("lease_restart") else {
        return;
    };
    let old = node(&db, "a");
    let r = region(3, 3);
    let mut world = Seq::default();
    old.commit_batch(&edit(&mut world, &[chunk_in(r, 0)], 1))
        .unwrap();
    // The lease is live, but the name is the same: a new epoch at once.
    let new = node(&db, "a");
    assert_eq!(new.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));
    let before = footprint(&db, &new);
    let err = old
        .commit_batch(&edit(&mut fork(&world), &[chunk_in(r, 0)], 2))
        .unwrap_err();
    assert_eq!(fenced(err), (r, Some(1), Some(2), Some("a".into())));
    assert_eq!(footprint(&db, &new), before);
    new.commit_batch(&edit(&mut world, &[chunk_in(r, 0)], 3))
        .unwrap();
}

/// A process started under a node id that a live process still runs as
/// supersedes it: the older one's next renewal finds out, and from then on
/// it claims, renews and adopts nothing, and says why.
#[test]
fn a_second_process_under_a_node_id_supersedes_the_first() {
    let Some(db) = database("lease_superseded") else {
        return;
    };
    let old = node(&db, "a");
    let (r, s) = (region(3, 3), region(4, 3));
    old.claim_regions(&[r]).unwrap();
    old.renew_leases().unwrap();
    assert_eq!(old.superseded(), None);
    // A row gone (a database restored from a dump) is written again.
    sql(&db, "DELETE FROM nodes");
    old.renew_leases().unwrap();
    assert_eq!(sql(&db, "SELECT node_id FROM nodes"), ["a"]);
    assert_eq!(old.superseded(), None);
    // A process not registered yet (its ports not bound) checks nothing
    // and supersedes nobody.
    let starting = PgStore::open_node(
        &PgConfig {
            url: db.url(),
            ..PgConfig::default()
        },
        DEFAULT_REGION_CHUNKS,
        &ClusterConfig {
            node_id: "a".into(),
            adopt: false,
            ..ClusterConfig::default()
        },
    )
    .unwrap();
    starting.renew_leases().unwrap();
    old.renew_leases().unwrap();
    assert_eq!((starting.superseded(), old.superseded()), (None, None));
    drop(starting);
    let new = node(&db, "a");
    assert_eq!(new.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));

    let err = old.renew_leases().unwrap_err();
    assert!(matches!(err, StoreError::Superseded { .. }), "{err}");
    let why = old.superseded().expect("superseded");
    assert!(why.contains("another process started as node a"), "{why}");
    assert!(matches!(
        old.claim_regions(&[s]).unwrap_err(),
        StoreError::Superseded { .. }
    ));
    assert!(matches!(
        old.acquire_regions(&regions(&[r])).unwrap_err(),
        StoreError::Superseded { .. }
    ));
    assert!(matches!(
        old.adopt_regions().unwrap_err(),
        StoreError::Superseded { .. }
    ));
    let before = footprint(&db, &new);
    let mut world = Seq::default();
    assert!(matches!(
        old.commit_batch(&edit(&mut world, &[chunk_in(s, 0)], 1))
            .unwrap_err(),
        StoreError::Superseded { .. }
    ));
    assert_eq!(footprint(&db, &new), before, "it wrote nothing");
    // The new process goes on, and its renewals keep its region.
    assert_eq!(new.renew_leases().unwrap(), Vec::<RegionId>::new());
    assert_eq!(new.superseded(), None);
    assert_eq!(new.leases().unwrap().held(), BTreeMap::from([(r, 2)]));
    assert_eq!(
        sql(&db, "SELECT node_id FROM nodes"),
        ["a"],
        "one row per node id"
    );
}

#[test]
fn nodes_racing_for_the_same_regions_get_one_owner_each() {
    let Some(db) = database("lease_race") else {
        return;
    };
    let regions: Vec<RegionId> = (0..6)
        .flat_map(|x| (0..6).map(move |z| region(x, z)))
        .collect();
    for round in 1..=3u64 {
        // Fresh nodes each round, after every lease of the last ran out.
        let names: Vec<String> = ["a", "b", "c"]
            .iter()
            .map(|n| format!("{n}{round}"))
            .collect();
        let nodes: Vec<PgStore> = names.iter().map(|id| node(&db, id)).collect();
        let start = Barrier::new(nodes.len());
        let claims: Vec<BTreeMap<RegionId, u64>> = std::thread::scope(|s| {
            let handles: Vec<_> = nodes
                .iter()
                .enumerate()
                .map(|(i, n)| {
                    let (start, regions) = (&start, &regions);
                    s.spawn(move || {
                        start.wait();
                        // Batches of five, each node from another end.
                        let mut got = BTreeMap::new();
                        let mut batches: Vec<&[RegionId]> = regions.chunks(5).collect();
                        let turn = i * 3 % batches.len();
                        batches.rotate_left(turn);
                        for batch in batches {
                            got.extend(n.claim_regions(batch).unwrap());
                        }
                        got
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let mut owners: BTreeMap<RegionId, usize> = BTreeMap::new();
        for (i, got) in claims.iter().enumerate() {
            assert_eq!(&nodes[i].leases().unwrap().held(), got);
            for (&r, &epoch) in got {
                assert_eq!(epoch, round, "one claim per region and round");
                assert_eq!(owners.insert(r, i), None, "{r:?} claimed twice");
            }
        }
        assert_eq!(owners.len(), regions.len(), "every region has an owner");
        let table = sql(
            &db,
            "SELECT owner || ':' || region_x || ',' || region_z || ':' || epoch \
             FROM regions ORDER BY 1",
        );
        let mut believed: Vec<String> = owners
            .iter()
            .map(|(r, &i)| format!("{}:{},{}:{round}", names[i], r.x, r.z))
            .collect();
        believed.sort();
        assert_eq!(table, believed);
        sql(
            &db,
            "UPDATE regions SET lease_expires = now() - interval '1 second'",
        );
    }
}

#[test]
fn a_commit_racing_a_takeover_is_either_before_it_or_refused() {
    let Some(db) = database("lease_commit_race") else {
        return;
    };
    let a = Arc::new(node(&db, "a"));
    let b = node(&db, "b");
    let r = region(0, 0);
    let pos = chunk_in(r, 2);
    let mut world = Seq::default();
    a.commit_batch(&edit(&mut world, &[pos], 1)).unwrap();
    let taken = Arc::new(AtomicBool::new(false));
    let writer = {
        let (a, taken) = (a.clone(), taken.clone());
        std::thread::spawn(move || {
            let (mut acked, mut late) = (Vec::new(), 0);
            for salt in 2..2000 {
                let started_after = taken.load(Ordering::SeqCst);
                let mut next = fork(&world);
                let batch = edit(&mut next, &[pos], salt);
                match a.commit_batch(&batch) {
                    Ok(_) => {
                        assert!(
                            !started_after,
                            "a commit begun after the takeover succeeded"
                        );
                        world = next;
                        acked.push(world.last_seq);
                    }
                    Err(e) => {
                        fenced(e);
                        late += 1;
                        if late > 3 {
                            break;
                        }
                    }
                }
            }
            (acked, late)
        })
    };
    std::thread::sleep(Duration::from_millis(100));
    expire(&db, r);
    assert_eq!(b.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));
    taken.store(true, Ordering::SeqCst);
    let (acked, late) = writer.join().unwrap();
    assert!(!acked.is_empty(), "a wrote before the takeover");
    assert!(
        late > 0,
        "a was still writing at the takeover, and was refused"
    );
    // The log holds exactly the first commit and what a was told succeeded.
    let mut want = vec!["1".to_string()];
    want.extend(acked.iter().map(u64::to_string));
    assert_eq!(sql(&db, "SELECT seq FROM edit_log ORDER BY seq"), want);
    assert_eq!(b.last_seq().unwrap(), *acked.last().unwrap());
}

#[test]
fn the_renewal_thread_keeps_leases_alive_until_the_node_is_gone() {
    let Some(db) = database("lease_renewer") else {
        return;
    };
    let (lease_ms, renew_ms) = (400, 50);
    let a = node_with(&db, "a", lease_ms, renew_ms);
    let b = node(&db, "b");
    let r = region(4, 4);
    a.claim_regions(&[r]).unwrap();
    // Three leases long: only the thread's renewals keep it a's.
    std::thread::sleep(Duration::from_millis(3 * lease_ms));
    assert!(b.claim_regions(&[r]).unwrap().is_empty());
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(r, 1)]));
    drop(a);
    std::thread::sleep(Duration::from_millis(lease_ms + 200));
    assert_eq!(b.claim_regions(&[r]).unwrap(), BTreeMap::from([(r, 2)]));
}

#[test]
fn open_node_refuses_bad_cluster_settings() {
    let Some(db) = database("lease_settings") else {
        return;
    };
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    for (cluster, field) in [
        (ClusterConfig::default(), "cluster.node_id"),
        (
            ClusterConfig {
                node_id: "a b".into(),
                ..ClusterConfig::default()
            },
            "cluster.node_id",
        ),
        (
            ClusterConfig {
                node_id: "a".into(),
                lease_ms: 1000,
                renew_ms: 600,
                ..ClusterConfig::default()
            },
            "cluster.renew_ms",
        ),
        (
            ClusterConfig {
                node_id: "a".into(),
                max_held_regions: 0,
                ..ClusterConfig::default()
            },
            "cluster.max_held_regions",
        ),
        (
            ClusterConfig {
                node_id: "a".into(),
                lease_ms: 10_000,
                release_idle_ms: 5_000,
                ..ClusterConfig::default()
            },
            "cluster.release_idle_ms",
        ),
        (
            ClusterConfig {
                node_id: "a".into(),
                handoff_idle_ms: 999,
                ..ClusterConfig::default()
            },
            "cluster.handoff_idle_ms",
        ),
        (
            ClusterConfig {
                node_id: "a".into(),
                seq_block: strata_server::cluster::MIN_SEQ_BLOCK - 1,
                ..ClusterConfig::default()
            },
            "cluster.seq_block",
        ),
    ] {
        let err = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster).unwrap_err();
        assert!(err.to_string().contains(field), "{err}");
    }
}

#[test]
fn the_regions_table_lists_owners_epochs_and_expiry() {
    let Some(db) = database("lease_listing") else {
        return;
    };
    let a = node(&db, "a");
    let (r0, r1) = (region(-2, 0), region(1, 1));
    a.claim_regions(&[r1, r0]).unwrap();
    expire(&db, r1);
    a.release_leases().unwrap();
    let rows = a.region_leases().unwrap();
    let got: Vec<_> = rows
        .iter()
        .map(|l| (l.region, l.owner.clone(), l.epoch))
        .collect();
    assert_eq!(got, [(r0, None, 1), (r1, None, 1)]);
    // r0's lease had most of a minute left, r1's ran out a second ago.
    assert!(rows[0].expires_in_ms > 50_000, "{rows:?}");
    assert!((-5_000..=-900).contains(&rows[1].expires_in_ms), "{rows:?}");
}

#[test]
fn fenced_commits_count_edits_per_region_and_refused_ones_count_nothing() {
    let Some(db) = database("lease_edit_counts") else {
        return;
    };
    let a = node(&db, "a");
    let (r0, r1) = (region(0, 0), region(1, 0));
    let mut world = Seq::default();
    // Two edits in r0, one across the border of r0 and r1, in one batch.
    let (c0, c1) = (chunk_in(r0, 0), chunk_in(r1, 0));
    let batch = world.delta_batch(&[
        vec![(c0, terrain_chunk(1))],
        vec![(c0, terrain_chunk(2))],
        vec![(c0, terrain_chunk(3)), (c1, terrain_chunk(3))],
    ]);
    a.commit_batch(&batch).unwrap();
    let counts = |s: &PgStore| -> Vec<(RegionId, u64)> {
        s.region_leases()
            .unwrap()
            .iter()
            .map(|l| (l.region, l.edits))
            .collect()
    };
    assert_eq!(counts(&a), [(r0, 3), (r1, 1)]);
    let rows = a.region_leases().unwrap();
    assert!(
        rows.iter().all(|l| (0..5_000).contains(&l.renewed_ms_ago)),
        "{rows:?}"
    );

    // b takes r1 over; a's next batch across the border is refused whole
    // and counts nothing anywhere.
    expire(&db, r1);
    let b = node(&db, "b");
    b.claim_regions(&[r1]).unwrap();
    let mut stale = fork(&world);
    let refused = stale.delta_batch(&[vec![(c0, terrain_chunk(4)), (c1, terrain_chunk(4))]]);
    fenced(a.commit_batch(&refused).unwrap_err());
    assert_eq!(counts(&b), [(r0, 3), (r1, 1)]);
}

#[test]
fn renewals_do_not_wait_behind_a_commit_holding_the_pool() {
    let Some(db) = database("lease_own_connection") else {
        return;
    };
    let (lease_ms, renew_ms) = (600, 50);
    let pg = PgConfig {
        url: db.url(),
        max_connections: 1,
        ..PgConfig::default()
    };
    let cluster = ClusterConfig {
        node_id: "a".into(),
        lease_ms,
        renew_ms,
        // Adoption is tested on its own (`adopt_regions`).
        adopt: false,
        ..ClusterConfig::default()
    };
    let a = Arc::new(PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &cluster).unwrap());
    a.init_meta(&WorldMeta::new(7, 1, "")).unwrap();
    let r = region(2, 2);
    a.claim_regions(&[r]).unwrap();
    let mut world = Seq::default();
    let pos = chunk_in(r, 0);
    a.commit_batch(&world.delta_batch(&[vec![(pos, terrain_chunk(8))]]))
        .unwrap();
    let batch = world.delta_batch(&[vec![(pos, terrain_chunk(9))]]);

    // Another session holds the chunk's row for three leases (as a
    // checkpoint folding it would): a's commit waits on it with the
    // pool's only connection.
    let lock = format!(
        "SELECT 1 FROM chunks WHERE x = {} AND y = {} AND z = {} FOR UPDATE",
        pos.x, pos.y, pos.z
    );
    let holder = store_common::hold_rows(&db, &lock, "COMMIT", move || {
        std::thread::sleep(Duration::from_millis(3 * lease_ms));
    });
    let committing = {
        let a = a.clone();
        std::thread::spawn(move || a.commit_batch(&batch))
    };
    // Three leases later the lease is still a's: renewed meanwhile.
    std::thread::sleep(Duration::from_millis(3 * lease_ms - 200));
    assert!(!committing.is_finished(), "the commit still waits");
    let row = sql(
        &db,
        &format!(
            "SELECT owner || ':' || (lease_expires > now()) FROM regions \
             WHERE region_x = {} AND region_z = {}",
            r.x, r.z
        ),
    );
    assert_eq!(row, ["a:true"], "renewed while the commit waited");
    holder.join().unwrap();
    committing.join().unwrap().unwrap();
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(r, 1)]));
}

/// Nodes "a" and "b", each with its seq block reserved, and a world
/// numbering from each one's block.
fn two_nodes(db: &PgDb) -> (PgStore, PgStore, Seq, Seq) {
    let a = node(db, "a");
    let b = node(db, "b");
    let world = |store: &PgStore| Seq {
        last_seq: store.reserve_seqs(0).unwrap(),
        ..Seq::default()
    };
    let (wa, wb) = (world(&a), world(&b));
    (a, b, wa, wb)
}

/// A log cursor (the console's place in the edit log) reads every
/// node's entries: one a node logs after another node's higher seq is
/// read too (a single highest seq seen would skip it), and a node's new
/// seq block is read from its start.
#[test]
fn a_log_cursor_misses_no_nodes_entries_on_a_cluster() {
    let Some(db) = database("lease_log_cursor") else {
        return;
    };
    let (a, b, mut wa, mut wb) = two_nodes(&db);
    let (ra, rb) = (region(0, 0), region(1, 0));
    let mut cursor = LogCursor::at_end(&a).unwrap();
    let read = |c: &mut LogCursor| {
        let mut seqs = Vec::new();
        c.read(&a, |e| seqs.push(e.seq)).unwrap();
        seqs
    };
    b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 1))
        .unwrap();
    assert_eq!(read(&mut cursor), [SEQ_BLOCK + 1]);
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 2))
        .unwrap();
    b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 3))
        .unwrap();
    assert_eq!(read(&mut cursor), [1, SEQ_BLOCK + 2]);
    assert!(read(&mut cursor).is_empty());
    // Node a numbers from a new block (as after a restart).
    let floor = a.reserve_seqs(wa.last_seq).unwrap();
    wa.last_seq = floor;
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 4))
        .unwrap();
    assert_eq!(read(&mut cursor), [floor + 1]);
    assert!(!cursor.pruned(&a).unwrap());
    // Node a fills a block and moves on twice between two reads: the
    // block in the middle, never a node's newest when read, is read too.
    wa.last_seq = a.reserve_seqs(wa.last_seq).unwrap();
    let middle = wa.last_seq + 1;
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 5))
        .unwrap();
    wa.last_seq = a.reserve_seqs(wa.last_seq).unwrap();
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 6))
        .unwrap();
    assert_eq!(read(&mut cursor), [middle, wa.last_seq]);
    assert!(!cursor.pruned(&a).unwrap());
    // A cursor begun at the end just after a's lease thread reserved its
    // next block, while a's engine still finishes a tick in this one
    // (reserved an hour ago): that tick's entry is read.
    sql(
        &db,
        "UPDATE seq_blocks SET reserved_at = now() - interval '1 hour'",
    );
    let next = a.reserve_seqs(wa.last_seq).unwrap();
    let mut late = LogCursor::at_end(&a).unwrap();
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 8))
        .unwrap();
    assert!(wa.last_seq < next);
    assert_eq!(read(&mut late), [wa.last_seq]);
    wa.last_seq = next;
    // One more block, not read yet when every block is pruned to its end:
    // a cursor at the end now has lost nothing (the heads count pruned
    // entries), so readers do not start over and over; this one has lost
    // the new block's entry.
    let behind = cursor;
    wa.last_seq = a.reserve_seqs(wa.last_seq).unwrap();
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 7))
        .unwrap();
    assert!(!behind.pruned(&a).unwrap());
    assert_eq!(a.prune_log(u64::MAX >> 1, 100).unwrap(), 8);
    let fresh = LogCursor::at_end(&a).unwrap();
    assert!(!fresh.pruned(&a).unwrap());
    assert!(behind.pruned(&a).unwrap(), "the new block's entry is gone");
    // A server alone on the store reads the log whole, whatever blocks
    // the cluster left.
    let segments = plain(&db).log_segments(SegmentsAlso::After(0)).unwrap();
    assert_eq!(segments.len(), 1);
    assert_eq!(segments[0].first, 1);
}

/// Blocks reserved before their last seqs were stored (migration 13)
/// were 2^40 seqs long: a reader of the log reads such a block that far,
/// and a block reserved since to its own end (`[cluster] seq_block`);
/// `check` takes the log across both.
#[test]
fn blocks_reserved_before_their_ends_were_stored_read_as_two_to_the_forty() {
    let Some(db) = database("lease_block_ends") else {
        return;
    };
    // As a build before migration 13 left it: node a's block of 2^40.
    let a = node(&db, "a");
    let fa = a.reserve_seqs(0).unwrap();
    let mut wa = Seq {
        last_seq: fa,
        ..Seq::default()
    };
    let (ra, rb) = (region(0, 0), region(1, 0));
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 1))
        .unwrap();
    drop(a);
    sql(
        &db,
        &format!(
            "ALTER TABLE seq_blocks DROP COLUMN last_seq; \
             DROP INDEX seq_blocks_node, seq_blocks_reserved_at; \
             UPDATE world SET seq_reserved = {}; \
             DELETE FROM schema_migrations WHERE version = 13",
            fa + (1 << 40)
        ),
    );
    let b = open_node(
        &db,
        &ClusterConfig {
            node_id: "b".into(),
            seq_block: 1000,
            adopt: false,
            ..ClusterConfig::default()
        },
    );
    let mut cursor = LogCursor::default();
    let fb = b.reserve_seqs(0).unwrap();
    assert_eq!(fb, fa + (1 << 40), "above the old block");
    assert_eq!(b.seq_bounds(), (fb, fb + 1000));
    let ends: BTreeMap<u64, u64> = b
        .log_segments(SegmentsAlso::After(0))
        .unwrap()
        .iter()
        .map(|s| (s.first, s.last))
        .collect();
    assert_eq!(
        ends,
        BTreeMap::from([(fa + 1, fa + (1 << 40)), (fb + 1, fb + 1000)])
    );
    let mut wb = Seq {
        last_seq: fb,
        ..Seq::default()
    };
    b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 2))
        .unwrap();
    let mut seqs = Vec::new();
    cursor.read(&b, |e| seqs.push(e.seq)).unwrap();
    assert_eq!(seqs, [fa + 1, fb + 1]);
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// A node paused inside its commit (here: a session holding what such a
/// commit locks, the world row included, as builds before this one
/// locked it) holds up no other node's commit: fenced commits lock only
/// their own regions' and chunks' rows. The store's last seq is the
/// log's, which fenced commits leave the world row behind.
#[test]
fn a_node_paused_in_its_commit_holds_up_no_other_nodes_commit() {
    let Some(db) = database("lease_paused_commit") else {
        return;
    };
    let (a, b, mut wa, mut wb) = two_nodes(&db);
    let fb = wb.last_seq;
    let (ra, rb) = (region(0, 0), region(1, 0));
    b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 1))
        .unwrap();
    let pb = chunk_in(rb, 0);
    let lock = format!(
        "SELECT 1 FROM world WHERE id = 1 FOR UPDATE; \
         SELECT 1 FROM regions WHERE region_x = {} AND region_z = {} FOR UPDATE; \
         SELECT 1 FROM chunks WHERE x = {} AND y = {} AND z = {} FOR UPDATE",
        rb.x, rb.z, pb.x, pb.y, pb.z
    );
    let (release, holder) = store_common::hold_until_told(&db, &lock);
    // While b is "paused", a commits twice (the first claims its region).
    for i in 0..2 {
        a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 10 + i))
            .unwrap();
    }
    release.send(()).unwrap();
    holder.join().unwrap();

    assert_eq!(a.last_seq().unwrap(), fb + 1, "the log's last seq");
    assert_eq!(
        sql(&db, "SELECT last_seq FROM world"),
        ["0"],
        "fenced commits leave the world row alone"
    );
    assert_eq!(plain(&db).load_meta().unwrap().unwrap().last_seq, fb + 1);
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    // A single node opened on the cluster's store goes on after the log.
    let single = plain(&db);
    let mut ws = Seq {
        last_seq: fb + 1,
        ..Seq::default()
    };
    single
        .commit_batch(&edit(&mut ws, &[chunk_in(region(5, 5), 0)], 30))
        .unwrap();
    assert_eq!(single.last_seq().unwrap(), fb + 2);
    assert_eq!(
        sql(&db, "SELECT last_seq FROM world"),
        [(fb + 2).to_string()]
    );
}

/// A region row locked by a node paused mid-commit holds up no other
/// node's engine: a claim of it (its lease run out) is answered
/// `Contended` at once, and asking its holder for it is skipped, instead
/// of waiting until PostgreSQL ends the paused session.
#[test]
fn a_region_row_locked_by_a_paused_commit_is_not_waited_for() {
    let Some(db) = database("lease_contended_row") else {
        return;
    };
    let (a, b, _, _) = two_nodes(&db);
    let r = region(2, 0);
    granted(&a, r);
    expire(&db, r);
    let lock = format!(
        "SELECT 1 FROM regions WHERE region_x = {} AND region_z = {} FOR UPDATE",
        r.x, r.z
    );
    let (release, holder) = store_common::hold_until_told(&db, &lock);
    let started = std::time::Instant::now();
    b.want_regions(&regions(&[r])).unwrap();
    for _ in 0..2 {
        // The second answered from memory, with no statement waiting.
        assert_eq!(
            b.acquire_regions(&regions(&[r])).unwrap(),
            RegionAccess::Contended
        );
    }
    assert!(
        started.elapsed() < std::time::Duration::from_secs(2),
        "waited {:?}",
        started.elapsed()
    );
    release.send(()).unwrap();
    holder.join().unwrap();
    let wanted_by = || region_text(&db, r, "wanted_by");
    assert_eq!(wanted_by(), [""], "the ask was skipped");
    // The skipped ask is made at the next edit's.
    b.want_regions(&regions(&[r])).unwrap();
    assert_eq!(wanted_by(), ["b"]);
    // Once the row is free, and the contended answer has run out, the
    // claim goes through.
    std::thread::sleep(std::time::Duration::from_millis(600));
    granted(&b, r);
}

/// A free region's mark moves with every write into it, a write at the
/// same epoch included (a holder paused past its lease that renews and
/// commits on): another node's copy read at the old mark is stale.
#[test]
fn a_free_regions_mark_moves_with_every_write() {
    let Some(db) = database("lease_free_marks") else {
        return;
    };
    let (a, b, mut wa, _) = two_nodes(&db);
    let (r, never) = (region(3, 0), region(9, 9));
    let marks = || b.free_region_marks(&regions(&[r, never])).unwrap();
    a.commit_batch(&edit(&mut wa, &[chunk_in(r, 0)], 1))
        .unwrap();
    assert_eq!(marks(), [(never, (0, 0))], "held: not free");
    expire(&db, r);
    let first = marks();
    assert_eq!(first.len(), 2, "{first:?}");
    let (_, (epoch, seq)) = first[0];
    assert!(seq > 0);
    // Its lease run out, the holder commits at the same epoch.
    a.commit_batch(&edit(&mut wa, &[chunk_in(r, 0)], 2))
        .unwrap();
    expire(&db, r);
    let (_, (epoch_now, seq_now)) = marks()[0];
    assert_eq!(epoch_now, epoch);
    assert!(seq_now > seq, "{seq_now} after {seq}");
}

/// Text column `column` of region `r`'s row ('' for NULL).
fn region_text(db: &PgDb, r: RegionId, column: &str) -> Vec<String> {
    sql(
        db,
        &format!(
            "SELECT COALESCE({column}, '') FROM regions WHERE region_x = {} AND region_z = {}",
            r.x, r.z
        ),
    )
}

fn regions(rs: &[RegionId]) -> std::collections::BTreeSet<RegionId> {
    rs.iter().copied().collect()
}

/// A plain handle on `db`, as the admin tools open it.
fn plain(db: &PgDb) -> PgStore {
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    PgStore::open(&pg, DEFAULT_REGION_CHUNKS).unwrap()
}

#[test]
fn nodes_writing_at_once_number_from_their_own_seq_blocks_in_order_per_region() {
    let Some(db) = database("lease_seq_blocks") else {
        return;
    };
    let (a, b, mut wa, mut wb) = two_nodes(&db);
    let (fa, fb) = (wa.last_seq, wb.last_seq);
    assert_eq!((fa, fb), (0, SEQ_BLOCK), "blocks one after the other");
    assert_eq!((a.seq_bounds().0, b.seq_bounds().0), (fa, fb));
    let (ra, rb) = (region(0, 0), region(1, 0));
    // Interleaved commits of two nodes, each in its own region.
    for i in 0..3 {
        a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], i))
            .unwrap();
        b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 10 + i))
            .unwrap();
    }
    assert_eq!(a.last_seq().unwrap(), fb + 3, "last_seq is the highest");
    assert_eq!(
        sql(&db, "SELECT seq FROM edit_log ORDER BY seq"),
        ["1", "2", "3"]
            .into_iter()
            .map(String::from)
            .chain((1..=3).map(|i| (fb + i).to_string()))
            .collect::<Vec<_>>()
    );
    // A batch not above its region's last seq is refused, changing nothing.
    let before = footprint(&db, &b);
    let mut stale = fork(&wb);
    stale.last_seq = fb + 1;
    let err = b
        .commit_batch(&edit(&mut stale, &[chunk_in(rb, 1)], 20))
        .unwrap_err();
    assert!(
        err.to_string()
            .contains("is not above region (1, 0)'s last seq"),
        "{err}"
    );
    assert_eq!(footprint(&db, &b), before);

    // The log's jump to b's block is no gap; any other jump still is.
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    sql(&db, "DELETE FROM edit_log WHERE seq = 2");
    let report = plain(&db).check().unwrap();
    assert!(
        format!("{report:?}").contains("LogGap"),
        "a lost record is still found: {report:?}"
    );
}

#[test]
fn an_edit_in_another_nodes_region_names_it_and_a_crashed_nodes_regions_are_adopted() {
    let Some(db) = database("lease_adopt") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    a.bound_at("127.0.0.1:4001");
    b.bound_at("127.0.0.1:4002");
    let fa = a.reserve_seqs(0).unwrap();
    let fb = b.reserve_seqs(0).unwrap();
    let r = region(3, 3);
    granted(&a, r);
    assert_eq!(
        a.take_fresh_regions(),
        [(r, Some(1))],
        "a claim is reported once, with its epoch"
    );
    assert!(a.take_fresh_regions().is_empty());
    let elsewhere = RegionAccess::Elsewhere {
        region: r,
        owner: "a".into(),
        addr: "127.0.0.1:4001".into(),
    };
    assert_eq!(b.acquire_regions(&regions(&[r])).unwrap(), elsewhere);
    // Asked again, b answers from what it learnt, even with the row gone.
    sql(
        &db,
        "UPDATE regions SET owner_addr = 'moved' WHERE region_x = 3",
    );
    assert_eq!(b.acquire_regions(&regions(&[r])).unwrap(), elsewhere);
    assert!(b.take_fresh_regions().is_empty());

    let pos = chunk_in(r, 0);
    let mut world = Seq {
        last_seq: fa,
        ..Seq::default()
    };
    a.commit_batch(&edit(&mut world, &[pos], 1)).unwrap();
    a.commit_batch(&edit(&mut world, &[pos], 2)).unwrap();
    // a crashes; b's renewal adopts what a let run out, and nothing else.
    let other = region(9, 9);
    granted(&a, other);
    expire(&db, r);
    assert_eq!(b.adopt_regions().unwrap(), [r]);
    assert!(b.adopt_regions().unwrap().is_empty());
    assert_eq!(b.take_fresh_regions(), [(r, Some(2))]);
    assert_eq!(b.region_versions(r).unwrap(), [(pos, 2)]);
    assert_eq!(b.seq_bounds().0, fb, "b's block is above a's seqs already");
    // b goes on from the stored chain, with seqs from its block.
    world.last_seq = fb;
    b.commit_batch(&edit(&mut world, &[pos], 3)).unwrap();
    assert_eq!(b.load_chunk(pos).unwrap().unwrap().version, 3);
    let err = a
        .commit_batch(&edit(&mut fork(&world), &[pos], 4))
        .unwrap_err();
    assert_eq!(fenced(err).3.as_deref(), Some("b"));

    // The other way round: a takes a region b wrote from its newer block,
    // and moves to a block above b's before it numbers any edit there.
    let r2 = region(4, 4);
    let pos2 = chunk_in(r2, 0);
    b.commit_batch(&edit(&mut world, &[pos2], 5)).unwrap();
    expire(&db, r2);
    granted(&a, r2);
    assert_eq!(a.seq_bounds().0, fb + SEQ_BLOCK);
    world.last_seq = a.seq_bounds().0;
    a.commit_batch(&edit(&mut world, &[pos2], 6)).unwrap();
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// A batch the engine built (with the epochs it loaded under) for a region
/// this node does not hold is refused, and claims nothing on the way: the
/// region stays free for whoever asks first.
#[test]
fn a_batch_built_for_a_region_not_held_claims_nothing() {
    let Some(db) = database("lease_no_commit_claim") else {
        return;
    };
    let a = node(&db, "a");
    let r = region(6, 6);
    let mut world = Seq::default();
    let mut batch = edit(&mut world, &[chunk_in(r, 0)], 1);
    batch.epochs = Some(BTreeMap::from([(r, 0)]));
    assert_eq!(fenced(a.commit_batch(&batch).unwrap_err()).0, r);
    assert!(a.leases().unwrap().held().is_empty());
    assert_eq!(
        sql(&db, "SELECT count(*) FROM regions WHERE owner IS NOT NULL"),
        ["0"]
    );
}

/// A node that lets a region go and takes it back, having written it from
/// its own block, goes on in that block: blocks are not burnt on handoffs.
#[test]
fn taking_back_a_region_written_from_ones_own_block_keeps_the_block() {
    let Some(db) = database("lease_own_block") else {
        return;
    };
    let a = node(&db, "a");
    let fa = a.reserve_seqs(0).unwrap();
    let r = region(5, 5);
    let pos = chunk_in(r, 0);
    let mut world = Seq {
        last_seq: fa,
        ..Seq::default()
    };
    a.commit_batch(&edit(&mut world, &[pos], 1)).unwrap();
    assert_eq!(a.release_leases().unwrap(), 1);
    granted(&a, r);
    assert_eq!(a.seq_bounds().0, fa, "no new block for its own seqs");
    a.commit_batch(&edit(&mut world, &[pos], 2)).unwrap();
    assert_eq!(
        sql(&db, "SELECT count(*) FROM seq_blocks"),
        ["1"],
        "one block reserved in all"
    );
}

/// A claim of a region written from a newer block than the claimer's
/// needs a new block; when none can be reserved, the claim is refused and
/// the region let go again, at once free for any node (not leased to the
/// claimer, unbooked, until its lease ran out).
#[test]
fn a_claim_whose_seq_block_cannot_be_reserved_lets_its_regions_go() {
    let Some(db) = database("lease_claim_no_block") else {
        return;
    };
    let (a, b, _, mut wb) = two_nodes(&db);
    let r = region(3, 0);
    b.commit_batch(&edit(&mut wb, &[chunk_in(r, 0)], 1))
        .unwrap();
    assert_eq!(b.release_leases().unwrap(), 1);
    sql(
        &db,
        "ALTER TABLE seq_blocks ADD CONSTRAINT no_new_block CHECK (first_seq < 0) NOT VALID",
    );
    let err = a.acquire_regions(&regions(&[r])).unwrap_err();
    assert!(err.to_string().contains("no_new_block"), "{err}");
    assert_eq!(a.regions_held(), 0);
    assert_eq!(
        sql(
            &db,
            "SELECT coalesce(owner, '-') FROM regions WHERE region_x = 3"
        ),
        ["-"],
        "let go again"
    );
    granted(&b, r);

    // With blocks to be had again, the claim goes through.
    sql(&db, "ALTER TABLE seq_blocks DROP CONSTRAINT no_new_block");
    assert_eq!(b.release_leases().unwrap(), 1);
    granted(&a, r);
    assert!(a.seq_bounds().0 > wb.last_seq, "a block above b's");
}

/// A node's checkpoint folds only the regions it holds: another node's
/// deltas are that node's to fold (every node folding every region would
/// stall the owners' commits on the chunk rows, and a stopping node's last
/// fold would chase the others' commits).
#[test]
fn a_node_lists_only_the_deltas_of_regions_it_holds() {
    let Some(db) = database("lease_fold_scope") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let (ra, rb) = (region(0, 0), region(1, 0));
    let (pa, pb) = (chunk_in(ra, 0), chunk_in(rb, 0));
    let mut world = Seq::default();
    for salt in 1..=2 {
        a.commit_batch(&edit(&mut world, &[pa], salt)).unwrap();
        b.commit_batch(&edit(&mut world, &[pb], salt)).unwrap();
    }
    assert_eq!(a.chunks_with_deltas(None, usize::MAX).unwrap(), [pa]);
    assert_eq!(b.chunks_with_deltas(None, usize::MAX).unwrap(), [pb]);
    assert_eq!(a.checkpoint(usize::MAX).unwrap().chunks, 1);
    assert_eq!(b.chunks_with_deltas(None, usize::MAX).unwrap(), [pb]);
    // A node holding nothing lists nothing.
    assert_eq!(a.release_leases().unwrap(), 1);
    assert!(a.chunks_with_deltas(None, usize::MAX).unwrap().is_empty());
    // Tools on the database alone (no node) list every region's.
    assert_eq!(
        store_common::pg_store(&db)
            .chunks_with_deltas(None, usize::MAX)
            .unwrap(),
        [pb]
    );
}

/// Regions claimed for an edit refused after all are let go at once,
/// reported fresh (no longer held); others, and regions not held, stay.
#[test]
fn regions_claimed_for_a_refused_edit_are_let_go() {
    let Some(db) = database("lease_release_some") else {
        return;
    };
    let a = node(&db, "a");
    let (r, s, t) = (region(0, 0), region(1, 0), region(2, 0));
    a.claim_regions(&[r, s]).unwrap();
    let _ = a.take_fresh_regions();
    a.release_regions(&regions(&[r, t])).unwrap();
    assert_eq!(a.leases().unwrap().held(), BTreeMap::from([(s, 1)]));
    assert_eq!(a.take_fresh_regions(), vec![(r, None)]);
    let owners = sql(
        &db,
        "SELECT region_x || ':' || coalesce(owner, '-') FROM regions ORDER BY region_x",
    );
    assert_eq!(owners, ["0:-", "1:a"]);
}

/// A cluster's log is pruned in each node's seq block from the block's own
/// start: the old entries of a block above another node's newer ones go
/// too. What was pruned is told apart from what was never logged, and the
/// store checks clean.
#[test]
fn a_clusters_log_is_pruned_block_by_block() {
    let Some(db) = database("cluster_log_pruned") else {
        return;
    };
    let a = node(&db, "a");
    let b = node(&db, "b");
    let (fa, fb) = (a.reserve_seqs(0).unwrap(), b.reserve_seqs(0).unwrap());
    assert!(fb > fa);
    // Entries timed as given, whatever their seqs.
    let timed = |seq: &mut Seq, pos: ChunkPos, salt: u32, time_ms: u64| {
        let mut batch = edit(seq, &[pos], salt);
        for e in &mut batch.entries {
            e.time_ms = time_ms;
        }
        batch
    };
    let (old, new, cut) = (1_000, 9_000, 5_000);
    let (pa, pb) = (chunk_in(region(1, 1), 0), chunk_in(region(5, 5), 0));
    let mut on_a = Seq {
        last_seq: fa,
        ..Seq::default()
    };
    let mut on_b = Seq {
        last_seq: fb,
        ..Seq::default()
    };
    a.commit_batch(&timed(&mut on_a, pa, 1, old)).unwrap();
    a.commit_batch(&timed(&mut on_a, pa, 2, new)).unwrap();
    b.commit_batch(&timed(&mut on_b, pb, 3, old)).unwrap();
    b.commit_batch(&timed(&mut on_b, pb, 4, old)).unwrap();
    b.commit_batch(&timed(&mut on_b, pb, 5, new)).unwrap();
    // a's newer entry (below b's block) does not hold b's old ones back.
    assert_eq!(a.prune_log(cut, 100).unwrap(), 3);
    let logged: Vec<u64> = a
        .edit_log(0..=u64::MAX >> 2)
        .map(|e| e.unwrap().seq)
        .collect();
    assert_eq!(logged, [fa + 2, fb + 3]);
    assert_eq!(
        sql(&db, "SELECT pruned_to FROM seq_blocks ORDER BY first_seq"),
        [(fa + 1).to_string(), (fb + 2).to_string()]
    );
    assert!(a.log_pruned_at(fb + 1).unwrap() && a.log_pruned_at(fa + 1).unwrap());
    assert!(!a.log_pruned_at(fb + 3).unwrap() && !a.log_pruned_at(fa + 2).unwrap());
    assert_eq!(a.prune_log(cut, 100).unwrap(), 0);
    let report = a.check().unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
    // Every block pruned to its end: the store's last seq stays, and the
    // store checks clean with no entry left above it.
    assert_eq!(a.prune_log(new + 1, 100).unwrap(), 2);
    assert_eq!(a.last_seq().unwrap(), fb + 3);
    let report = a.check().unwrap();
    assert!(report.is_ok(), "{:?}", report.issues);
    // Both nodes' chunks read as committed.
    assert_eq!(b.load_chunk(pb).unwrap().unwrap().version, 3);
    assert_eq!(a.load_chunk(pa).unwrap().unwrap().version, 2);
}

/// A node whose renewals do not get through (the database out of its
/// reach, here its regions table locked) stops saying it writes its
/// regions once their lease may have run out: another node may have taken
/// them, and clients would route to both. A renewal that gets through
/// says so again.
#[test]
fn a_node_cut_off_past_its_lease_no_longer_says_it_writes_its_regions() {
    use strata_server::store::RegionHolder;
    let Some(db) = database("lease_cut_off") else {
        return;
    };
    let a = node_with(&db, "a", 1_000, 200);
    let r = region(2, 2);
    granted(&a, r);
    let holder = |s: &PgStore| s.region_holders(&regions(&[r])).unwrap()[0].1.clone();
    assert_eq!(holder(&a), RegionHolder::Here);
    let (release, locker) =
        store_common::hold_until_told(&db, "LOCK TABLE regions IN ACCESS EXCLUSIVE MODE");
    std::thread::sleep(Duration::from_millis(1_500));
    assert_eq!(holder(&a), RegionHolder::Free);
    release.send(()).unwrap();
    locker.join().unwrap();
    let started = std::time::Instant::now();
    while holder(&a) != RegionHolder::Here {
        assert!(started.elapsed() < Duration::from_secs(10), "renewed");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// What a viewer looks up (`region_holders_read`, the console's map) is
/// not cached: the engine's cache of other nodes' regions, which routes
/// its edits, keeps what it had. The engine's own lookups are cached.
#[test]
fn a_viewers_lookups_leave_the_holders_cache_alone() {
    use strata_server::store::RegionHolder;
    let Some(db) = database("lease_viewer_lookups") else {
        return;
    };
    let (a, b) = (node(&db, "a"), node(&db, "b"));
    let (r, q) = (region(4, 4), region(5, 4));
    granted(&b, r);
    granted(&b, q);
    let held_by_b = RegionHolder::Node {
        owner: "b".into(),
        addr: String::new(),
    };
    let first = |v: Vec<(RegionId, RegionHolder)>| v[0].1.clone();
    // a looks r up as a viewer, q as the engine would; then both leases
    // run out.
    assert_eq!(
        first(a.region_holders_read(&regions(&[r])).unwrap()),
        held_by_b
    );
    assert_eq!(first(a.region_holders(&regions(&[q])).unwrap()), held_by_b);
    expire(&db, r);
    expire(&db, q);
    // r was not cached: read again, it is free. q still answers from the
    // cache (for up to a renewal period).
    assert_eq!(
        first(a.region_holders(&regions(&[r])).unwrap()),
        RegionHolder::Free
    );
    assert_eq!(first(a.region_holders(&regions(&[q])).unwrap()), held_by_b);
}

/// Seq blocks a handoff or refill left behind are merged once their log is
/// pruned and their node moved on long ago (`seqs::compact`, at the end of
/// a prune pass): the table stops growing, `check` and the pruned answers
/// hold, log readers are not sent to the merged row, and a commit still
/// numbered in a merged block (a node paused all that while) is refused,
/// changing nothing.
#[test]
fn old_empty_seq_blocks_are_merged_and_a_commit_numbered_in_one_is_refused() {
    let Some(db) = database("lease_blocks_compacted") else {
        return;
    };
    let (a, b, mut wa, mut wb) = two_nodes(&db);
    let (ra, rb) = (region(0, 0), region(1, 0));
    a.commit_batch(&edit(&mut wa, &[chunk_in(ra, 0)], 1))
        .unwrap();
    b.commit_batch(&edit(&mut wb, &[chunk_in(rb, 0)], 2))
        .unwrap();
    let stale = fork(&wa);
    // Blocks: a, b, a, b, a (each node's newest is the last of its own).
    a.reserve_seqs(0).unwrap();
    b.reserve_seqs(0).unwrap();
    let fa = a.reserve_seqs(0).unwrap();
    let prune_all = |s: &PgStore| while s.prune_log(u64::MAX, 1000).unwrap() > 0 {};
    let blocks = || sql(&db, "SELECT node FROM seq_blocks ORDER BY first_seq");

    // Superseded just now: kept (the engine may still finish a tick there,
    // a reader starting at the log's end reads them).
    prune_all(&a);
    assert_eq!(blocks(), ["a", "b", "a", "b", "a"]);

    sql(
        &db,
        "UPDATE seq_blocks SET reserved_at = now() - interval '1 hour'",
    );
    prune_all(&a);
    // The first three merged: b's second block is its newest.
    assert_eq!(blocks(), ["", "b", "a"]);
    assert_eq!(
        sql(
            &db,
            "SELECT first_seq || ':' || pruned_to FROM seq_blocks WHERE node = ''"
        ),
        [format!("1:{}", SEQ_BLOCK + 1)]
    );
    prune_all(&a);
    assert_eq!(blocks(), ["", "b", "a"], "nothing more to merge");
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
    assert!(a.log_pruned_at(1).unwrap() && a.log_pruned_at(SEQ_BLOCK + 1).unwrap());
    let segments = a.log_segments(SegmentsAlso::After(0)).unwrap();
    assert!(
        segments.iter().all(|s| s.first > 2 * SEQ_BLOCK),
        "{segments:?}"
    );
    assert_eq!(segments.len(), 2);

    // a's batch numbered in its first block: refused, nothing written.
    let before = footprint(&db, &a);
    let err = a
        .commit_batch(&edit(&mut fork(&stale), &[chunk_in(ra, 1)], 3))
        .unwrap_err();
    assert!(matches!(err, StoreError::SeqsRetired { .. }), "{err}");
    assert_eq!(footprint(&db, &a), before);
    // Numbered in its newest block, it goes through.
    let mut on_a = Seq {
        last_seq: fa,
        ..fork(&stale)
    };
    a.commit_batch(&edit(&mut on_a, &[chunk_in(ra, 1)], 4))
        .unwrap();
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// Blocks a, b, a, b, a with the log pruned, all superseded an hour ago
/// (the next pass's compaction merges the first three), and each node's
/// world as it was after its one commit (its next batch is numbered in
/// its first block).
fn old_blocks(db: &PgDb) -> (PgStore, PgStore, Seq, Seq) {
    let (a, b, mut wa, mut wb) = two_nodes(db);
    a.commit_batch(&edit(&mut wa, &[chunk_in(region(0, 0), 0)], 1))
        .unwrap();
    b.commit_batch(&edit(&mut wb, &[chunk_in(region(1, 0), 0)], 2))
        .unwrap();
    a.reserve_seqs(0).unwrap();
    b.reserve_seqs(0).unwrap();
    a.reserve_seqs(0).unwrap();
    while a.prune_log(u64::MAX, 1000).unwrap() > 0 {}
    sql(
        db,
        "UPDATE seq_blocks SET reserved_at = now() - interval '1 hour'",
    );
    (a, b, wa, wb)
}

/// Waits until `n` sessions of `db` wait for `what` (a `wait_event_type`).
fn waiting(db: &PgDb, what: &str, n: usize) {
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let q = format!(
        "SELECT count(*) FROM pg_stat_activity \
         WHERE datname = current_database() AND wait_event_type = '{what}'"
    );
    while sql(db, &q)[0].parse::<usize>().unwrap() < n {
        assert!(
            std::time::Instant::now() < deadline,
            "no {n} waiting on {what}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn seq_block_nodes(db: &PgDb) -> Vec<String> {
    sql(db, "SELECT node FROM seq_blocks ORDER BY first_seq")
}

/// A commit past its fence holds its seq block's row: a compaction then
/// gives up after its lock timeout and merges nothing, the commit lands,
/// and the next pass (its entry pruned) merges.
#[test]
fn a_compaction_leaves_a_block_a_commit_holds() {
    let Some(db) = database("lease_blocks_held") else {
        return;
    };
    let (a, _b, wa, _wb) = old_blocks(&db);
    // The commit stops at its first chunk write, after the fence.
    let (release, holder) =
        store_common::hold_until_told(&db, "LOCK TABLE chunks, chunk_deltas IN SHARE MODE");
    std::thread::scope(|s| {
        let commit =
            s.spawn(|| a.commit_batch(&edit(&mut fork(&wa), &[chunk_in(region(0, 0), 1)], 3)));
        waiting(&db, "Lock", 1);
        assert_eq!(a.prune_log(u64::MAX, 1000).unwrap(), 0);
        assert_eq!(seq_block_nodes(&db), ["a", "b", "a", "b", "a"]);
        drop(release);
        holder.join().unwrap();
        commit.join().unwrap().unwrap();
    });
    assert_eq!(sql(&db, "SELECT seq FROM edit_log"), ["2"]);
    while a.prune_log(u64::MAX, 1000).unwrap() > 0 {}
    assert_eq!(seq_block_nodes(&db), ["", "b", "a"]);
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// Commits that reach their seq block while a compaction merges it wait
/// for the merge and are refused, whether their block's row was the one
/// kept (a's) or one deleted (b's); nothing of theirs is written.
#[test]
fn a_commit_meeting_a_compaction_of_its_block_is_refused() {
    let Some(db) = database("lease_blocks_merging") else {
        return;
    };
    let (a, b, wa, wb) = old_blocks(&db);
    // The compaction stops at its merge, its rows locked, until told.
    sql(
        &db,
        "CREATE TABLE go (x int); \
         CREATE FUNCTION hold_merge() RETURNS trigger AS $$ BEGIN \
             WHILE NOT EXISTS (SELECT 1 FROM go) LOOP PERFORM pg_sleep(0.01); END LOOP; \
             RETURN NEW; END $$ LANGUAGE plpgsql; \
         CREATE TRIGGER hold_merge BEFORE UPDATE ON seq_blocks FOR EACH ROW \
             WHEN (NEW.node = '') EXECUTE FUNCTION hold_merge()",
    );
    let before = footprint(&db, &a);
    std::thread::scope(|s| {
        let pass = s.spawn(|| a.prune_log(u64::MAX, 1000));
        waiting(&db, "Timeout", 1);
        let on_a =
            s.spawn(|| a.commit_batch(&edit(&mut fork(&wa), &[chunk_in(region(0, 0), 1)], 3)));
        let on_b =
            s.spawn(|| b.commit_batch(&edit(&mut fork(&wb), &[chunk_in(region(1, 0), 1)], 4)));
        waiting(&db, "Lock", 2);
        sql(&db, "INSERT INTO go VALUES (1)");
        assert_eq!(pass.join().unwrap().unwrap(), 0);
        for err in [on_a.join().unwrap(), on_b.join().unwrap()] {
            let err = err.unwrap_err();
            assert!(matches!(err, StoreError::SeqsRetired { .. }), "{err}");
        }
    });
    sql(
        &db,
        "DROP TRIGGER hold_merge ON seq_blocks; DROP FUNCTION hold_merge(); DROP TABLE go",
    );
    assert_eq!(seq_block_nodes(&db), ["", "b", "a"]);
    assert_eq!(footprint(&db, &a), before);
    let report = plain(&db).check().unwrap();
    assert!(report.is_ok(), "{report:?}");
}

/// A region row another session holds locked (a node paused in its
/// commit) holds up no release: the others are let go at once, that one
/// stays this node's (booked and leased) and a later release, the row
/// free, lets it go. So does the release at shutdown, which leaves it to
/// run out.
#[test]
fn a_release_skips_a_region_row_another_session_holds() {
    let Some(db) = database("lease_release_locked") else {
        return;
    };
    let a = node(&db, "a");
    let (r0, r1) = (region(0, 0), region(1, 0));
    granted(&a, r0);
    granted(&a, r1);
    let owners = || {
        sql(
            &db,
            "SELECT COALESCE(owner, '-') FROM regions ORDER BY region_x",
        )
    };
    let lock_r1 = "SELECT 1 FROM regions WHERE region_x = 1 AND region_z = 0 FOR UPDATE";
    let released_while_locked = |release: &(dyn Fn() -> Result<u64, StoreError> + Sync)| {
        let (unlock, holder) = store_common::hold_until_told(&db, lock_r1);
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::scope(|s| {
            s.spawn(|| tx.send(release()).unwrap());
            let done = rx.recv_timeout(Duration::from_secs(5));
            drop(unlock);
            holder.join().unwrap();
            done.expect("the release waited for the locked row")
                .unwrap()
        })
    };

    released_while_locked(&|| a.release_regions(&regions(&[r0, r1])).map(|()| 0));
    assert_eq!(owners(), ["-", "a"]);
    assert_eq!(
        a.leases().unwrap().held().into_keys().collect::<Vec<_>>(),
        [r1]
    );
    a.release_regions(&regions(&[r1])).unwrap();
    assert_eq!(owners(), ["-", "-"]);
    assert!(a.leases().unwrap().held().is_empty());

    granted(&a, r0);
    granted(&a, r1);
    assert_eq!(released_while_locked(&|| a.release_leases()), 1);
    assert_eq!(owners(), ["-", "a"]);
}
