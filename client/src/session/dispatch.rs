//! The session's tasks on the connection thread: one takes the game's
//! commands in order (so edits reach the server in the order taken) and
//! turns each edit's verdict into an event; one notes the connection's end.
//! On a cluster one task owns the [`ClusterClient`]: it takes the game's
//! commands and follows the nodes' word between them.

use std::net::SocketAddr;
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::time::Duration;

use strata_terrain::{ChunkPos, Edit};
use tokio::sync::mpsc;
use tokio::task::JoinSet;

use super::event::Event;
use super::links::Links;
use crate::client::{Acked, Client, ClientError, Verdict};
use crate::cluster::{ClusterClient, ClusterError};

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

/// An edit sent to a node, and that node's answer.
type Answered = (u64, Edit, SocketAddr, Result<Acked, ClientError>);

/// [`dispatch`] for a cluster: subscriptions and forgets go to every node
/// connected then (a node joined later follows the player's positions and
/// streams its whole view), a resync to the node the chunk is read from.
/// Each edit goes at once to the node that writes its region (edits to one
/// node reach it in the order taken) and its verdict is awaited on the
/// side; an answer the cluster client may send again elsewhere
/// (`RegionElsewhere`, `NodeFull`) is settled here, the others become
/// events as they come. After each command and every [`FOLLOW_EVERY`] the
/// session's copy of the routes is brought up to date.
pub(super) async fn dispatch_cluster(
    mut cluster: ClusterClient,
    links: Arc<Links>,
    mut commands: mpsc::Receiver<Command>,
    events: std_mpsc::Sender<Event>,
) {
    let mut follow = tokio::time::interval(FOLLOW_EVERY);
    follow.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut answers: JoinSet<Answered> = JoinSet::new();
    loop {
        tokio::select! {
            command = commands.recv() => {
                let Some(command) = command else { break };
                run_on_cluster(&cluster, command, &mut answers, &events).await;
            }
            Some(answered) = answers.join_next(), if !answers.is_empty() => {
                // A verdict task cannot fail but by a panic, which has no
                // ticket to report: nothing else to do with it.
                if let Ok(answered) = answered {
                    let _ = events.send(settle(&mut cluster, answered).await);
                }
            }
            _ = follow.tick() => {
                // A node that cannot be joined is retried later; the home
                // connection's end is reported by `watch_close`.
                let _ = cluster.follow().await;
            }
        }
        links.update(cluster.view());
    }
}

/// Sends an edit to the node that writes its region and awaits its
/// verdict in `answers`.
async fn submit_on_cluster(
    cluster: &ClusterClient,
    ticket: u64,
    edit: Edit,
    answers: &mut JoinSet<Answered>,
    events: &std_mpsc::Sender<Event>,
) {
    let (to, sent) = match cluster.submit(edit.clone()).await {
        Ok(sent) => sent,
        Err(e) => {
            let _ = events.send(failed_event(ticket, e));
            return;
        }
    };
    let Some(node) = cluster.node_shared(to) else {
        // Not reached (edits route to a connected node), but no ticket
        // goes unanswered.
        let _ = events.send(Event::EditFailed {
            ticket,
            error: format!("node {to} is no longer connected"),
        });
        return;
    };
    answers.spawn(async move {
        let verdict = node.verdict(sent).await;
        (ticket, edit, to, verdict)
    });
}

/// The event for an answer, sending the edit again first where the
/// cluster client may ([`ClusterClient::settle`]).
async fn settle(cluster: &mut ClusterClient, (ticket, edit, to, verdict): Answered) -> Event {
    match verdict {
        Ok(acked) if ClusterClient::may_resend(&acked) => {
            match cluster.settle(to, edit, acked).await {
                Ok((_, acked)) => verdict_event(ticket, Ok(acked)),
                Err(e) => failed_event(ticket, e),
            }
        }
        other => verdict_event(ticket, other),
    }
}

fn failed_event(ticket: u64, e: ClusterError) -> Event {
    match e {
        ClusterError::Client(e) => verdict_event(ticket, Err(e)),
        e => Event::EditFailed {
            ticket,
            error: e.to_string(),
        },
    }
}

async fn run_on_cluster(
    cluster: &ClusterClient,
    command: Command,
    answers: &mut JoinSet<Answered>,
    events: &std_mpsc::Sender<Event>,
) {
    let view = cluster.view();
    match command {
        Command::Edit { ticket, edit } => {
            submit_on_cluster(cluster, ticket, edit, answers, events).await;
        }
        Command::Subscribe { center, radius } => {
            for c in view.nodes.values() {
                let _ = c.subscribe(center, radius).await;
            }
        }
        Command::Forget { chunks } => {
            for c in view.nodes.values() {
                let _ = c.forget(&chunks).await;
            }
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
