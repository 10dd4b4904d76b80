//! One bot's life: connect (and reconnect), find footing, walk, edit by
//! role, and at the end compare its replica with the server's world.

use std::collections::HashMap;
use std::future::Future;
use std::hash::BuildHasher;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use strata_protocol::reject_label;
use strata_protocol::{ErrorCode, PositionRefusal, RejectReason, Start, PROTOCOL_VERSION};
use strata_terrain::{ChunkPos, Edit, FixedVec3, VoxelPos};
use tokio::sync::watch;
use tracing::debug;

use super::footing;
use super::rng::Rng;
use super::stats::Stats;
use super::walker::Walker;
use super::{Fleet, Phase, Role, VerifyMode};
use crate::client::{Acked, Arrival, Client, ClientError, ClientOptions, Verdict};
use crate::prediction::PredictionStats;
use crate::replica::ReplicaStats;
use crate::Notice;

/// Time between a bot's steps.
pub const STEP: Duration = Duration::from_millis(100);
/// Steps between position reports.
pub const POSITION_EVERY: u32 = 2;
/// Steps between pings (the server answers each with a pong).
pub const PING_EVERY: u32 = 5;
/// Steps between matching delta arrivals with edits.
pub const DRAIN_EVERY: u32 = 10;
/// How long a bot waits for the ground under it to arrive.
pub const SPAWN_TIMEOUT: Duration = Duration::from_secs(30);
/// One connection attempt, handshake included.
pub const CONNECT_ATTEMPT_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a bot keeps trying to reconnect.
pub const RECONNECT_WINDOW: Duration = Duration::from_secs(60);
/// Pause between connection attempts.
pub const RECONNECT_DELAY: Duration = Duration::from_millis(250);
/// Delta arrivals whose edit is not acknowledged yet are kept this long.
pub const ARRIVAL_MATCH_WINDOW: Duration = Duration::from_secs(30);
/// Chunk requests a bot has in flight during its end-of-run check.
pub const CHECK_WINDOW: usize = 4;
/// A chunk request unanswered this long is sent again (a full server
/// command queue drops requests).
pub const CHECK_RETRY: Duration = Duration::from_secs(3);

/// An edit in flight: its verdict and when it was sent.
type PendingEdit<'a> = dyn Future<Output = (Result<Acked, ClientError>, Instant)> + Send + 'a;

/// What the session loop does after a step.
enum Next {
    Continue,
    Edit,
    Done,
}

/// The session loop's state.
struct Loop {
    steps: u32,
    subscribed: ChunkPos,
    last_bytes: u64,
    next_edit: Instant,
    interval: Option<Duration>,
    /// This bot's offset into each edit interval, so edits spread out.
    edit_offset: Duration,
    /// When this bot starts walking and editing: the bots start one by one
    /// over the first interval, not all at the same instant.
    active_from: Instant,
    pings: u64,
    /// The region (x, z) the feet were last in.
    region: Option<(i32, i32)>,
}

/// What one bot reports at the end, over all its connections.
#[derive(Debug, Default)]
pub struct BotOutcome {
    pub stalled: bool,
    pub connected_at_end: bool,
    pub replica: ReplicaStats,
    pub bytes_in: u64,
    pub bytes_out: u64,
    /// Hash of every (chunk, version) any of its replicas held (the first
    /// connection's, where two differ: that counts in `order_violations`).
    pub version_hashes: HashMap<(ChunkPos, u64), u64>,
    /// Newest version of each chunk its connections to `newest_from` so
    /// far received.
    newest: HashMap<ChunkPos, u64>,
    /// The node those connections were to: another node may stream an
    /// older copy of a chunk in a region it does not hold (PROTOCOL.md,
    /// clusters), so a move starts the comparison afresh.
    newest_from: Option<SocketAddr>,
    /// Steps where a chunk's version went backwards in one replica, chunks
    /// a later connection received older than an earlier one had, and
    /// (chunk, version) pairs two of its connections received with
    /// different contents.
    pub order_violations: u64,
    /// Versions held by the last replica.
    pub final_versions: HashMap<ChunkPos, u64>,
    /// Chunks (or, for a bot that never checked, 1) not compared at the end.
    pub unverified: u64,
    /// Its predictions, over all its connections (with `predict`).
    pub prediction: PredictionStats,
    verified: bool,
    /// Whether it was counted joined and checked (shared with
    /// [`CountOnPanic`], so a bot is counted once either way).
    counted: Arc<Counted>,
}

/// A bot's marks in the fleet's counts.
#[derive(Debug, Default)]
struct Counted {
    ready: AtomicBool,
    finished: AtomicBool,
}

impl Counted {
    /// Adds the bot to the fleet's joined count, once.
    fn ready(&self, fleet: &Fleet) {
        if !self.ready.swap(true, Ordering::Relaxed) {
            fleet.ready.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Adds the bot to the fleet's checked count, once.
    fn finished(&self, fleet: &Fleet) {
        if !self.finished.swap(true, Ordering::Relaxed) {
            fleet.finished.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl BotOutcome {
    /// Folds a finished connection to `node` in.
    fn absorb(&mut self, client: &Client, node: SocketAddr) {
        self.on_node(node);
        self.bytes_in += client.bytes_in();
        self.bytes_out += client.bytes_out();
        let r = client.replica();
        self.replica += r.stats;
        if let (Some(history), Some(hashes)) = (r.history(), r.version_hashes()) {
            self.fold_history(history, hashes);
        }
        self.final_versions = r.chunks().map(|(p, h)| (p, h.version)).collect();
        drop(r);
        if let Some(p) = client.prediction_stats() {
            self.prediction.add(&p);
        }
    }

    /// The next connection folded in was to `node`: versions are compared
    /// across connections to one node only.
    fn on_node(&mut self, node: SocketAddr) {
        if self.newest_from != Some(node) {
            self.newest.clear();
            self.newest_from = Some(node);
        }
    }

    /// Folds one connection's received versions in: within it, a chunk's
    /// versions only go forward; across connections, a chunk is never
    /// received older than an earlier connection received it, and one
    /// (chunk, version) always has one content. Only versions received for
    /// a chunk count: one not held since (forgotten, out of view) has no
    /// newer version to contradict, and a resync or a new connection
    /// receives the chunk at the version it then had, never older.
    fn fold_history<S: BuildHasher, T: BuildHasher>(
        &mut self,
        history: &HashMap<ChunkPos, Vec<u64>, S>,
        hashes: &HashMap<(ChunkPos, u64), u64, T>,
    ) {
        for (pos, versions) in history {
            self.order_violations += versions.windows(2).filter(|w| w[1] <= w[0]).count() as u64;
            let (Some(&oldest), Some(&newest)) = (versions.iter().min(), versions.iter().max())
            else {
                continue;
            };
            let before = self.newest.entry(*pos).or_insert(oldest);
            if oldest < *before {
                self.order_violations += 1;
            }
            *before = (*before).max(newest);
        }
        for (key, hash) in hashes {
            let first = self.version_hashes.entry(*key).or_insert(*hash);
            if first != hash {
                self.order_violations += 1;
            }
        }
    }
}

/// How long a bot waits for `Arrived` after sending its ticket.
const ARRIVE_WAIT: Duration = Duration::from_secs(3);

/// Sends `ticket` and waits for the node's answer; a refusal (or none) is
/// logged, and the bot then starts as the node's `Welcome` says.
async fn arrive(c: &Client, ticket: strata_protocol::Ticket, bot: usize) {
    if !matches!(c.arrive_within(ticket, ARRIVE_WAIT).await, Ok(Some(_))) {
        debug!(bot, refusals = ?c.refusals(), "ticket not accepted");
    }
}

/// Counts a bot whose task panics as joined and checked (unless it was
/// already), so the fleet does not wait out its ramp and check timeouts
/// for it (the run counts it in `bots_failed`).
struct CountOnPanic(Arc<Fleet>, Arc<Counted>);

impl Drop for CountOnPanic {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.1.ready(&self.0);
            self.1.finished(&self.0);
        }
    }
}

/// The client's QUIC config with a per-stream receive window of `window`
/// bytes (`--stalled-window`; every stream, the control stream too): what
/// the server may have written to a stalled bot's updates stream before
/// flow control holds the rest in its queue.
/// The transport is otherwise `client_config_pinned`'s.
fn stalled_config(cert_der: &[u8], window: u32) -> Result<quinn::ClientConfig, ClientError> {
    use crate::tls::{CLIENT_DATAGRAM_BUFFER, CLIENT_RECEIVE_WINDOW, KEEP_ALIVE};
    let mut config = crate::tls::client_config_pinned(cert_der)?;
    let mut transport = quinn::TransportConfig::default();
    transport
        .keep_alive_interval(Some(KEEP_ALIVE))
        .max_concurrent_bidi_streams(quinn::VarInt::from_u32(0))
        .max_concurrent_uni_streams(quinn::VarInt::from_u32(1))
        .receive_window(quinn::VarInt::from_u32(CLIENT_RECEIVE_WINDOW))
        .datagram_receive_buffer_size(Some(CLIENT_DATAGRAM_BUFFER))
        .stream_receive_window(quinn::VarInt::from_u32(window));
    config.transport_config(Arc::new(transport));
    Ok(config)
}

/// Runs bot `id` until the run is done.
pub async fn run_bot(fleet: Arc<Fleet>, id: usize) -> BotOutcome {
    let counted = Arc::new(Counted::default());
    let _count_on_panic = CountOnPanic(fleet.clone(), counted.clone());
    let stalled = id < fleet.cfg.stalled;
    let mut bot = Bot {
        role: fleet.cfg.profile.role_of(id),
        phase: fleet.phase.subscribe(),
        rng: Rng::new(fleet.cfg.seed, id as u64),
        out: BotOutcome {
            stalled,
            counted,
            ..Default::default()
        },
        walker: None,
        arrivals: Vec::new(),
        server: fleet.cfg.server,
        ticket: None,
        move_to: None,
        fleet,
        id,
    };
    loop {
        let Some(client) = bot.connect().await else {
            break;
        };
        let fleet = bot.fleet.clone();
        let stats = &fleet.stats;
        stats.connected.fetch_add(1, Ordering::Relaxed);
        let result = bot.session(&client).await;
        stats.connected.fetch_sub(1, Ordering::Relaxed);
        bot.drain_arrivals(&client);
        bot.out.absorb(&client, bot.server);
        match result {
            Ok(()) => {
                bot.out.connected_at_end = !client.is_closed();
                client.close().await;
                break;
            }
            Err(_) if bot.move_to.is_some() => {
                // Told another node writes the region: move there, and
                // arrive with the newest ticket this node gave.
                bot.server = bot.move_to.take().expect("checked");
                debug!(bot = id, to = %bot.server, "moving to the region's node");
                Stats::add(&stats.handoffs, 1);
                client.close().await;
            }
            Err(e) => {
                debug!(bot = id, error = %e, "connection lost; reconnecting");
                Stats::add(&stats.reconnects, 1);
                if bot.server != fleet.cfg.server {
                    // A node moved to is gone: back to the first one.
                    bot.ticket = client.region_owners().and_then(|o| o.ticket);
                    bot.server = fleet.cfg.server;
                }
                client.abandon();
                tokio::time::sleep(RECONNECT_DELAY).await;
            }
        }
    }
    bot.finish();
    if !bot.out.verified && !stalled && bot.fleet.cfg.verify != VerifyMode::Off {
        bot.out.unverified = bot.out.unverified.max(1);
    }
    bot.out
}

struct Bot {
    fleet: Arc<Fleet>,
    id: usize,
    role: Role,
    phase: watch::Receiver<Phase>,
    rng: Rng,
    out: BotOutcome,
    walker: Option<Walker>,
    /// Delta arrivals not yet matched with their edit.
    arrivals: Vec<Arrival>,
    /// The node this bot connects to (`--follow-owners` moves it).
    server: SocketAddr,
    /// A ticket to arrive with at the next connection.
    ticket: Option<strata_protocol::Ticket>,
    /// Set by a `RegionElsewhere` verdict to move the bot there.
    move_to: Option<SocketAddr>,
}

impl Bot {
    fn phase(&self) -> Phase {
        *self.phase.borrow()
    }

    /// Counts this bot as done with the end-of-run check, once.
    fn finish(&mut self) {
        self.out.counted.finished(&self.fleet);
    }

    /// Connects, retrying within [`RECONNECT_WINDOW`]; `None` gives up.
    async fn connect(&mut self) -> Option<Client> {
        let start = Instant::now();
        let cfg = &self.fleet.cfg;
        loop {
            if self.phase() == Phase::Done || start.elapsed() > RECONNECT_WINDOW {
                return None;
            }
            let token = match cfg.tokens.token(&cfg.player_prefix, self.id) {
                Ok(t) => t,
                Err(e) => {
                    tracing::error!(bot = self.id, error = %e, "no token");
                    return None;
                }
            };
            let opts = ClientOptions {
                pool: self.fleet.pool.clone(),
                record_history: true,
                predict: cfg.predict,
                structures: Default::default(),
                track_changes: false,
                capabilities: cfg.capabilities,
                link_delay: cfg.link_delay,
                join_rate: Default::default(),
                // Delta latencies: `drain_arrivals` takes them every step.
                record_arrivals: true,
            };
            let attempt = {
                let _slot = self.fleet.connect_slots.acquire().await.ok()?;
                let connect = async {
                    match cfg.stalled_window.filter(|_| self.out.stalled) {
                        Some(window) => {
                            let config = stalled_config(&cfg.cert_der, window)?;
                            Client::connect_with(self.server, config, &token, PROTOCOL_VERSION)
                                .await
                        }
                        None => {
                            Client::connect_opts(self.server, &cfg.cert_der, &token, opts).await
                        }
                    }
                };
                tokio::time::timeout(CONNECT_ATTEMPT_TIMEOUT, connect).await
            };
            match attempt {
                Ok(Ok(c)) => {
                    if let Some(t) = self.ticket.take() {
                        arrive(&c, t, self.id).await;
                    }
                    let (hx, hz) = cfg.home(self.id);
                    let home = FixedVec3::from_f64([hx, 0.0, hz])?;
                    if self.walker.is_none() && !c.welcome().start.admits_column(home) {
                        tracing::error!(
                            bot = self.id,
                            start = ?c.welcome().start,
                            "the bot's home lies outside the server's spawn area \
                             (widen [validation.spawn])"
                        );
                        return None;
                    }
                    return Some(c);
                }
                Ok(Err(ClientError::Refused { code, message }))
                    if matches!(
                        code,
                        ErrorCode::BadToken
                            | ErrorCode::ExpiredToken
                            | ErrorCode::UnsupportedVersion
                    ) =>
                {
                    tracing::error!(bot = self.id, ?code, message, "server refused the bot");
                    return None;
                }
                Ok(Err(e)) => debug!(bot = self.id, error = %e, "connect failed"),
                Err(_) => debug!(bot = self.id, "connect timed out"),
            }
            // A node moved to that cannot be reached: back to the first.
            self.server = cfg.server;
            tokio::time::sleep(RECONNECT_DELAY).await;
        }
    }

    /// Counts the server's position refusals and moves the bot back to
    /// where the server holds it, as a game client would: its walk went
    /// somewhere the server did not follow (through a wall built since its
    /// replica last heard, a stall), so reports from there stay refused.
    /// Returns whether it moved the bot.
    fn take_refusals(&mut self, client: &Client) -> bool {
        let mut moved = false;
        while let Some(n) = client.pop_notice() {
            let Notice::PositionRefused { reason, at, .. } = n else {
                continue;
            };
            self.fleet
                .stats
                .position_refused(strata_protocol::refusal_label(&reason));
            if let (Some(at), Some(w)) = (at, self.walker.as_mut()) {
                w.feet = at.to_f64();
                moved = true;
                // Terrain its replica had not seen yet: go elsewhere, not
                // at the same wall again.
                if matches!(
                    reason,
                    PositionRefusal::PathBlocked { .. }
                        | PositionRefusal::InsideSolid { .. }
                        | PositionRefusal::TooHigh { .. }
                ) {
                    w.new_waypoint(&mut self.rng);
                }
            }
        }
        moved
    }

    /// One connection: `Ok` when the run is done, `Err` when it was lost.
    async fn session(&mut self, client: &Client) -> Result<(), ClientError> {
        let radius = self.fleet.cfg.view_radius;
        let (hx, hz) = self.fleet.cfg.home(self.id);
        let own = self.walker.as_ref().map(|w| w.feet);
        let (sx, sz, hint) = start_spot(client.welcome().start, own)
            .unwrap_or_else(|| (hx, hz, self.fleet.surface_hint(client.welcome(), hx, hz)));
        let start_chunk = VoxelPos::new(sx as i32, hint as i32, sz as i32).chunk();
        client.subscribe(start_chunk, radius).await?;
        let feet = self.await_footing(client, sx, sz, hint).await?;
        let walker = self.walker.get_or_insert_with(|| {
            let half = if self.role.roams() {
                self.fleet.cfg.area_side() as f64 / 2.0
            } else {
                super::CELL as f64 / 2.0
            };
            let (cx, cz) = if self.role.roams() {
                let o = self.fleet.cfg.area_origin;
                (o.0 as f64 + half, o.1 as f64 + half)
            } else {
                (hx, hz)
            };
            Walker {
                feet,
                waypoint: [sx, sz],
                bounds: [cx - half, cx + half, cz - half, cz + half],
                speed: self.role.walk_speed(),
            }
        });
        walker.feet = feet;
        // Report a position before the first edit (edits need one).
        if let Some(p) = FixedVec3::from_f64(feet) {
            client.send_position(p)?;
        }
        let subscribed = walker.chunk();
        if subscribed != start_chunk {
            client.subscribe(subscribed, radius).await?;
        }
        if self.out.stalled {
            client.stop_reading_updates();
        }
        let interval = (self.fleet.cfg.edit_rate > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / self.fleet.cfg.edit_rate));
        // Spread the bots' edits over the first interval.
        let edit_offset = interval.map_or(Duration::ZERO, |i| i.mul_f64(self.rng.unit()));
        let mut st = Loop {
            steps: 0,
            subscribed,
            last_bytes: client.bytes_in(),
            next_edit: Instant::now() + edit_offset,
            interval,
            edit_offset,
            active_from: Instant::now() + edit_offset,
            pings: 0,
            region: None,
        };
        let mut ticker = tokio::time::interval(STEP);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        // The edit awaiting its verdict: the bot keeps walking and pinging.
        let mut pending: Option<Pin<Box<PendingEdit<'_>>>> = None;
        let result = loop {
            tokio::select! {
                (verdict, sent_at) = async { pending.as_mut().expect("guarded").await },
                    if pending.is_some() =>
                {
                    pending = None;
                    self.fleet.in_flight.fetch_sub(1, Ordering::Relaxed);
                    if let Err(e) = self.verdict(verdict, sent_at, client) {
                        break Err(e);
                    }
                }
                _ = ticker.tick() => match self.tick(client, &mut st).await {
                    Ok(Next::Continue) => {}
                    Ok(Next::Edit) if pending.is_none() => {
                        if let Some(edit) = self.prepare_edit(client) {
                            self.fleet.in_flight.fetch_add(1, Ordering::Relaxed);
                            let sent_at = Instant::now();
                            pending = Some(Box::pin(async move {
                                (client.edit_acked(edit).await, sent_at)
                            }));
                        }
                    }
                    // The slot fell due while the last edit awaits its
                    // verdict: no edit for it, and no latency measured;
                    // counted, so a slow server's omitted slots show.
                    Ok(Next::Edit) => Stats::add(&self.fleet.stats.edit_slots_skipped, 1),
                    Ok(Next::Done) => break Ok(()),
                    Err(e) => break Err(e),
                },
            }
        };
        if pending.is_some() {
            self.fleet.in_flight.fetch_sub(1, Ordering::Relaxed);
            Stats::add(&self.fleet.stats.edits_unanswered, 1);
        }
        result
    }

    /// One step of the session loop.
    async fn tick(&mut self, client: &Client, st: &mut Loop) -> Result<Next, ClientError> {
        st.steps = st.steps.wrapping_add(1);
        if client.is_closed() {
            return Err(client.closed().await);
        }
        if client.silent_for() > self.fleet.cfg.silence_limit {
            return Err(ClientError::Timeout("a sign of life from the server"));
        }
        if st.steps % PING_EVERY == 0 {
            st.pings += 1;
            client.ping(st.pings).await?;
        }
        if st.steps % DRAIN_EVERY == 0 {
            self.drain_arrivals(client);
        }
        let radius = self.fleet.cfg.view_radius;
        match self.phase() {
            Phase::Ramp => {
                self.out.counted.ready(&self.fleet);
                let b = client.bytes_in();
                if b != st.last_bytes {
                    st.last_bytes = b;
                    self.fleet.touch();
                }
                st.next_edit = Instant::now() + st.edit_offset;
                st.active_from = st.next_edit;
            }
            Phase::Run if Instant::now() < st.active_from => {}
            Phase::Run => {
                if self.take_refusals(client) {
                    // Moved back: not a walk into another region.
                    st.region = None;
                }
                let walker = self.walker.as_mut().expect("set by session");
                walker.step(&client.replica(), STEP.as_secs_f64(), &mut self.rng);
                if st.steps % POSITION_EVERY == 0 {
                    if let Some(p) = FixedVec3::from_f64(walker.feet) {
                        client.send_position(p)?;
                    }
                }
                let chunk = walker.chunk();
                let side = self.fleet.cfg.region_chunks.max(1) as i32;
                let region = (chunk.x.div_euclid(side), chunk.z.div_euclid(side));
                if st.region.is_some_and(|r| r != region) {
                    Stats::add(&self.fleet.stats.region_crossings, 1);
                }
                st.region = Some(region);
                if chunk != st.subscribed {
                    st.subscribed = chunk;
                    client.subscribe(chunk, radius).await?;
                }
                if let Some(i) = st.interval {
                    let now = Instant::now();
                    if now >= st.next_edit {
                        // Slots that fell due since the one taken now (a
                        // late step, or a rate above one edit a step) are
                        // skipped: counted, not made up for.
                        let late = now.saturating_duration_since(st.next_edit);
                        let missed = late.as_nanos() / i.as_nanos().max(1);
                        Stats::add(
                            &self.fleet.stats.edit_slots_skipped,
                            u64::try_from(missed).unwrap_or(u64::MAX),
                        );
                        st.next_edit = (st.next_edit + i).max(now);
                        return Ok(Next::Edit);
                    }
                }
            }
            Phase::Quiesce => {
                let b = client.bytes_in();
                if b != st.last_bytes {
                    st.last_bytes = b;
                    self.fleet.touch();
                }
            }
            Phase::Verify => {
                if !self.out.verified && !self.out.stalled {
                    self.verify(client).await?;
                }
                self.finish();
            }
            Phase::Done => return Ok(Next::Done),
        }
        Ok(Next::Continue)
    }

    /// Waits until the replica holds ground under `(x, z)`.
    async fn await_footing(
        &self,
        client: &Client,
        x: f64,
        z: f64,
        hint: f64,
    ) -> Result<[f64; 3], ClientError> {
        let start = Instant::now();
        loop {
            if let Some(f) = footing::stand(&client.replica(), x, z, hint) {
                return Ok(f);
            }
            if client.is_closed() {
                return Err(client.closed().await);
            }
            if start.elapsed() > SPAWN_TIMEOUT {
                return Err(ClientError::Timeout("the ground under the bot"));
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// The next edit aimed from the bot's position, if a target is in
    /// reach and sight.
    fn prepare_edit(&mut self, client: &Client) -> Option<Edit> {
        let stats = &self.fleet.stats;
        let feet = self.walker.as_ref().expect("walking").feet;
        let target = footing::pick_target(&client.replica(), feet, &mut self.rng);
        let Some(target) = target else {
            Stats::add(&stats.edits_skipped, 1);
            return None;
        };
        Stats::add(&stats.edits_sent, 1);
        Some(self.role.edit(target, &mut self.rng))
    }

    /// Records an edit's verdict; an error means the connection is lost.
    fn verdict(
        &mut self,
        result: Result<Acked, ClientError>,
        sent_at: Instant,
        client: &Client,
    ) -> Result<(), ClientError> {
        let stats = &self.fleet.stats;
        match result {
            Ok((Verdict::Accepted { seq }, changes)) => {
                stats.ack.record(sent_at.elapsed());
                Stats::add(&stats.edits_accepted, 1);
                self.fleet.accepted(seq, sent_at, self.id, &changes);
                Ok(())
            }
            Ok((Verdict::Rejected(reason), _)) => {
                debug!(bot = self.id, ?reason, "edit rejected");
                stats.reject(reject_label(&reason));
                if let RejectReason::RegionElsewhere {
                    region_x,
                    region_z,
                    addr,
                    ..
                } = &reason
                {
                    // Only for the region the bot stands in: an edit across
                    // a border is refused by its own region's node until the
                    // other hands its region over, and the other node would
                    // refuse it too.
                    let side = self.fleet.cfg.region_chunks.max(1) as i32;
                    let here = self.walker.as_ref().map(|w| {
                        let c = w.chunk();
                        (c.x.div_euclid(side), c.z.div_euclid(side))
                    });
                    let to = addr.parse::<SocketAddr>().ok();
                    // Without a ticket (this node never judged the bot
                    // where it stands: it appeared in the other node's
                    // region) it starts over there as a new player would.
                    let ticket = client.region_owners().and_then(|o| o.ticket);
                    if self.fleet.cfg.follow_owners
                        && here == Some((*region_x, *region_z))
                        && to.is_some_and(|a| a != self.server)
                    {
                        self.move_to = to;
                        self.ticket = ticket;
                        return Err(ClientError::Protocol("moving to the region's node".into()));
                    }
                }
                Ok(())
            }
            Err(e) => {
                Stats::add(&stats.edits_unanswered, 1);
                Err(e)
            }
        }
    }

    /// Matches delta arrivals with the edits that caused them.
    fn drain_arrivals(&mut self, client: &Client) {
        self.arrivals.extend(client.take_arrivals());
        if self.arrivals.is_empty() {
            return;
        }
        self.fleet.touch();
        let sent = self.fleet.sent.lock().expect("not poisoned");
        let me = self.id;
        let broadcast = &self.fleet.stats.broadcast;
        self.arrivals.retain(|a| match sent.get(&a.seq) {
            Some((at, author)) => {
                if *author != me {
                    broadcast.record(a.at.saturating_duration_since(*at));
                }
                false
            }
            None => a.at.elapsed() < ARRIVAL_MATCH_WINDOW,
        });
    }

    /// Asks the server for every held chunk and compares, a few requests
    /// at a time (the server's command queue is shared by every bot), and
    /// asks again for any the server has not answered after a while.
    async fn verify(&mut self, client: &Client) -> Result<(), ClientError> {
        let mode = self.fleet.cfg.verify;
        if mode == VerifyMode::Off {
            self.out.verified = true;
            return Ok(());
        }
        let mut queue: Vec<ChunkPos> = {
            let mut r = client.replica();
            let list: Vec<ChunkPos> = r
                .chunks()
                .filter(|(_, h)| mode == VerifyMode::All || h.version > 0)
                .map(|(p, _)| p)
                .collect();
            for p in &list {
                r.expect_check(*p);
            }
            list
        };
        let ask = |pos| async move {
            match mode {
                VerifyMode::All => client.full_snapshot(pos).await,
                _ => client.resync(pos).await,
            }
        };
        let mut outstanding: Vec<(ChunkPos, Instant)> = Vec::new();
        // Checks the server's withdrawal of the copy cancelled, until the
        // chunk is held again (then checked anew).
        let mut lost: Vec<ChunkPos> = Vec::new();
        let start = Instant::now();
        loop {
            {
                let mut r = client.replica();
                lost.extend(r.take_lost_checks());
                lost.retain(|&p| {
                    let again = r
                        .get(p)
                        .is_some_and(|h| mode == VerifyMode::All || h.version > 0);
                    if again {
                        r.expect_check(p);
                        queue.push(p);
                    }
                    !again
                });
                outstanding.retain(|(p, _)| r.is_checking(*p));
                queue.retain(|p| r.is_checking(*p));
            }
            while outstanding.len() < CHECK_WINDOW {
                let Some(pos) = queue.pop() else { break };
                ask(pos).await?;
                outstanding.push((pos, Instant::now()));
            }
            if outstanding.is_empty() && queue.is_empty() {
                break;
            }
            if start.elapsed() > self.fleet.cfg.verify_timeout || self.phase() == Phase::Done {
                break;
            }
            if client.is_closed() {
                return Err(client.closed().await);
            }
            for (pos, asked) in outstanding.iter_mut() {
                if asked.elapsed() > CHECK_RETRY {
                    ask(*pos).await?;
                    *asked = Instant::now();
                }
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        self.out.unverified += client.replica().checks_pending() as u64;
        // Withdrawn and not sent again by the end: not compared either.
        self.out.unverified += lost.len() as u64;
        self.out.verified = true;
        Ok(())
    }
}

/// Where a connection's bot starts (`x`, `z`, a height to look for
/// footing near), or `None` for its home: where the server holds the
/// player when it remembers it (after a reconnect too: a report it refused
/// or never heard left the bot's own feet elsewhere), else where the bot
/// last stood.
fn start_spot(start: Start, own: Option<[f64; 3]>) -> Option<(f64, f64, f64)> {
    match (start, own) {
        (Start::Resume { feet }, _) => {
            let [x, y, z] = feet.to_f64();
            Some((x, z, y))
        }
        (Start::Spawn { .. }, Some([x, y, z])) => Some((x, z, y)),
        (Start::Spawn { .. }, None) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One connection's received versions of each chunk (in order) and the
    /// hash of each (chunk, version), as its replica records them.
    type ConnHistory = (HashMap<ChunkPos, Vec<u64>>, HashMap<(ChunkPos, u64), u64>);

    /// One connection's record: each chunk's versions in the order
    /// received, with the hash each version had.
    fn conn(chunks: &[(ChunkPos, &[(u64, u64)])]) -> ConnHistory {
        let mut history = HashMap::new();
        let mut hashes = HashMap::new();
        for (pos, seen) in chunks {
            history.insert(*pos, seen.iter().map(|(v, _)| *v).collect());
            for (v, h) in *seen {
                hashes.insert((*pos, *v), *h);
            }
        }
        (history, hashes)
    }

    fn violations(conns: &[ConnHistory]) -> u64 {
        let mut out = BotOutcome::default();
        for (history, hashes) in conns {
            out.fold_history(history, hashes);
        }
        out.order_violations
    }

    #[test]
    fn a_resumed_bot_starts_where_the_server_holds_it() {
        let held = FixedVec3::from_f64([10.0, 5.0, 20.0]).unwrap();
        let resume = Start::Resume { feet: held };
        let spawn = Start::Spawn {
            x: 0,
            z: 0,
            radius: 8,
        };
        assert_eq!(
            start_spot(resume, Some([40.0, 9.0, 40.0])),
            Some((10.0, 20.0, 5.0))
        );
        assert_eq!(start_spot(resume, None), Some((10.0, 20.0, 5.0)));
        assert_eq!(
            start_spot(spawn, Some([40.0, 9.0, 40.0])),
            Some((40.0, 40.0, 9.0))
        );
        assert_eq!(start_spot(spawn, None), None);
    }

    #[test]
    fn reconnects_keep_each_chunk_version_and_its_contents() {
        let (a, b) = (ChunkPos::new(1, 0, 1), ChunkPos::new(2, 0, 1));
        let first = conn(&[(a, &[(0, 10), (1, 11), (2, 12)]), (b, &[(4, 40)])]);
        // Reconnected: a again at 2 (same contents) then 3; b not held
        // this time (out of view): nothing to contradict.
        let later = conn(&[(a, &[(2, 12), (3, 13)])]);
        assert_eq!(violations(&[first.clone(), later.clone()]), 0);
        // A chunk first received on the second connection, forgotten on
        // the third: fine too.
        let third = conn(&[(b, &[(5, 50)])]);
        assert_eq!(violations(&[first.clone(), later.clone(), third]), 0);
        // An acknowledged version lost in a crash, and the version number
        // reused with other contents.
        let reused = conn(&[(a, &[(2, 99), (3, 13)])]);
        assert_eq!(violations(&[first.clone(), reused]), 1);
        // The chunk back at an older version than the last connection had.
        let behind = conn(&[(a, &[(1, 11)])]);
        assert_eq!(violations(&[first.clone(), later, behind]), 1);
        // Going backwards within one connection still counts.
        let within = conn(&[(a, &[(3, 13), (2, 12)])]);
        assert_eq!(violations(&[within]), 1);
        // Another node may stream an older copy (a region it does not
        // hold): only connections to one node are compared.
        let node = |p: u16| SocketAddr::from(([127, 0, 0, 1], p));
        let mut out = BotOutcome::default();
        for (at, (history, hashes)) in [(1, first.clone()), (2, conn(&[(a, &[(1, 11)])]))] {
            out.on_node(node(at));
            out.fold_history(&history, &hashes);
        }
        assert_eq!(out.order_violations, 0);
        out.on_node(node(2));
        let (history, hashes) = conn(&[(a, &[(0, 10)])]);
        out.fold_history(&history, &hashes);
        assert_eq!(out.order_violations, 1, "older again on the same node");
        // A resync within a connection skips ahead: fine.
        let resynced = conn(&[(a, &[(2, 12), (4, 14)])]);
        assert_eq!(violations(&[first, resynced]), 0);
    }
}
