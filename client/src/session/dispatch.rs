//! The session's tasks on the connection thread: one takes the game's
//! commands in order (so edits reach the server in the order taken) and
//! turns each edit's verdict into an event; one notes the connection's end.
//! On a cluster one task owns the [`ClusterClient`]: it takes the game's
//! commands and follows the nodes' word between them.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::net::SocketAddr;
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::time::Duration;

use strata_terrain::{ChunkPos, Edit};
use tokio::sync::mpsc;
use tokio::task::JoinSet;

use super::event::Event;
use super::links::Links;
use crate::client::{Acked, Client, ClientError, Verdict};
use crate::cluster::{edit_anchor, is_node_full, ClusterClient, NextHop};

/// How often a cluster session takes in the nodes' `RegionOwners` (and
/// joins the nodes they name).
pub const FOLLOW_EVERY: Duration = Duration::from_millis(50);

/// What the game asked the connection thread to send.
#[derive(Debug)]
pub(super) enum Command {
    Edit { ticket: u64, edit: Edit },
    Subscribe { center: ChunkPos, radius: u8 },
    Forget { chunks: Vec<ChunkPos> },
    Resync { pos: ChunkPos },
}

pub(super) async fn dispatch(
    client: Arc<Client>,
    mut commands: mpsc::Receiver<Command>,
    events: std_mpsc::Sender<Event>,
) {
    while let Some(command) = commands.recv().await {
        match command {
            Command::Edit { ticket, edit } => match client.submit(edit).await {
                Ok(sent) => {
                    let (client, events) = (client.clone(), events.clone());
                    tokio::spawn(async move {
                        let _ = events.send(verdict_event(ticket, client.verdict(sent).await));
                    });
                }
                Err(e) => {
                    let _ = events.send(verdict_event(ticket, Err(e)));
                }
            },
            // A failure here is the connection's end, reported by `watch_close`.
            Command::Subscribe { center, radius } => {
                let _ = client.subscribe(center, radius).await;
            }
            Command::Forget { chunks } => {
                let _ = client.forget(&chunks).await;
            }
            Command::Resync { pos } => {
                let _ = client.resync(pos).await;
            }
        }
    }
}

/// [`dispatch`] for a cluster: subscriptions and forgets go to every node
/// connected (a node joined later is asked for the view asked, where the
/// cluster client moved it with the player; it may stream forgotten chunks
/// again), a resync to the node the chunk is read from, each edit to the
/// node that writes its region. Edits keep their order per region: one of
/// a region is sent once the last one there has its final answer (sent
/// again where a refusal points, [`ClusterClient::next_hop`]); those of
/// other regions go meanwhile, and every verdict is awaited in a task of
/// its own, so a node that stopped answering holds up only its regions'
/// edits, and once one of them gets no answer (a timeout, the connection's
/// end) those waiting behind it fail with it. After each command and
/// verdict and every [`FOLLOW_EVERY`] the session's copy of the routes is
/// brought up to date.
pub(super) async fn dispatch_cluster(
    mut cluster: ClusterClient,
    links: Arc<Links>,
    mut commands: mpsc::Receiver<Command>,
    events: std_mpsc::Sender<Event>,
) {
    let mut follow = tokio::time::interval(FOLLOW_EVERY);
    follow.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut edits = Edits {
        cluster: &mut cluster,
        events: &events,
        awaited: JoinSet::new(),
        tasks: HashMap::new(),
        lanes: BTreeMap::new(),
        after_sizing: VecDeque::new(),
    };
    loop {
        tokio::select! {
            command = commands.recv() => {
                let Some(command) = command else { break };
                match command {
                    Command::Edit { ticket, edit } => edits.take(ticket, edit).await,
                    other => run_on_cluster(edits.cluster, other).await,
                }
            }
            Some(done) = edits.awaited.join_next_with_id(), if !edits.awaited.is_empty() => {
                edits.joined(done).await;
            }
            _ = follow.tick() => {
                // A node that cannot be joined is retried later; the home
                // connection's end is reported by `watch_close`.
                let _ = edits.cluster.follow().await;
            }
        }
        links.update(edits.cluster.view());
    }
}

/// A region's edits, in order: the first of them in flight (or being sent
/// again), the others waiting. `None`: before any node told the region
/// size; edits taken while those wait go by region once they are all
/// answered (one sent before its region was known is not overtaken).
type Lane = Option<(i32, i32)>;

/// An edit on its way: sent to `tried` in order, the last of them now;
/// `last` is the answer before (kept for passing over a node after
/// `NodeFull`).
struct Flight {
    ticket: u64,
    edit: Edit,
    lane: Lane,
    tried: Vec<SocketAddr>,
    last: Option<(SocketAddr, Acked)>,
}

/// A flight's verdict from `to` (or why none will come).
struct Awaited {
    flight: Flight,
    to: SocketAddr,
    verdict: Result<Acked, ClientError>,
}

/// A flight's final answer, for the game.
type Answer = Result<Acked, ClientError>;

/// The cluster session's edits in flight and waiting.
struct Edits<'a> {
    cluster: &'a mut ClusterClient,
    events: &'a std_mpsc::Sender<Event>,
    awaited: JoinSet<Awaited>,
    /// Each verdict task's flight (lane, ticket) and node, should the task
    /// end without its value.
    tasks: HashMap<tokio::task::Id, (Lane, u64, SocketAddr)>,
    lanes: BTreeMap<Lane, VecDeque<(u64, Edit)>>,
    /// Edits of known regions taken while the `None` lane was busy.
    after_sizing: VecDeque<(u64, Edit)>,
}

impl Edits<'_> {
    /// An edit the game made: sent now, or after those of its region.
    async fn take(&mut self, ticket: u64, edit: Edit) {
        let lane = self.cluster.region_key(edit_anchor(&edit).chunk());
        // Edits taken before the region size was known may be of any
        // region: later ones wait until they are answered.
        if lane.is_some() && (self.lanes.contains_key(&None) || !self.after_sizing.is_empty()) {
            self.after_sizing.push_back((ticket, edit));
            return;
        }
        if let Some(waiting) = self.lanes.get_mut(&lane) {
            waiting.push_back((ticket, edit));
            return;
        }
        self.lanes.insert(lane, VecDeque::new());
        if let Some((ticket, answer)) = self.start(ticket, edit, lane).await {
            self.finish(lane, ticket, answer).await;
        }
    }

    /// Sends an edit to the node that writes its region. `Some`: it could
    /// not be sent, with the answer.
    async fn start(&mut self, ticket: u64, edit: Edit, lane: Lane) -> Option<(u64, Answer)> {
        let to = self.cluster.route(edit_anchor(&edit).chunk());
        let flight = Flight {
            ticket,
            edit,
            lane,
            tried: Vec::new(),
            last: None,
        };
        self.send(flight, to).await
    }

    /// Sends the flight to `to` and awaits the verdict in a task. `Some`:
    /// it could not be sent anywhere, with the answer that stands.
    async fn send(&mut self, mut flight: Flight, mut to: SocketAddr) -> Option<(u64, Answer)> {
        loop {
            flight.tried.push(to);
            let sent = match self.cluster.node_shared(to) {
                Some(node) => node.submit(flight.edit.clone()).await.map(|s| (node, s)),
                None => Err(ClientError::Closed("node left".into())),
            };
            let e = match sent {
                Ok((node, sent)) => {
                    self.cluster.hold(to);
                    let (lane, ticket) = (flight.lane, flight.ticket);
                    let task = self.awaited.spawn(async move {
                        let verdict = node.verdict(sent).await;
                        Awaited {
                            flight,
                            to,
                            verdict,
                        }
                    });
                    self.tasks.insert(task.id(), (lane, ticket, to));
                    return None;
                }
                Err(e) => e,
            };
            // After `NodeFull` a node the edit cannot reach is passed over
            // (none left: that answer stands); else the failure is the
            // answer.
            let Some((from, acked)) = flight.last.clone().filter(|(_, a)| is_node_full(a)) else {
                return Some((flight.ticket, Err(e)));
            };
            match self
                .cluster
                .next_hop(from, &flight.edit, &acked, &flight.tried)
                .await
            {
                NextHop::Again(next) => to = next,
                NextHop::Done => return Some((flight.ticket, Ok(acked))),
            }
        }
    }

    /// A verdict task ended.
    async fn joined(&mut self, done: Result<(tokio::task::Id, Awaited), tokio::task::JoinError>) {
        let id = match &done {
            Ok((id, _)) => *id,
            Err(e) => e.id(),
        };
        let Some((lane, ticket, to)) = self.tasks.remove(&id) else {
            return;
        };
        self.cluster.release(to);
        match done {
            Ok((_, done)) => self.answered(done).await,
            // Panicked or aborted: no answer will come.
            Err(e) => {
                let why = ClientError::Closed(format!("awaiting the verdict ended: {e}"));
                self.finish(lane, ticket, Err(why)).await
            }
        }
    }

    /// A verdict came: it stands, or the edit goes on to another node.
    async fn answered(&mut self, done: Awaited) {
        let Awaited {
            mut flight,
            to,
            verdict,
        } = done;
        let (lane, ticket) = (flight.lane, flight.ticket);
        let acked = match verdict {
            Ok(acked) => acked,
            Err(e) => return self.finish(lane, ticket, Err(e)).await,
        };
        match self
            .cluster
            .next_hop(to, &flight.edit, &acked, &flight.tried)
            .await
        {
            NextHop::Again(there) => {
                flight.last = Some((to, acked));
                if let Some((ticket, answer)) = self.send(flight, there).await {
                    self.finish(lane, ticket, answer).await;
                }
            }
            NextHop::Done => self.finish(lane, ticket, Ok(acked)).await,
        }
    }

    /// An edit's final answer goes to the game, and the next edit of its
    /// region is sent. An edit that got no answer takes those waiting
    /// behind it along: they were for the same node.
    async fn finish(&mut self, lane: Lane, ticket: u64, answer: Answer) {
        let mut done = Some((ticket, answer));
        while let Some((ticket, answer)) = done.take() {
            let unanswered = match &answer {
                Err(e @ (ClientError::Timeout(_) | ClientError::Closed(_))) => Some(e.to_string()),
                _ => None,
            };
            let _ = self.events.send(verdict_event(ticket, answer));
            if let Some(why) = unanswered {
                let waiting = self.lanes.get_mut(&lane).map(std::mem::take);
                for (t, _) in waiting.unwrap_or_default() {
                    let _ = self.events.send(Event::EditFailed {
                        ticket: t,
                        error: format!("an earlier edit of its region got no answer: {why}"),
                    });
                }
            }
            match self.lanes.get_mut(&lane).and_then(VecDeque::pop_front) {
                Some((ticket, edit)) => done = self.start(ticket, edit, lane).await,
                None => {
                    self.lanes.remove(&lane);
                }
            }
        }
        if lane.is_none() && !self.lanes.contains_key(&None) {
            // The edits taken before the region size was known are all
            // answered: those taken since go, by region.
            for (ticket, edit) in std::mem::take(&mut self.after_sizing) {
                Box::pin(self.take(ticket, edit)).await;
            }
        }
    }
}

async fn run_on_cluster(cluster: &mut ClusterClient, command: Command) {
    let view = cluster.view();
    match command {
        // Taken by `Edits` before this.
        Command::Edit { .. } => {}
        Command::Subscribe { center, radius } => {
            cluster.subscribe(center, radius).await;
        }
        Command::Forget { chunks } => {
            let _ = cluster.forget(&chunks).await;
        }
        Command::Resync { pos } => {
            let _ = view.client_for(pos).resync(pos).await;
        }
    }
}

fn verdict_event(
    ticket: u64,
    v: Result<(Verdict, Vec<strata_protocol::ChunkVersion>), ClientError>,
) -> Event {
    match v {
        Ok((Verdict::Accepted { seq }, changes)) => Event::EditAccepted {
            ticket,
            seq,
            changes,
        },
        Ok((Verdict::Rejected(reason), _)) => Event::EditRejected { ticket, reason },
        Err(e) => Event::EditFailed {
            ticket,
            error: e.to_string(),
        },
    }
}

pub(super) async fn watch_close(client: Arc<Client>, closed: Arc<Mutex<Option<ClientError>>>) {
    let why = client.closed().await;
    *closed
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(why);
}
