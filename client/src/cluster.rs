//! A player on a cluster of nodes that share one world
//! ([`ClusterClient`]). Each node writes some regions; every node tells
//! its sessions who writes each region their view overlaps
//! (`ServerMessage::RegionOwners`). The cluster client keeps one
//! connection per node named there (at most [`MAX_CLUSTER_NODES`], joined
//! no faster than [`JoinRate`] allows whatever a node names; one no longer
//! named nor routed to is closed), arriving at each with the
//! ticket the last message carried so the player continues where it
//! stands, reports every position to all of them, sends each edit to the
//! node that writes its region, and reads each chunk from that node's
//! replica (for a region let go, the last writer's while connected).
//!
//! Each connection's replica is whole and ordered on its own (every
//! node streams the view it is told), so walking across a border only
//! changes which replica a chunk is read from: nothing is resent.
//!
//! A view asked for ([`ClusterClient::subscribe`]) is the same on every
//! node: the cluster client moves it with the player itself
//! ([`moved_view`]) and asks every node for it there, so a node joined
//! later is asked for the view where it is, not where it was first asked
//! (which may be out of the player's reach by then). It moves only when a
//! new position has been sent since it was asked or last moved
//! ([`view_to_follow`]), so the client's reach (narrower than a node's by
//! the hysteresis) applies at the next position, not to a view a node
//! accepted; an admin's view stays where it was asked, as the server keeps
//! it. A node joined later is asked for the view the home node last
//! confirmed (`InterestComplete`, [`view_for_new_node`]): the client moves
//! on positions it sent, a node on positions it accepted.

use std::collections::{BTreeMap, BTreeSet};
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use strata_protocol::limits::MAX_REGION_OWNERS;
use strata_protocol::{RegionHolder, RegionOwner, RejectReason, Role, Ticket};
use strata_terrain::{Chunk, ChunkPos, Edit, FixedVec3, VoxelPos, CHUNK_SIZE};
use thiserror::Error;

use crate::client::{Acked, Client, ClientError, ClientOptions, SentEdit, Verdict};

/// Most nodes a cluster client keeps connections to.
pub const MAX_CLUSTER_NODES: usize = 8;
/// How long a new connection waits for its `Arrived`.
pub const ARRIVE_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a node that could not be joined is left alone.
pub const JOIN_BACKOFF: Duration = Duration::from_secs(2);
/// Most distinct node addresses one reroute looks up, and most names the
/// client keeps looked up.
const MAX_LOOKUPS: usize = 2 * MAX_CLUSTER_NODES;
/// Most routes kept: every node's `RegionOwners` at its limit, and as many
/// again learned from refusals and acks between two of them. A node naming
/// new regions in refusal after refusal adds none past it.
pub const MAX_ROUTES: usize = 2 * MAX_CLUSTER_NODES * MAX_REGION_OWNERS;
/// How long a name's lookup is used again (a failed one: [`JOIN_BACKOFF`]).
pub const RESOLVED_TTL: Duration = Duration::from_secs(60);

/// How fast one cluster client (one player) reaches out to destinations
/// it does not use yet: each handshake with a node it is not connected to
/// takes a token from a bucket of `burst`, refilled one per `every`; a name
/// looked up afresh takes the token its node's join then uses. Whatever a
/// node's `RegionOwners` or `RegionElsewhere` name, a player sends
/// handshakes or lookups to addresses of its choosing no faster than that.
/// A join left for lack of tokens is tried again at a later
/// [`ClusterClient::follow`] (a name from a refused edit, when the edit is
/// sent again); a join given up because no message names its node any
/// more leaves that address alone for [`JOIN_BACKOFF`]. A name whose
/// lookup is past [`RESOLVED_TTL`] keeps its address while no token is
/// left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JoinRate {
    /// Tokens when none was spent for a while: 0 joins no other node.
    pub burst: u32,
    /// One token back per this long (zero: no limit).
    pub every: Duration,
}

impl Default for JoinRate {
    /// [`MAX_CLUSTER_NODES`] at once (a cluster's worth, even by name),
    /// then one a second.
    fn default() -> Self {
        Self {
            burst: MAX_CLUSTER_NODES as u32,
            every: Duration::from_secs(1),
        }
    }
}

/// A [`JoinRate`]'s tokens.
#[derive(Debug)]
struct JoinBucket {
    rate: JoinRate,
    tokens: u32,
    /// When the last token came back (or the bucket was last full).
    since: Instant,
}

impl JoinBucket {
    fn new(rate: JoinRate, now: Instant) -> Self {
        Self {
            rate,
            tokens: rate.burst,
            since: now,
        }
    }

    /// Whether [`Self::take`] would give a token at `now`.
    fn ready(&self, now: Instant) -> bool {
        self.rate.every.is_zero()
            || self.tokens > 0
            || (self.rate.burst > 0 && now.saturating_duration_since(self.since) >= self.rate.every)
    }

    /// Takes a token if there is one.
    fn take(&mut self, now: Instant) -> bool {
        if self.rate.every.is_zero() {
            return true;
        }
        let every = self.rate.every.as_nanos();
        let earned = now.saturating_duration_since(self.since).as_nanos() / every;
        if earned > 0 {
            let tokens = u128::from(self.tokens) + earned;
            if tokens >= u128::from(self.rate.burst) {
                self.tokens = self.rate.burst;
                self.since = now;
            } else {
                self.tokens = tokens as u32;
                // earned < burst here, so this fits.
                self.since += self.rate.every * earned as u32;
            }
        }
        if self.tokens == 0 {
            return false;
        }
        self.tokens -= 1;
        true
    }
}

/// A node's last `RegionOwners`, numbered in arrival order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegionOwners {
    /// 1 for the first message on a connection, then one more each.
    pub serial: u64,
    pub region_chunks: u32,
    pub regions: Vec<RegionOwner>,
    pub ticket: Option<Ticket>,
    /// The sending node's id.
    pub node: String,
}

/// What [`ClusterClient::next_hop`] makes of a node's answer to an edit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NextHop {
    /// The answer stands.
    Done,
    /// Send the edit again, to this connected node.
    Again(SocketAddr),
}

/// A `NodeFull` refusal: [`ClusterClient::next_hop`] passes the edit on.
pub fn is_node_full(acked: &Acked) -> bool {
    matches!(acked.0, Verdict::Rejected(RejectReason::NodeFull { .. }))
}

/// Why the cluster client could not go on.
#[derive(Debug, Error)]
pub enum ClusterError {
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("node address {0:?} does not resolve")]
    BadAddress(String),
    #[error("already connected to {MAX_CLUSTER_NODES} nodes; {0} is one more")]
    TooManyNodes(SocketAddr),
    #[error("node {0} did not accept the ticket in time")]
    NotArrived(SocketAddr),
}

/// A [`ClusterClient`]'s connections and routes at one moment.
#[derive(Debug, Clone)]
pub struct ClusterView {
    pub home: SocketAddr,
    pub nodes: BTreeMap<SocketAddr, Arc<Client>>,
    region_chunks: Option<u32>,
    routes: BTreeMap<(i32, i32), SocketAddr>,
}

impl ClusterView {
    /// The node that writes the region of `pos`, as last told; the home
    /// node when none is known or connected.
    pub fn route(&self, pos: ChunkPos) -> SocketAddr {
        self.region_chunks
            .and_then(|side| self.routes.get(&region_of(pos, side)))
            .filter(|a| self.nodes.contains_key(a))
            .copied()
            .unwrap_or(self.home)
    }

    /// The connection whose replica is current for `pos`.
    pub fn client_for(&self, pos: ChunkPos) -> &Arc<Client> {
        &self.nodes[&self.route(pos)]
    }

    /// Whether every chunk routes the same under `other`.
    pub fn routes_like(&self, other: &ClusterView) -> bool {
        self.home == other.home
            && self.region_chunks == other.region_chunks
            && self.routes == other.routes
            && self.nodes.keys().eq(other.nodes.keys())
    }
}

/// A region's coordinates: chunk x and z divided (floor) by the side.
fn region_of(pos: ChunkPos, side: u32) -> (i32, i32) {
    // In i64: any u32 side is positive there, and the quotient fits i32.
    let side = i64::from(side.max(1));
    let div = |v: i32| i64::from(v).div_euclid(side) as i32;
    (div(pos.x), div(pos.z))
}

/// Whether `node`'s last `RegionOwners` says it holds `region` itself.
fn holds_here(node: &Client, region: (i32, i32)) -> bool {
    node.region_owners().is_some_and(|o| {
        o.regions
            .iter()
            .any(|r| (r.region_x, r.region_z) == region && r.holder == RegionHolder::Here)
    })
}

/// The voxel an edit is routed by: its centre, box corner or origin
/// ([`Edit::anchor`], which the nodes use too).
pub fn edit_anchor(edit: &Edit) -> VoxelPos {
    edit.anchor()
}

/// Voxels the feet must be past where a view asked for may reach before
/// it moves to them (the protocol's margin, PROTOCOL.md "Interest").
pub const RECENTRE_MARGIN: i32 = 4;

/// Where a view asked for, `radius` chunks around `center`, goes once the
/// player's feet are at `feet`: `None` (it stays) while the feet voxel is
/// fewer than [`RECENTRE_MARGIN`] voxels past every chunk within `reach =
/// view_radius - min(radius, view_radius)` chunks (Chebyshev) of `center`
/// on its farthest axis, else the feet voxel's chunk (the radius kept).
///
/// A node's own rule is the same with `reach` larger by its hysteresis,
/// which the `Welcome` does not give: moved by this rule, a view never
/// waits for a node to move it (whatever the hysteresis), so the view the
/// client last asked for is the one every node streams.
pub fn moved_view(
    center: ChunkPos,
    radius: u8,
    view_radius: u8,
    feet: FixedVec3,
) -> Option<ChunkPos> {
    let reach = i64::from(view_radius - radius.min(view_radius));
    let side = i64::from(CHUNK_SIZE);
    let past = |v: i32, c: i32| {
        let lo = (i64::from(c) - reach) * side;
        let hi = (i64::from(c) + reach + 1) * side - 1;
        (lo - i64::from(v)).max(i64::from(v) - hi).max(0)
    };
    let at = VoxelPos::new(
        feet.x.floor_voxel(),
        feet.y.floor_voxel(),
        feet.z.floor_voxel(),
    );
    let far = past(at.x, center.x)
        .max(past(at.y, center.y))
        .max(past(at.z, center.z));
    (far >= i64::from(RECENTRE_MARGIN)).then(|| at.chunk())
}

/// Where [`ClusterClient::follow`] moves the view asked for (`asked`:
/// centre, radius): `None` for an admin (the server keeps an admin's view
/// wherever it was asked), while no position was sent, while the last
/// position sent (`feet`) is the one it was asked or last moved at
/// (`checked`), so a view a node accepted past the client's reach is not
/// undone before the player moves, else as [`moved_view`] says.
pub fn view_to_follow(
    asked: Option<(ChunkPos, u8)>,
    role: Role,
    feet: Option<FixedVec3>,
    checked: Option<FixedVec3>,
    view_radius: u8,
) -> Option<ChunkPos> {
    let (center, radius) = asked?;
    let feet = feet?;
    if role == Role::Admin || checked == Some(feet) {
        return None;
    }
    moved_view(center, radius, view_radius, feet)
}

/// The view a node just joined is asked for: the one the home node last
/// confirmed (`loaded`, its last `InterestComplete`) when it has the
/// radius asked (a node moves the view on positions it accepted, the
/// client on positions it sent, which may be lost or refused), else the
/// view asked for where it is now; none while no view was asked.
pub fn view_for_new_node(
    asked: Option<(ChunkPos, u8)>,
    loaded: Option<(ChunkPos, u8)>,
) -> Option<(ChunkPos, u8)> {
    let asked = asked?;
    Some(loaded.filter(|l| l.1 == asked.1).unwrap_or(asked))
}

/// Longest a node's name may take to resolve, and all the names of one
/// reroute together: names a server hands out never stall the session's
/// commands for longer.
pub const RESOLVE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

async fn resolve(addr: &str) -> Result<SocketAddr, ClusterError> {
    if let Ok(a) = addr.parse() {
        return Ok(a);
    }
    // IPv4 first: "localhost" often resolves to ::1 first, and a node
    // listens on 127.0.0.1 by default.
    tokio::time::timeout(RESOLVE_TIMEOUT, tokio::net::lookup_host(addr))
        .await
        .ok()
        .and_then(Result::ok)
        .and_then(|a| a.min_by_key(SocketAddr::is_ipv6))
        .ok_or_else(|| ClusterError::BadAddress(addr.to_string()))
}

/// Names looked up: what each gave, and when.
type Resolved = BTreeMap<String, (Option<SocketAddr>, Instant)>;

/// A round of name lookups: the names looked up before, the tokens fresh
/// ones take, and the addresses a fresh lookup found (their join is paid).
struct Lookups<'a> {
    resolved: &'a mut Resolved,
    joins: &'a mut JoinBucket,
    prepaid: &'a mut BTreeSet<SocketAddr>,
    /// A name was left for lack of tokens.
    owed: bool,
}

/// How a kept lookup stands.
enum Kept {
    /// Within its time: use it.
    Fresh(Option<SocketAddr>),
    /// Past its time, but an address: used while no token is left.
    Stale(SocketAddr),
    /// None kept, or a failure past its time.
    Missing,
}

impl Lookups<'_> {
    /// How the lookup of `name` kept stands at `now`.
    fn kept(&self, name: &str, now: Instant) -> Kept {
        let Some(&(found, at)) = self.resolved.get(name) else {
            return Kept::Missing;
        };
        let age = now.saturating_duration_since(at);
        match found {
            Some(a) if age < RESOLVED_TTL => Kept::Fresh(Some(a)),
            Some(a) => Kept::Stale(a),
            None if age < JOIN_BACKOFF => Kept::Fresh(None),
            None => Kept::Missing,
        }
    }

    /// Keeps a lookup, dropping the oldest past [`MAX_LOOKUPS`].
    fn keep(&mut self, name: String, found: Option<SocketAddr>, at: Instant) {
        self.resolved.insert(name, (found, at));
        while self.resolved.len() > MAX_LOOKUPS {
            let oldest = self
                .resolved
                .iter()
                .min_by_key(|(_, (_, at))| *at)
                .map(|(n, _)| n.clone());
            match oldest {
                Some(n) => self.resolved.remove(&n),
                None => break,
            };
        }
    }
}

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `name` as an address: an address as it is, a name from the lookups
/// kept, or looked up for a [`JoinRate`] token by `until` (which also pays
/// the join of what it finds). With no token left, or past `until`, a
/// name kept past its time keeps its last address; otherwise `None`, which
/// `state` then owes. A name that does not resolve is `None` for
/// [`JOIN_BACKOFF`].
async fn look_up(
    state: &std::sync::Mutex<Lookups<'_>>,
    name: String,
    now: Instant,
    until: tokio::time::Instant,
) -> Option<SocketAddr> {
    if let Ok(found) = name.parse() {
        return Some(found);
    }
    let stale = match lock(state).kept(&name, now) {
        Kept::Fresh(found) => return found,
        Kept::Stale(a) => Some(a),
        Kept::Missing => None,
    };
    {
        let mut l = lock(state);
        if tokio::time::Instant::now() >= until || !l.joins.take(now) {
            l.owed |= stale.is_none();
            return stale;
        }
    }
    let Ok(result) = tokio::time::timeout_at(until, resolve(&name)).await else {
        // Out of time for this round, not a name that does not resolve.
        lock(state).owed |= stale.is_none();
        return stale;
    };
    let found = result.ok();
    let mut l = lock(state);
    l.keep(name, found, Instant::now());
    if let Some(a) = found {
        l.prepaid.insert(a);
    }
    found
}

/// Routes built from every connected node's last word.
#[derive(Debug, Default)]
struct Routing {
    routes: BTreeMap<(i32, i32), SocketAddr>,
    /// The nodes named, at most [`MAX_CLUSTER_NODES`].
    named: Vec<SocketAddr>,
}

/// Routes `region` to `to`: a region known already is routed anew; a new
/// one only while fewer than [`MAX_ROUTES`] are kept (past it the edit
/// still reaches its node, the route is not remembered).
fn learn_route(routes: &mut BTreeMap<(i32, i32), SocketAddr>, region: (i32, i32), to: SocketAddr) {
    if routes.len() < MAX_ROUTES || routes.contains_key(&region) {
        routes.insert(region, to);
    }
}

/// Builds the routes from `latest`: another node's word first, each
/// node's word on itself last, since a node knows best what it holds. A
/// region reported free keeps its route in `kept` (routes to connected
/// nodes only): the last writer's replica holds its newest versions,
/// other nodes' copies may be older. Messages with more than
/// `MAX_REGION_OWNERS` regions are ignored; each distinct address is
/// looked up once, and new ones only while fewer than
/// [`MAX_CLUSTER_NODES`] nodes are named (and [`MAX_LOOKUPS`] tried).
async fn build_routes<F, Fut>(
    latest: &[(SocketAddr, RegionOwners)],
    kept: &BTreeMap<(i32, i32), SocketAddr>,
    lookup: F,
) -> Routing
where
    F: Fn(String) -> Fut,
    Fut: Future<Output = Option<SocketAddr>>,
{
    let mut out = Routing::default();
    // The nodes connected, by their own ids: another node naming one of
    // them at another address (a load balancer's, IPv6 for IPv4) means
    // that connection, not a second session of the player there (which
    // would end the first).
    let connected: BTreeMap<&str, SocketAddr> = latest
        .iter()
        .filter(|(_, o)| !o.node.is_empty())
        .map(|(from, o)| (o.node.as_str(), *from))
        .collect();
    let mut looked: BTreeMap<&str, Option<SocketAddr>> = BTreeMap::new();
    let mut free = Vec::new();
    let valid = || {
        latest
            .iter()
            .filter(|(_, o)| o.regions.len() <= MAX_REGION_OWNERS)
    };
    for (_, o) in valid() {
        for r in &o.regions {
            let region = (r.region_x, r.region_z);
            let addr = match &r.holder {
                RegionHolder::Node { node, .. } if connected.contains_key(node.as_str()) => {
                    let a = connected[node.as_str()];
                    out.routes.insert(region, a);
                    if out.named.len() < MAX_CLUSTER_NODES && !out.named.contains(&a) {
                        out.named.push(a);
                    }
                    continue;
                }
                RegionHolder::Node { addr, .. } if !addr.is_empty() => addr.as_str(),
                RegionHolder::Free => {
                    free.push(region);
                    continue;
                }
                _ => continue,
            };
            let found = match looked.get(addr) {
                Some(found) => *found,
                None if out.named.len() < MAX_CLUSTER_NODES && looked.len() < MAX_LOOKUPS => {
                    let found = lookup(addr.to_string()).await;
                    looked.insert(addr, found);
                    found
                }
                None => None,
            };
            let Some(a) = found else {
                continue;
            };
            out.routes.insert(region, a);
            if out.named.len() < MAX_CLUSTER_NODES && !out.named.contains(&a) {
                out.named.push(a);
            }
        }
    }
    for (from, o) in valid() {
        for r in o.regions.iter().filter(|r| r.holder == RegionHolder::Here) {
            out.routes.insert((r.region_x, r.region_z), *from);
        }
    }
    for region in free {
        if let Some(a) = kept.get(&region) {
            out.routes.entry(region).or_insert(*a);
        }
    }
    out
}

/// One player's connections to the nodes of a cluster.
#[derive(Debug)]
pub struct ClusterClient {
    cert: Vec<u8>,
    token: String,
    opts: ClientOptions,
    /// The connections, and region (x, z) to the node that writes it.
    view: ClusterView,
    /// Per node, the serial of the last `RegionOwners` taken in.
    seen: BTreeMap<SocketAddr, u64>,
    /// The newest ticket any node gave.
    ticket: Option<Ticket>,
    /// Connections being opened in the background.
    joining: BTreeMap<SocketAddr, tokio::task::JoinHandle<Result<Client, ClusterError>>>,
    /// Nodes that could not be joined, and when.
    failed: BTreeMap<SocketAddr, Instant>,
    /// The nodes the last reroute named.
    named: Vec<SocketAddr>,
    /// Tokens for joins and fresh lookups ([`JoinRate`]).
    joins: JoinBucket,
    /// Names looked up: what each gave, and when (at most [`MAX_LOOKUPS`]).
    resolved: Resolved,
    /// Addresses a fresh lookup found, whose join its token paid (at most
    /// the nodes named).
    prepaid: BTreeSet<SocketAddr>,
    /// A lookup was left for lack of tokens: route again.
    reroute_owed: bool,
    /// The view asked for ([`Self::subscribe`]) where it is now: moved
    /// with the player ([`moved_view`]), for nodes joined since.
    asked_view: Option<(ChunkPos, u8)>,
    /// The last position sent when the view was asked for or last moved
    /// ([`view_to_follow`]).
    view_checked_at: Option<FixedVec3>,
    /// Per node, the verdicts still awaited there ([`Self::hold`]): such a
    /// node stays connected though no route uses it any more.
    held: BTreeMap<SocketAddr, usize>,
}

/// Connects to node `addr` and arrives there with `ticket`.
async fn join(
    addr: SocketAddr,
    cert: Vec<u8>,
    token: String,
    opts: ClientOptions,
    ticket: Option<Ticket>,
) -> Result<Client, ClusterError> {
    let c = Client::connect_opts(addr, &cert, &token, opts).await?;
    if let Some(t) = ticket {
        if c.arrive_within(t, ARRIVE_TIMEOUT).await?.is_none() {
            return Err(ClusterError::NotArrived(addr));
        }
    }
    Ok(c)
}

impl ClusterClient {
    /// Connects to one node (`home`) of the cluster, trusting `cert` (the
    /// certificate the cluster's nodes share).
    pub async fn connect(
        home: SocketAddr,
        cert: &[u8],
        token: &str,
        opts: ClientOptions,
    ) -> Result<Self, ClusterError> {
        let client = Client::connect_opts(home, cert, token, opts.clone()).await?;
        let joins = JoinBucket::new(opts.join_rate, Instant::now());
        Ok(Self {
            cert: cert.to_vec(),
            token: token.to_string(),
            opts,
            view: ClusterView {
                home,
                nodes: BTreeMap::from([(home, Arc::new(client))]),
                region_chunks: None,
                routes: BTreeMap::new(),
            },
            seen: BTreeMap::new(),
            ticket: None,
            joining: BTreeMap::new(),
            failed: BTreeMap::new(),
            named: Vec::new(),
            joins,
            resolved: BTreeMap::new(),
            prepaid: BTreeSet::new(),
            reroute_owed: false,
            asked_view: None,
            view_checked_at: None,
            held: BTreeMap::new(),
        })
    }

    /// The first node's connection.
    pub fn home(&self) -> &Client {
        &self.view.nodes[&self.view.home]
    }

    /// A round of name lookups on this client's kept names and tokens.
    fn lookups(&mut self) -> std::sync::Mutex<Lookups<'_>> {
        std::sync::Mutex::new(Lookups {
            resolved: &mut self.resolved,
            joins: &mut self.joins,
            prepaid: &mut self.prepaid,
            owed: false,
        })
    }

    /// The connection to `addr`, if open.
    pub fn node(&self, addr: SocketAddr) -> Option<&Client> {
        self.view.nodes.get(&addr).map(|c| c.as_ref())
    }

    /// The connection to `addr`, if open, for a task of its own (one
    /// awaiting a verdict there).
    pub fn node_shared(&self, addr: SocketAddr) -> Option<Arc<Client>> {
        self.view.nodes.get(&addr).cloned()
    }

    /// A verdict from `addr` is awaited: [`Self::follow`] keeps that
    /// connection open, routes or not, until as many [`Self::release`]s.
    /// Closing it would lose the verdict of an edit it may have applied.
    pub fn hold(&mut self, addr: SocketAddr) {
        *self.held.entry(addr).or_default() += 1;
    }

    /// One verdict [`Self::hold`] waited for came (or never will).
    pub fn release(&mut self, addr: SocketAddr) {
        if let Some(n) = self.held.get_mut(&addr) {
            *n -= 1;
            if *n == 0 {
                self.held.remove(&addr);
            }
        }
    }

    /// Every connected node.
    pub fn nodes(&self) -> impl Iterator<Item = (SocketAddr, &Client)> {
        self.view.nodes.iter().map(|(a, c)| (*a, c.as_ref()))
    }

    /// The node that writes the region of `pos`, as last told; the home
    /// node when none is known or connected.
    pub fn route(&self, pos: ChunkPos) -> SocketAddr {
        self.view.route(pos)
    }

    /// A copy of the connections and routes as they are now, for readers
    /// on other threads (the game-loop [`crate::Session`]).
    pub fn view(&self) -> ClusterView {
        self.view.clone()
    }

    /// The connection whose replica is current for `pos`.
    pub fn client_for(&self, pos: ChunkPos) -> &Client {
        &self.view.nodes[&self.route(pos)]
    }

    /// The chunk as its writer's replica holds it (see
    /// [`Client::visible_chunk`]).
    pub fn chunk(&self, pos: ChunkPos) -> Option<(Arc<Chunk>, u64, bool)> {
        self.client_for(pos).visible_chunk(pos)
    }

    /// Moves the view asked for to the player once a new position sent
    /// leaves it out of reach ([`view_to_follow`]), then takes in every node's
    /// newest `RegionOwners`, connects to the nodes they name and closes the
    /// others. Call it often (every frame is fine: it is cheap when nothing
    /// changed). Returns the nodes newly connected.
    pub async fn follow(&mut self) -> Result<Vec<SocketAddr>, ClusterError> {
        self.move_view().await;
        let before = self.view.nodes.len();
        let home = self.view.home;
        self.view.nodes.retain(|a, c| *a == home || !c.is_closed());
        let nodes = &self.view.nodes;
        self.seen.retain(|a, _| nodes.contains_key(a));
        let latest: Vec<(SocketAddr, RegionOwners)> = self
            .view
            .nodes
            .iter()
            .filter_map(|(a, c)| Some((*a, c.region_owners()?)))
            .collect();
        let news = latest
            .iter()
            .any(|(a, o)| self.seen.get(a) != Some(&o.serial));
        let owed = self.reroute_owed && self.joins.ready(Instant::now());
        if news || owed || self.view.nodes.len() != before {
            self.named = self.reroute(&latest).await;
            self.let_go_unused();
        }
        self.start_joins();
        Ok(self.finish_joins().await)
    }

    /// Rebuilds the routes from every connected node's last word (see
    /// [`build_routes`]) and takes in the newest ticket. Returns the nodes
    /// named.
    async fn reroute(&mut self, latest: &[(SocketAddr, RegionOwners)]) -> Vec<SocketAddr> {
        let mut side = None;
        for (from, o) in latest {
            self.seen.insert(*from, o.serial);
            if o.regions.len() > MAX_REGION_OWNERS {
                continue;
            }
            side = Some(o.region_chunks);
            if let Some(t) = &o.ticket {
                if self
                    .ticket
                    .as_ref()
                    .is_none_or(|old| old.issued_ms <= t.issued_ms)
                {
                    self.ticket = Some(t.clone());
                }
            }
        }
        let mut kept = std::mem::take(&mut self.view.routes);
        let nodes = &self.view.nodes;
        kept.retain(|_, a| nodes.contains_key(a));
        if side.is_some_and(|s| Some(s) != self.view.region_chunks) {
            // Other coordinates: the old routes name other regions.
            kept.clear();
            self.view.region_chunks = side;
        }
        // One deadline for every name of this reroute.
        let until = tokio::time::Instant::now() + RESOLVE_TIMEOUT;
        let now = Instant::now();
        let state = self.lookups();
        let routing = build_routes(latest, &kept, |a| look_up(&state, a, now, until)).await;
        self.reroute_owed = state.into_inner().unwrap_or_else(|p| p.into_inner()).owed;
        self.prepaid.retain(|a| routing.named.contains(a));
        self.view.routes = routing.routes;
        routing.named
    }

    /// Closes the connections to nodes other than home that no message
    /// names and no route uses (freeing their places for new writers),
    /// and stops joining nodes no longer named.
    fn let_go_unused(&mut self) {
        let home = self.view.home;
        let named = &self.named;
        let used: BTreeSet<SocketAddr> = self
            .view
            .routes
            .values()
            .chain(named)
            .chain(self.held.keys())
            .copied()
            .collect();
        let unused: Vec<SocketAddr> = self
            .view
            .nodes
            .keys()
            .filter(|a| **a != home && !used.contains(a))
            .copied()
            .collect();
        for a in unused {
            if let Some(c) = self.view.nodes.remove(&a) {
                c.disconnect();
            }
            self.seen.remove(&a);
        }
        let now = Instant::now();
        let failed = &mut self.failed;
        self.joining.retain(|a, h| {
            let keep = named.contains(a);
            if !keep {
                // Left alone a while, as a failed join: naming an address
                // again and again restarts no handshake sooner.
                h.abort();
                failed.insert(*a, now);
            }
            keep
        });
    }

    /// Opens connections to the named nodes not yet connected, in the
    /// background (a dead node's address never stalls the caller), each
    /// for a [`JoinRate`] token.
    fn start_joins(&mut self) {
        let now = Instant::now();
        self.failed
            .retain(|_, at| now.duration_since(*at) < JOIN_BACKOFF);
        for a in self.named.clone() {
            if self.view.nodes.contains_key(&a)
                || self.joining.contains_key(&a)
                || self.failed.contains_key(&a)
                || self.view.nodes.len() + self.joining.len() >= MAX_CLUSTER_NODES
            {
                continue;
            }
            // Joins a lookup paid for go even when no token is left.
            if !self.prepaid.remove(&a) && !self.joins.take(now) {
                continue;
            }
            let task = join(
                a,
                self.cert.clone(),
                self.token.clone(),
                self.opts.clone(),
                self.ticket.clone(),
            );
            self.joining.insert(a, tokio::spawn(task));
        }
    }

    /// Asks every node for the view around `center` (see
    /// [`Client::subscribe`]). [`Self::follow`] moves it with the player
    /// ([`view_to_follow`]: at the next position sent, it is kept within
    /// the `Welcome`'s view radius of the feet, not that and the
    /// hysteresis a node allows), asking every node again; an admin's view
    /// stays where asked. A node joined later is asked for the view the
    /// home node confirmed ([`view_for_new_node`]).
    pub async fn subscribe(&mut self, center: ChunkPos, radius: u8) {
        self.asked_view = Some((center, radius));
        self.view_checked_at = self.home().last_position();
        for c in self.view.nodes.values() {
            // A node that cannot be told is one whose end is reported.
            let _ = c.subscribe(center, radius).await;
        }
    }

    /// Drops chunks on every node connected (see [`Client::forget`]). A
    /// node joined later is not told: it may stream them again (telling it
    /// could hide a chunk asked for again on another node since).
    pub async fn forget(&mut self, chunks: &[ChunkPos]) -> Result<(), ClientError> {
        for c in self.view.nodes.values() {
            if let Err(e @ ClientError::TooManyChunks { .. }) = c.forget(chunks).await {
                return Err(e);
            }
        }
        Ok(())
    }

    /// Asks every node for the view asked for at the chunk of the last
    /// position sent, once a new position leaves it out of reach
    /// ([`view_to_follow`]).
    async fn move_view(&mut self) {
        let home = self.home();
        let feet = home.last_position();
        let welcome = home.welcome();
        let to = view_to_follow(
            self.asked_view,
            welcome.role,
            feet,
            self.view_checked_at,
            welcome.view_radius,
        );
        if feet.is_some() {
            self.view_checked_at = feet;
        }
        if let (Some(to), Some((_, radius))) = (to, self.asked_view) {
            self.subscribe(to, radius).await;
        }
    }

    /// A node just joined (and arrived) is asked for the view the others
    /// stream: the one the home node confirmed ([`view_for_new_node`]).
    async fn catch_up(&self, node: &Client) {
        let loaded = self.home().view_loaded();
        if let Some((center, radius)) = view_for_new_node(self.asked_view, loaded) {
            let _ = node.subscribe(center, radius).await;
        }
    }

    /// Takes in the connections opened since the last call, each caught
    /// up with the view asked for, where it is now.
    async fn finish_joins(&mut self) -> Vec<SocketAddr> {
        let done: Vec<SocketAddr> = self
            .joining
            .iter()
            .filter(|(_, h)| h.is_finished())
            .map(|(a, _)| *a)
            .collect();
        let mut added = Vec::new();
        for a in done {
            let Some(h) = self.joining.remove(&a) else {
                continue;
            };
            match h.await {
                Ok(Ok(c)) => {
                    self.catch_up(&c).await;
                    self.view.nodes.insert(a, Arc::new(c));
                    added.push(a);
                }
                _ => {
                    self.failed.insert(a, Instant::now());
                }
            }
        }
        added
    }

    /// Reports the player's position to every node (each validates it);
    /// the next [`Self::follow`] moves the view asked for after it.
    pub fn send_position(&self, pos: FixedVec3) -> Result<(), ClientError> {
        let mut home = Ok(());
        for (a, c) in &self.view.nodes {
            let sent = c.send_position(pos);
            if *a == self.view.home {
                home = sent;
            }
        }
        home
    }

    /// Sends `edit` to the node that writes its region and waits for the
    /// verdict ([`Self::submit`], the verdict, then [`Self::settle`]).
    /// Returns the node that answered, with its answer.
    pub async fn edit(&mut self, edit: Edit) -> Result<(SocketAddr, Acked), ClusterError> {
        let (to, sent) = self.submit(edit.clone()).await?;
        let acked = self.view.nodes[&to].verdict(sent).await?;
        self.settle(to, edit, acked).await
    }

    /// Sends `edit` to the node that writes its region without waiting
    /// for the verdict: edits submitted one after another to one node reach
    /// it in that order. Returns the node and what [`Client::verdict`]
    /// takes; pass the verdict to [`Self::settle`]. A caller keeping
    /// several edits in flight should know that one [`Self::settle`] sends
    /// again reaches its new node after any submitted there since, and
    /// that [`Self::follow`] may close a node whose verdicts are still
    /// awaited unless it is held ([`Self::hold`]; [`Self::edit`] keeps one
    /// edit in flight and has neither).
    pub async fn submit(&self, edit: Edit) -> Result<(SocketAddr, SentEdit), ClusterError> {
        let to = self.route(edit_anchor(&edit).chunk());
        let sent = self.view.nodes[&to].submit(edit).await?;
        Ok((to, sent))
    }

    /// What to make of node `to`'s answer to `edit`. One refused
    /// `RegionElsewhere` naming the edit's own region held by another
    /// connected node (the region changed hands since this client was
    /// told) is sent once more, there; naming one not connected, the
    /// client starts joining it and returns the refusal. One naming
    /// another region (the edit reaches across a border into it) from the
    /// node holding the edit's own region is returned: that node asked the
    /// holder to hand it over, so the edit may pass when sent again a
    /// moment later. One refused `NodeFull` (no node holds the region, and that
    /// one may take no more) is sent to each other connected node in turn
    /// (one it cannot be sent to is passed over), until one answers
    /// otherwise; the one that accepts writes the region from then on (a
    /// node named by `RegionElsewhere` that answers `NodeFull` starts that
    /// round too). Returns the node that answered last, with its answer.
    pub async fn settle(
        &mut self,
        to: SocketAddr,
        edit: Edit,
        acked: Acked,
    ) -> Result<(SocketAddr, Acked), ClusterError> {
        let (mut to, mut acked) = (to, acked);
        let mut tried = vec![to];
        loop {
            let NextHop::Again(there) = self.next_hop(to, &edit, &acked, &tried).await else {
                return Ok((to, acked));
            };
            tried.push(there);
            let node = self.view.nodes[&there].clone();
            match node.submit(edit.clone()).await {
                Ok(sent) => {
                    // One that took it but gave no verdict may have applied
                    // it: its error is the answer.
                    acked = node.verdict(sent).await?;
                    to = there;
                }
                Err(_) if is_node_full(&acked) => {}
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// One step of [`Self::settle`], for a caller that sends and awaits
    /// the edit itself (the game-loop session, which awaits each verdict
    /// apart): node `to`'s answer to `edit`, sent to `tried` so far in
    /// order (`to` among them), stands ([`NextHop::Done`]) or the edit goes
    /// to another connected node ([`NextHop::Again`]; after `NodeFull`, if
    /// it cannot be sent there, call this again with that node in
    /// `tried` and the same answer). Routes the region to a node that
    /// accepted it after another refused.
    pub async fn next_hop(
        &mut self,
        to: SocketAddr,
        edit: &Edit,
        acked: &Acked,
        tried: &[SocketAddr],
    ) -> NextHop {
        if is_node_full(acked) {
            return match self.view.nodes.keys().find(|a| !tried.contains(a)).copied() {
                Some(next) => NextHop::Again(next),
                None => NextHop::Done,
            };
        }
        if tried.len() > 1 {
            if let (Verdict::Accepted { .. }, Some(side)) = (&acked.0, self.view.region_chunks) {
                let region = region_of(edit_anchor(edit).chunk(), side);
                learn_route(&mut self.view.routes, region, to);
            }
            return NextHop::Done;
        }
        let Verdict::Rejected(RejectReason::RegionElsewhere {
            region_x,
            region_z,
            owner,
            addr,
        }) = &acked.0
        else {
            return NextHop::Done;
        };
        // Another region than the edit's own, which this node holds: the
        // edit was at the right node, which asked the holder to hand that
        // region over. The holder would refuse it too; sent here again
        // later, it may pass. (With its own region free, the holder may
        // claim that one and apply it.)
        let beside = self.view.region_chunks.is_some_and(|side| {
            let own = region_of(edit_anchor(edit).chunk(), side);
            own != (*region_x, *region_z)
                && self.view.nodes.get(&to).is_some_and(|c| holds_here(c, own))
        });
        // A node connected already, known by its own id, is that
        // connection whatever address it is named at (a load balancer's,
        // the bound one): a second session of the player there would end
        // the first.
        let there = match self.connected_as(owner) {
            Some(a) => a,
            None if addr.is_empty() => return NextHop::Done,
            None => {
                let until = tokio::time::Instant::now() + RESOLVE_TIMEOUT;
                let state = self.lookups();
                // Owed or not, only the edit sent again asks for this name again.
                let found = look_up(&state, addr.clone(), Instant::now(), until).await;
                let Some(there) = found else {
                    return NextHop::Done;
                };
                there
            }
        };
        if there == to {
            return NextHop::Done;
        }
        learn_route(&mut self.view.routes, (*region_x, *region_z), there);
        if beside {
            return NextHop::Done;
        }
        if !self.view.nodes.contains_key(&there) {
            // Not connected yet: joined in the background, the refusal
            // goes back to the caller (it may send the edit again).
            if !self.named.contains(&there) && self.named.len() < MAX_CLUSTER_NODES {
                self.named.push(there);
            }
            self.start_joins();
            return NextHop::Done;
        }
        NextHop::Again(there)
    }

    /// The connected node whose own `RegionOwners` names it `node_id`.
    fn connected_as(&self, node_id: &str) -> Option<SocketAddr> {
        if node_id.is_empty() {
            return None;
        }
        self.view
            .nodes
            .iter()
            .find(|(_, c)| c.region_owners().is_some_and(|o| o.node == node_id))
            .map(|(a, _)| *a)
    }

    /// The region (x, z) of `pos`, once a node told the region size: the
    /// unit whose edits keep their order ([`crate::Session`] sends one at a
    /// time per region).
    pub fn region_key(&self, pos: ChunkPos) -> Option<(i32, i32)> {
        self.view.region_chunks.map(|side| region_of(pos, side))
    }

    /// Closes every connection.
    pub async fn close(self) {
        for (_, h) in self.joining {
            h.abort();
        }
        for (_, c) in self.view.nodes {
            c.shutdown().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn node_names_resolve_or_are_bad_addresses_in_time() {
        let a: SocketAddr = "127.0.0.1:4433".parse().unwrap();
        assert_eq!(resolve("127.0.0.1:4433").await.unwrap(), a);
        let local = resolve("localhost:4433").await.unwrap();
        assert!(local.port() == 4433 && local.is_ipv4(), "{local}");
        assert!(matches!(
            resolve("no-such-host.invalid:4433").await,
            Err(ClusterError::BadAddress(_))
        ));
        assert!(resolve("not an address").await.is_err());
    }
    use strata_terrain::Fixed;

    #[test]
    fn the_join_bucket_spends_its_burst_then_one_per_period() {
        let t0 = Instant::now();
        let every = Duration::from_secs(1);
        let mut b = JoinBucket::new(JoinRate { burst: 3, every }, t0);
        assert!(b.ready(t0));
        assert!((0..3).all(|_| b.take(t0)));
        assert!(!b.ready(t0) && !b.take(t0));
        assert!(!b.take(t0 + every / 2));
        assert!(b.ready(t0 + every));
        assert!(b.take(t0 + every));
        assert!(!b.take(t0 + every));
        // A long quiet refills the burst, no more.
        let later = t0 + every * 100;
        assert!((0..3).all(|_| b.take(later)));
        assert!(!b.take(later));
        // Part of a period is kept towards the next token.
        assert!(!b.take(later + every * 3 / 4));
        assert!(b.take(later + every * 5 / 4));
        // A burst of 0 takes nothing; a period of zero, everything.
        let mut none = JoinBucket::new(JoinRate { burst: 0, every }, t0);
        assert!(!none.ready(t0 + every * 10) && !none.take(t0 + every * 10));
        let mut all = JoinBucket::new(
            JoinRate {
                burst: 0,
                every: Duration::ZERO,
            },
            t0,
        );
        assert!((0..1000).all(|_| all.take(t0)));
    }

    #[tokio::test]
    async fn names_are_looked_up_once_and_kept_a_bounded_while() {
        let t0 = Instant::now();
        let mut joins = JoinBucket::new(
            JoinRate {
                burst: 1,
                every: Duration::from_secs(3600),
            },
            t0,
        );
        let (mut resolved, mut prepaid) = (Resolved::new(), BTreeSet::new());
        let until = tokio::time::Instant::now() + RESOLVE_TIMEOUT;
        let state = std::sync::Mutex::new(Lookups {
            resolved: &mut resolved,
            joins: &mut joins,
            prepaid: &mut prepaid,
            owed: false,
        });
        // An address costs no token.
        let a = look_up(&state, "127.0.0.1:9".into(), t0, until).await;
        assert_eq!(a, Some("127.0.0.1:9".parse().unwrap()));
        // A name takes the one token, which pays its join too, then is
        // answered from the kept ones.
        let name = "localhost:4433".to_string();
        let found = look_up(&state, name.clone(), t0, until).await;
        assert_eq!(found.map(|a| a.port()), Some(4433));
        assert!(lock(&state).prepaid.contains(&found.unwrap()));
        assert_eq!(look_up(&state, name.clone(), t0, until).await, found);
        assert!(!lock(&state).owed);
        // A new name with no token left is owed, not looked up.
        assert_eq!(look_up(&state, "other:1".into(), t0, until).await, None);
        assert!(lock(&state).owed);
        // Past its time, with no token to look it up again, a kept name
        // keeps its address (its connection is not dropped for it).
        lock(&state).owed = false;
        let stale = t0 + RESOLVED_TTL + RESOLVE_TIMEOUT;
        assert_eq!(look_up(&state, name.clone(), stale, until).await, found);
        assert!(!lock(&state).owed);
        // Past the round's deadline nothing is looked up or kept as bad.
        let l = state.into_inner().unwrap();
        l.joins.tokens = 1;
        let state = std::sync::Mutex::new(l);
        let late = tokio::time::Instant::now();
        assert_eq!(look_up(&state, "late:1".into(), t0, late).await, None);
        let mut l = state.into_inner().unwrap();
        assert!(l.owed && l.joins.tokens == 1 && !l.resolved.contains_key("late:1"));
        // At most MAX_LOOKUPS names are kept, the oldest dropped first.
        for i in 0..MAX_LOOKUPS + 5 {
            l.keep(
                format!("n{i}:1"),
                None,
                t0 + Duration::from_millis(i as u64),
            );
        }
        assert_eq!(l.resolved.len(), MAX_LOOKUPS);
        assert!(!l.resolved.contains_key("n0:1"));
        assert!(l.resolved.contains_key(&format!("n{}:1", MAX_LOOKUPS + 4)));
    }

    #[test]
    fn regions_are_floor_divided_chunk_columns() {
        assert_eq!(region_of(ChunkPos::new(7, 3, 0), 8), (0, 0));
        assert_eq!(region_of(ChunkPos::new(8, -3, -1), 8), (1, -1));
        assert_eq!(region_of(ChunkPos::new(-9, 0, 16), 8), (-2, 2));
    }

    #[test]
    fn a_huge_region_side_does_not_overflow() {
        let corner = ChunkPos::new(i32::MIN, 0, i32::MIN);
        assert_eq!(region_of(corner, u32::MAX), (-1, -1));
        assert_eq!(region_of(ChunkPos::new(i32::MAX, 0, 0), u32::MAX), (0, 0));
        assert_eq!(region_of(corner, 0), (i32::MIN, i32::MIN));
    }

    fn owners(regions: Vec<RegionOwner>) -> RegionOwners {
        RegionOwners {
            serial: 1,
            region_chunks: 8,
            regions,
            ticket: None,
            node: String::new(),
        }
    }

    fn held(x: i32, holder: RegionHolder) -> RegionOwner {
        RegionOwner {
            region_x: x,
            region_z: 0,
            holder,
        }
    }

    fn node_at(addr: String) -> RegionHolder {
        RegionHolder::Node {
            node: "n".into(),
            addr,
        }
    }

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    /// Routes built with a lookup that parses and counts its calls.
    async fn counted(
        latest: &[(SocketAddr, RegionOwners)],
        kept: &BTreeMap<(i32, i32), SocketAddr>,
    ) -> (Routing, usize) {
        let calls = std::cell::Cell::new(0);
        let routing = build_routes(latest, kept, |a| {
            calls.set(calls.get() + 1);
            async move { a.parse().ok() }
        })
        .await;
        (routing, calls.get())
    }

    /// A node another names at an address other than the one the client
    /// reached it at is the same node, known by its id: no lookup, no
    /// second session there.
    #[tokio::test]
    async fn a_connected_node_named_at_another_address_is_that_connection() {
        let (home, east) = (addr(1), addr(2));
        let from_home = RegionOwners {
            node: "west".into(),
            ..owners(vec![held(0, RegionHolder::Here)])
        };
        let west_elsewhere = RegionHolder::Node {
            node: "west".into(),
            addr: "127.0.0.1:9999".into(),
        };
        let from_east = RegionOwners {
            node: "east".into(),
            ..owners(vec![held(0, west_elsewhere), held(1, RegionHolder::Here)])
        };
        let latest = [(home, from_home), (east, from_east)];
        let (routing, calls) = counted(&latest, &BTreeMap::new()).await;
        assert_eq!(calls, 0);
        assert_eq!(routing.routes[&(0, 0)], home);
        assert_eq!(routing.routes[&(1, 0)], east);
        assert_eq!(routing.named, vec![home]);
    }

    /// Refusals naming ever new regions add routes up to the limit, and
    /// known regions are still routed anew past it.
    #[test]
    fn routes_learned_from_refusals_stop_at_their_limit() {
        let mut routes = BTreeMap::new();
        for x in 0..MAX_ROUTES as i32 + 100 {
            learn_route(&mut routes, (x, 7), addr(1));
        }
        assert_eq!(routes.len(), MAX_ROUTES);
        learn_route(&mut routes, (0, 7), addr(2));
        assert_eq!(routes[&(0, 7)], addr(2));
        assert_eq!(routes.len(), MAX_ROUTES);
    }

    #[tokio::test]
    async fn one_address_is_looked_up_once_per_reroute() {
        let regions = (0..MAX_REGION_OWNERS as i32)
            .map(|x| held(x, node_at("127.0.0.1:7000".into())))
            .collect();
        let latest = [(addr(1), owners(regions))];
        let (routing, calls) = counted(&latest, &BTreeMap::new()).await;
        assert_eq!(calls, 1);
        assert_eq!(routing.named, vec![addr(7000)]);
        assert_eq!(routing.routes.len(), MAX_REGION_OWNERS);
    }

    #[tokio::test]
    async fn names_and_lookups_stop_at_their_limits() {
        let regions = (0..MAX_REGION_OWNERS as i32)
            .map(|x| held(x, node_at(format!("127.0.0.1:{}", 7000 + x))))
            .collect();
        let latest = [(addr(1), owners(regions))];
        let (routing, calls) = counted(&latest, &BTreeMap::new()).await;
        assert_eq!(calls, MAX_CLUSTER_NODES);
        assert_eq!(routing.named.len(), MAX_CLUSTER_NODES);
        assert_eq!(routing.routes.len(), MAX_CLUSTER_NODES);

        // Addresses that do not resolve stop at MAX_LOOKUPS.
        let regions = (0..MAX_REGION_OWNERS as i32)
            .map(|x| held(x, node_at(format!("nowhere-{x}"))))
            .collect();
        let latest = [(addr(1), owners(regions))];
        let (routing, calls) = counted(&latest, &BTreeMap::new()).await;
        assert_eq!(calls, MAX_LOOKUPS);
        assert!(routing.named.is_empty() && routing.routes.is_empty());
    }

    #[tokio::test]
    async fn a_message_with_too_many_regions_is_ignored() {
        let regions = (0..=MAX_REGION_OWNERS as i32)
            .map(|x| held(x, RegionHolder::Here))
            .collect();
        let latest = [(addr(1), owners(regions))];
        let (routing, calls) = counted(&latest, &BTreeMap::new()).await;
        assert_eq!(calls, 0);
        assert!(routing.routes.is_empty() && routing.named.is_empty());
    }

    #[tokio::test]
    async fn a_free_region_keeps_its_route_and_a_node_knows_best() {
        let kept = BTreeMap::from([((0, 0), addr(2)), ((2, 0), addr(1))]);
        let latest = [
            (
                addr(1),
                owners(vec![
                    held(0, RegionHolder::Free),
                    held(1, node_at(addr(2).to_string())),
                    held(2, RegionHolder::Free),
                    held(3, RegionHolder::Here),
                ]),
            ),
            (
                addr(2),
                owners(vec![
                    held(0, RegionHolder::Free),
                    held(1, RegionHolder::Free),
                    held(2, RegionHolder::Here),
                    held(3, node_at(addr(3).to_string())),
                ]),
            ),
        ];
        let (routing, _) = counted(&latest, &kept).await;
        let expected = BTreeMap::from([
            ((0, 0), addr(2)),
            ((1, 0), addr(2)),
            ((2, 0), addr(2)),
            ((3, 0), addr(1)),
        ]);
        assert_eq!(routing.routes, expected);
        assert_eq!(routing.named, vec![addr(2), addr(3)]);
    }

    #[test]
    fn a_view_asked_moves_to_the_feet_once_they_are_the_margin_past_its_reach() {
        let feet = |x: i32, y: i32| FixedVec3::from_voxels(x, y, 5);
        let c = ChunkPos::new(4, 0, 0);
        // Radius 1 of 2: reach 1, chunks 3..=5 (voxels 96..=191) on x.
        for x in [96 - RECENTRE_MARGIN + 1, 100, 191 + RECENTRE_MARGIN - 1] {
            assert_eq!(moved_view(c, 1, 2, feet(x, 5)), None, "{x}");
        }
        let to = moved_view(c, 1, 2, feet(191 + RECENTRE_MARGIN, 5));
        assert_eq!(to, Some(ChunkPos::new(6, 0, 0)));
        let to = moved_view(c, 1, 2, feet(96 - RECENTRE_MARGIN, 5));
        assert_eq!(to, Some(ChunkPos::new(2, 0, 0)));
        // Up and down too, to the feet's row.
        assert_eq!(moved_view(c, 1, 2, feet(100, 35)), None);
        let to = moved_view(c, 1, 2, feet(100, 64 + RECENTRE_MARGIN));
        assert_eq!(to, Some(ChunkPos::new(3, 2, 0)));
        // A radius of the view radius or more reaches from its own chunk
        // only; a view radius of 0 never underflows.
        assert_eq!(moved_view(c, 9, 2, feet(128 + 31 + 3, 5)), None);
        let to = moved_view(c, 9, 2, feet(128 + 31 + RECENTRE_MARGIN, 5));
        assert_eq!(to, Some(ChunkPos::new(5, 0, 0)));
        assert_eq!(moved_view(c, 3, 0, feet(130, 5)), None);
        // Far coordinates do not overflow.
        let far = FixedVec3::from_voxels(-(1 << 22) + 1, 0, (1 << 22) - 1);
        let corner = ChunkPos::new(i32::MAX, i32::MIN, i32::MAX);
        assert_eq!(
            moved_view(corner, 0, 32, far),
            Some(ChunkPos::new(-(1 << 17), 0, (1 << 17) - 1))
        );
    }

    #[test]
    fn a_view_follows_only_a_player_at_a_new_position() {
        let c = ChunkPos::new(4, 0, 0);
        let asked = Some((c, 1));
        let near = FixedVec3::from_voxels(100, 5, 5);
        let far = FixedVec3::from_voxels(191 + RECENTRE_MARGIN, 5, 5);
        let moved = Some(ChunkPos::new(6, 0, 0));
        // A player's view moves once a new position is past its reach.
        assert_eq!(
            view_to_follow(asked, Role::Player, Some(far), None, 2),
            moved
        );
        let from_near = view_to_follow(asked, Role::Player, Some(far), Some(near), 2);
        assert_eq!(from_near, moved);
        // An admin's view stays where it was asked.
        assert_eq!(view_to_follow(asked, Role::Admin, Some(far), None, 2), None);
        // A view asked past the client's reach (a node's hysteresis allows
        // it) stays until the player sends another position.
        let same = view_to_follow(asked, Role::Player, Some(far), Some(far), 2);
        assert_eq!(same, None);
        // Nothing asked or no position sent: nothing moves.
        assert_eq!(view_to_follow(None, Role::Player, Some(far), None, 2), None);
        assert_eq!(view_to_follow(asked, Role::Player, None, None, 2), None);
    }

    #[test]
    fn a_node_joined_is_asked_for_the_view_the_home_node_confirmed() {
        let asked = (ChunkPos::new(6, 0, 0), 1);
        let loaded = (ChunkPos::new(5, 0, 0), 1);
        // The home node refused the move (SubscribeTooFar, or a position
        // lost): the new node is asked for the view the home node streams.
        assert_eq!(view_for_new_node(Some(asked), Some(loaded)), Some(loaded));
        // Nothing confirmed yet, or a view of another radius: the asked.
        assert_eq!(view_for_new_node(Some(asked), None), Some(asked));
        let other = (ChunkPos::new(5, 0, 0), 2);
        assert_eq!(view_for_new_node(Some(asked), Some(other)), Some(asked));
        // Nothing asked: the node streams its own view.
        assert_eq!(view_for_new_node(None, Some(loaded)), None);
    }

    #[test]
    fn an_edit_is_routed_by_its_centre_corner_or_origin() {
        let c = FixedVec3::new(Fixed(300 * 256 + 128), Fixed(-256), Fixed(5 * 256));
        let mine = Edit::Mine {
            center: c,
            radius: Fixed(4 * 256),
            strength: 10,
        };
        assert_eq!(edit_anchor(&mine), VoxelPos::new(300, -1, 5));
        let fill = Edit::ClearBox {
            min: VoxelPos::new(-4, 2, 9),
            max: VoxelPos::new(0, 3, 10),
        };
        assert_eq!(edit_anchor(&fill), VoxelPos::new(-4, 2, 9));
    }
}
