//! The connections a [`super::Session`] reads from: one server, or the
//! nodes of a cluster as its [`ClusterClient`] last saw them (the driver
//! task updates the copy; the game's calls read it).

use std::collections::{BTreeSet, VecDeque};
use std::sync::{Arc, Mutex, RwLock};

use strata_terrain::ChunkPos;

use crate::client::Client;
use crate::cluster::ClusterView;

/// Most chunks queued as changed because their region moved to another
/// node; past it the oldest are dropped (a view holds far fewer).
pub const MAX_MOVED_CHUNKS: usize = 65_536;

#[derive(Debug)]
pub(super) struct Links {
    pub home: Arc<Client>,
    cluster: Option<RwLock<ClusterView>>,
    /// Held chunks now read from another connection than before.
    moved: Mutex<VecDeque<ChunkPos>>,
}

impl Links {
    pub fn one(client: Arc<Client>) -> Self {
        Self {
            home: client,
            cluster: None,
            moved: Mutex::default(),
        }
    }

    pub fn cluster(view: ClusterView) -> Self {
        Self {
            home: view.nodes[&view.home].clone(),
            cluster: Some(RwLock::new(view)),
            moved: Mutex::default(),
        }
    }

    /// The connection whose replica is current for `pos`.
    pub fn for_chunk(&self, pos: ChunkPos) -> Arc<Client> {
        match &self.cluster {
            None => self.home.clone(),
            Some(v) => v
                .read()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .client_for(pos)
                .clone(),
        }
    }

    /// Every connection, the home one first.
    /// Whether this session spans a cluster's nodes.
    pub fn is_cluster(&self) -> bool {
        self.cluster.is_some()
    }

    pub fn all(&self) -> Vec<Arc<Client>> {
        let Some(v) = &self.cluster else {
            return vec![self.home.clone()];
        };
        let v = v.read().unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut all = vec![self.home.clone()];
        all.extend(
            v.nodes
                .iter()
                .filter(|(a, _)| **a != v.home)
                .map(|(_, c)| c.clone()),
        );
        all
    }

    /// Takes in the driver's newest view; every chunk the new writer of a
    /// region holds, where that writer changed, is queued as changed.
    pub fn update(&self, view: ClusterView) {
        let Some(current) = &self.cluster else {
            return;
        };
        // The replicas are read with no view lock held: a replica's lock
        // never waits on the view's. Only this driver writes the view.
        let routes_like = current
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .routes_like(&view);
        let mut moved = BTreeSet::new();
        if !routes_like {
            let mut held = Vec::new();
            for (addr, c) in &view.nodes {
                held.extend(c.replica().chunks().map(|(pos, _)| (*addr, pos)));
            }
            let old = current
                .read()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            for (addr, pos) in held {
                if view.route(pos) == addr && old.route(pos) != addr {
                    moved.insert(pos);
                }
            }
        }
        *current
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = view;
        if moved.is_empty() {
            return;
        }
        let mut queue = self
            .moved
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        queue.extend(moved);
        while queue.len() > MAX_MOVED_CHUNKS {
            queue.pop_front();
        }
    }

    /// A chunk to report changed: one that moved, else one a connection
    /// changed.
    pub fn pop_changed(&self) -> Option<ChunkPos> {
        if let Some(pos) = self
            .moved
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .pop_front()
        {
            return Some(pos);
        }
        if self.cluster.is_none() {
            return self.home.pop_changed();
        }
        self.all().iter().find_map(|c| c.pop_changed())
    }
}
