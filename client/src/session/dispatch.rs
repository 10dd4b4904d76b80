//! The session's tasks on the connection thread: one takes the game's
//! commands in order (so edits reach the server in the order taken) and
//! turns each edit's verdict into an event; one notes the connection's end.

use std::sync::{mpsc as std_mpsc, Arc, Mutex};

use strata_terrain::{ChunkPos, Edit};
use tokio::sync::mpsc;

use super::event::Event;
use crate::client::{Client, ClientError, Verdict};

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
    *closed.lock().expect("not poisoned") = Some(why);
}
