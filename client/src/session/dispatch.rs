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

/// [`dispatch`] for a cluster: subscriptions and forgets go to every node
/// connected (a node joined later is asked for the view asked, where the
/// cluster client moved it with the player; it may stream forgotten chunks
/// again), a resync to the node the chunk is read from, each edit to the
/// node that writes its region, in the order taken. Verdicts are awaited
/// each in a task of its own, so a node that stopped answering holds up
/// only its own edits; a verdict naming another writer is settled
/// ([`ClusterClient::settle`]) here. After each command and verdict and
/// every [`FOLLOW_EVERY`] the session's copy of the routes is brought up to
/// date.
pub(super) async fn dispatch_cluster(
    mut cluster: ClusterClient,
    links: Arc<Links>,
    mut commands: mpsc::Receiver<Command>,
    events: std_mpsc::Sender<Event>,
) {
    let mut follow = tokio::time::interval(FOLLOW_EVERY);
    follow.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut awaited: JoinSet<Awaited> = JoinSet::new();
    loop {
        tokio::select! {
            command = commands.recv() => {
                let Some(command) = command else { break };
                run_on_cluster(&mut cluster, command, &events, &mut awaited).await;
            }
            Some(done) = awaited.join_next(), if !awaited.is_empty() => {
                // The tasks neither panic nor are aborted while this runs.
                if let Ok(done) = done {
                    settle(&mut cluster, done, &events).await;
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

/// An edit whose verdict came from node `to` (or never will: `Err`).
struct Awaited {
    ticket: u64,
    to: SocketAddr,
    edit: Edit,
    verdict: Result<Acked, ClientError>,
}

async fn run_on_cluster(
    cluster: &mut ClusterClient,
    command: Command,
    events: &std_mpsc::Sender<Event>,
    awaited: &mut JoinSet<Awaited>,
) {
    let view = cluster.view();
    match command {
        Command::Edit { ticket, edit } => match cluster.submit(edit.clone()).await {
            Ok((to, sent)) => {
                let Some(node) = cluster.node_shared(to) else {
                    // `submit` just sent it there: not reached.
                    let _ = events.send(verdict_event(
                        ticket,
                        Err(ClientError::Closed("node left".into())),
                    ));
                    return;
                };
                cluster.hold(to);
                awaited.spawn(async move {
                    let verdict = node.verdict(sent).await;
                    Awaited {
                        ticket,
                        to,
                        edit,
                        verdict,
                    }
                });
            }
            Err(e) => {
                let _ = events.send(failed_event(ticket, e));
            }
        },
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

/// Turns a verdict into the game's event, once any refusal naming another
/// writer was followed.
async fn settle(cluster: &mut ClusterClient, done: Awaited, events: &std_mpsc::Sender<Event>) {
    let Awaited {
        ticket,
        to,
        edit,
        verdict,
    } = done;
    cluster.release(to);
    let event = match verdict {
        Ok(acked) => match cluster.settle(to, edit, acked).await {
            Ok((_, acked)) => verdict_event(ticket, Ok(acked)),
            Err(e) => failed_event(ticket, e),
        },
        Err(e) => verdict_event(ticket, Err(e)),
    };
    let _ = events.send(event);
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
