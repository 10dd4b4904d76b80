//! Who gets in. A connection in its handshake (TLS, then `Hello` with a
//! valid token) holds a handshake slot: few of them, a few per address,
//! and only until a deadline. When every slot is taken, a new connection
//! (from an address with room) takes the slot of a handshake in progress
//! for half that deadline (the oldest from the busiest address), and that
//! handshake ends: a few addresses holding every slot with connections
//! that never say Hello cannot keep new logins out until their deadline.
//! Only an authenticated session takes a session slot, players and
//! admins from separate pools, so such a flood locks out neither players
//! nor operators.

use std::collections::{BTreeMap, HashMap};
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tracing::warn;

use super::player_slots::{PlayerSlot, PlayerSlots};
use crate::log_every::{LogEvery, LOG_EVERY};

/// The limits, from `[server]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Authenticated player sessions at once.
    pub sessions: u32,
    /// Authenticated admin sessions at once, beside the players'.
    pub admin_sessions: u32,
    /// Live sessions one player may have (`[engine] sessions_per_player`):
    /// at a full server, a login past it takes its oldest session's slot.
    pub sessions_per_player: usize,
    /// Connections in their handshake at once.
    pub handshakes: u32,
    /// Connections in their handshake at once from one IP address.
    pub handshakes_per_address: u32,
    /// Handshakes in progress from which unvalidated addresses get a Retry.
    pub retry_above: u32,
    /// From the first packet to a verified Hello.
    pub handshake_timeout: Duration,
    /// A handshake in progress this long may lose its slot to a newer one
    /// when every slot is taken: half `handshake_timeout` (2.5 s at the
    /// default), so a crowd of honest logins arriving at once (after a
    /// restart) is refused at the door rather than undoing handshakes
    /// about to finish, and a client over a slow link, a lost packet or a
    /// Retry included, is done within it.
    pub evictable_after: Duration,
}

/// Why a connection was turned away.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// Every handshake slot is taken.
    Handshakes,
    /// This address has its share of handshakes in progress.
    PerAddress,
    /// Every player session slot is taken.
    Sessions,
    /// Every admin session slot is taken.
    AdminSessions,
    /// A newer connection took this handshake's slot (every slot taken).
    Evicted,
}

impl Refused {
    /// Metric label.
    pub fn label(self) -> &'static str {
        match self {
            Refused::Handshakes => "handshakes",
            Refused::PerAddress => "per_address",
            Refused::Sessions => "sessions",
            Refused::AdminSessions => "admin_sessions",
            Refused::Evicted => "evicted",
        }
    }

    /// What the client is told.
    pub fn message(self) -> &'static str {
        match self {
            Refused::Handshakes | Refused::PerAddress | Refused::Evicted => {
                "too many connections being set up"
            }
            Refused::Sessions => "server is full",
            Refused::AdminSessions => "every admin session slot is taken",
        }
    }
}

#[derive(Debug)]
pub struct Admission {
    limits: Limits,
    handshakes: Arc<Semaphore>,
    /// Handshakes in progress by address; an entry exists only while it
    /// holds one (or a connection evicted from one has not ended yet), so
    /// it is bounded by the connections being set up.
    per_address: Mutex<HashMap<IpAddr, u32>>,
    /// Handshakes holding a slot, oldest first (by the order they began).
    in_progress: Mutex<BTreeMap<u64, Arc<Slot>>>,
    next_handshake: AtomicU64,
    players: Arc<Semaphore>,
    player_slots: Arc<PlayerSlots>,
    admins: Arc<Semaphore>,
    /// Refusals are logged at most once a second, with a count.
    logged: LogEvery,
}

impl Admission {
    pub fn new(limits: Limits) -> Arc<Self> {
        let permits = |n: u32| Arc::new(Semaphore::new(n as usize));
        let players = permits(limits.sessions);
        Arc::new(Self {
            handshakes: permits(limits.handshakes),
            player_slots: PlayerSlots::new(players.clone(), limits.sessions_per_player),
            players,
            admins: permits(limits.admin_sessions),
            per_address: Mutex::new(HashMap::new()),
            in_progress: Mutex::new(BTreeMap::new()),
            next_handshake: AtomicU64::new(0),
            logged: LogEvery::new(LOG_EVERY),
            limits,
        })
    }

    /// Whether a connection from an address QUIC has not validated should
    /// be sent a Retry instead of taking a slot: enough handshakes are in
    /// progress that the slots are worth defending against spoofed sources.
    pub fn wants_retry(&self) -> bool {
        let free = self.handshakes.available_permits();
        let in_progress = (self.limits.handshakes as usize).saturating_sub(free);
        in_progress >= self.limits.retry_above as usize
    }

    /// A handshake slot for a new connection from `addr`, or why not. The
    /// per-address count is per IPv4 address and per IPv6 /64 (one host
    /// usually holds a whole /64, so counting single IPv6 addresses would
    /// give it 2^64 shares).
    pub fn begin(self: &Arc<Self>, addr: IpAddr) -> Result<Handshake, Refused> {
        let addr = sharing_limits(addr);
        let mut per = self.per_address.lock().unwrap_or_else(|e| e.into_inner());
        let here = per.get(&addr).copied().unwrap_or(0);
        if here >= self.limits.handshakes_per_address {
            return Err(self.refused(Refused::PerAddress, addr));
        }
        let permit = match self.handshakes.clone().try_acquire_owned() {
            Ok(p) => p,
            Err(_) => match self.evict(&per) {
                Some(p) => p,
                None => return Err(self.refused(Refused::Handshakes, addr)),
            },
        };
        per.insert(addr, here + 1);
        drop(per);
        let slot = Arc::new(Slot {
            addr,
            started: std::time::Instant::now(),
            permit: Mutex::new(Some(permit)),
            evicted: AtomicBool::new(false),
            wake: tokio::sync::Notify::new(),
        });
        let id = self.next_handshake.fetch_add(1, Ordering::Relaxed);
        lock(&self.in_progress).insert(id, slot.clone());
        Ok(Handshake {
            slot,
            id,
            deadline: tokio::time::Instant::now() + self.limits.handshake_timeout,
            admission: self.clone(),
        })
    }

    /// Takes a slot from a handshake in progress for `evictable_after` or
    /// more and tells it it is over: the oldest of those from the address
    /// (or IPv6 /64) with the most handshakes in progress (a flood's, not
    /// an honest client's one); `None` when there is no such handshake.
    fn evict(&self, per: &HashMap<IpAddr, u32>) -> Option<OwnedSemaphorePermit> {
        let mut in_progress = lock(&self.in_progress);
        let victim = in_progress
            .iter()
            .filter(|(_, s)| s.started.elapsed() >= self.limits.evictable_after)
            // The most from one address; of those, the oldest (lowest id).
            .max_by_key(|&(&id, s)| {
                (
                    per.get(&s.addr).copied().unwrap_or(0),
                    std::cmp::Reverse(id),
                )
            })
            .map(|(&id, _)| id)?;
        let slot = in_progress.remove(&victim)?;
        let permit = lock(&slot.permit).take()?;
        slot.evicted.store(true, Ordering::Release);
        slot.wake.notify_one();
        metrics::counter!(crate::metrics::CONNECTIONS_REFUSED, "reason" => Refused::Evicted.label())
            .increment(1);
        Some(permit)
    }

    /// Counts and (at most once per [`LOG_EVERY`]) logs a refusal.
    fn refused(&self, why: Refused, addr: IpAddr) -> Refused {
        metrics::counter!(crate::metrics::CONNECTIONS_REFUSED, "reason" => why.label())
            .increment(1);
        if let Some(refused) = self.logged.event() {
            warn!(%addr, reason = why.label(), refused, "refusing connections");
        }
        why
    }

    /// Waits (at most `grace`) until every session and handshake ended.
    pub async fn drained(&self, grace: Duration) {
        let all = |s: &Arc<Semaphore>, n: u32| {
            let s = s.clone();
            async move {
                let _ = s.acquire_many(n).await;
            }
        };
        let _ = tokio::time::timeout(grace, async {
            all(&self.players, self.limits.sessions).await;
            all(&self.admins, self.limits.admin_sessions).await;
            all(&self.handshakes, self.limits.handshakes).await;
        })
        .await;
    }
}

/// The address whose share of handshakes a connection from `addr` takes:
/// an IPv4 address (IPv4-mapped IPv6 included) as it is, an IPv6 address
/// as its /64.
pub fn sharing_limits(addr: IpAddr) -> IpAddr {
    match addr {
        IpAddr::V4(_) => addr,
        IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => IpAddr::V4(v4),
            None => {
                let prefix = u128::from(v6) & !((1u128 << 64) - 1);
                IpAddr::V6(prefix.into())
            }
        },
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A handshake's slot, which a newer connection may take.
#[derive(Debug)]
struct Slot {
    /// Its address as the per-address count knows it.
    addr: IpAddr,
    started: std::time::Instant,
    permit: Mutex<Option<OwnedSemaphorePermit>>,
    evicted: AtomicBool,
    wake: tokio::sync::Notify,
}

/// Resolves once the handshake it was taken from lost its slot
/// ([`Handshake::eviction`]); never after the handshake was admitted.
#[derive(Debug, Clone)]
pub struct Eviction(Arc<Slot>);

impl Eviction {
    pub async fn wait(&self) {
        while !self.0.evicted.load(Ordering::Acquire) {
            self.0.wake.notified().await;
        }
    }
}

/// A connection in its handshake. Dropping it frees the slot.
#[derive(Debug)]
pub struct Handshake {
    slot: Arc<Slot>,
    /// Its place in `Admission::in_progress`.
    id: u64,
    /// The handshake must be done (Hello verified) by then.
    pub deadline: tokio::time::Instant,
    admission: Arc<Admission>,
}

impl Handshake {
    /// An admin authenticated: trades the handshake slot for an admin
    /// session slot, held for the session's life.
    pub fn admit_admin(self) -> Result<OwnedSemaphorePermit, Refused> {
        self.leave_eviction_order()?;
        let why = Refused::AdminSessions;
        self.admission
            .admins
            .clone()
            .try_acquire_owned()
            .map_err(|_| self.admission.refused(why, self.slot.addr))
    }

    /// `player` authenticated: trades the handshake slot for a player
    /// session slot ([`PlayerSlots::take`]), held for the session's life.
    pub fn admit_player(self, player: &str, session: u64) -> Result<PlayerSlot, Refused> {
        self.leave_eviction_order()?;
        let why = Refused::Sessions;
        self.admission
            .player_slots
            .take(player, session)
            .ok_or_else(|| self.admission.refused(why, self.slot.addr))
    }

    /// Out of the eviction order first: an admitted session keeps its
    /// connection; one evicted before is over.
    fn leave_eviction_order(&self) -> Result<(), Refused> {
        if lock(&self.admission.in_progress).remove(&self.id).is_none()
            || self.slot.evicted.load(Ordering::Acquire)
        {
            return Err(Refused::Evicted);
        }
        Ok(())
    }
}

impl Handshake {
    /// What resolves if a newer connection takes this handshake's slot
    /// before it is admitted: its connection should then end.
    pub fn eviction(&self) -> Eviction {
        Eviction(self.slot.clone())
    }
}

impl Drop for Handshake {
    fn drop(&mut self) {
        {
            let mut per = lock(&self.admission.per_address);
            if let Some(n) = per.get_mut(&self.slot.addr) {
                *n -= 1;
                if *n == 0 {
                    per.remove(&self.slot.addr);
                }
            }
        }
        lock(&self.admission.in_progress).remove(&self.id);
        // The slot itself (an `Eviction` may outlive this): admitted, the
        // connection holds a session slot instead; else it is done.
        drop(lock(&self.slot.permit).take());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            sessions: 2,
            admin_sessions: 1,
            sessions_per_player: 1,
            handshakes: 3,
            handshakes_per_address: 2,
            retry_above: 2,
            handshake_timeout: Duration::from_secs(1),
            evictable_after: Duration::ZERO,
        }
    }

    #[tokio::test]
    async fn handshakes_are_capped_per_address_and_in_all() {
        let a = Admission::new(limits());
        let (x, y): (IpAddr, IpAddr) = ([127, 0, 0, 2].into(), [127, 0, 0, 3].into());
        let x1 = a.begin(x).unwrap();
        let _x2 = a.begin(x).unwrap();
        assert_eq!(a.begin(x).unwrap_err(), Refused::PerAddress);
        let _y1 = a.begin(y).unwrap();
        drop(x1);
        let _x3 = a
            .begin(x)
            .expect("a finished handshake frees both its slots");
        assert_eq!(a.per_address.lock().unwrap().len(), 2);
        assert_eq!(a.handshakes.available_permits(), 0);
        assert_eq!(
            a.begin(x).unwrap_err(),
            Refused::PerAddress,
            "even when full"
        );
    }

    #[tokio::test]
    async fn a_new_handshake_takes_the_oldest_ones_slot_when_all_are_taken() {
        let a = Admission::new(limits());
        let ip = |n: u8| IpAddr::from([127, 0, 0, n]);
        let (old, mid, new) = (
            a.begin(ip(2)).unwrap(),
            a.begin(ip(3)).unwrap(),
            a.begin(ip(4)).unwrap(),
        );
        let (lost, kept) = (old.eviction(), mid.eviction());
        // Every slot taken: the next one takes the oldest's.
        let newest = a.begin(ip(5)).unwrap();
        tokio::time::timeout(Duration::from_secs(1), lost.wait())
            .await
            .expect("the oldest handshake is told");
        assert_eq!(old.admit_player("old", 1).unwrap_err(), Refused::Evicted);
        assert_eq!(a.handshakes.available_permits(), 0, "still three in all");
        // Admitted, a handshake gives its slot back (however long its
        // eviction handle lives) and is out of the order: never evicted.
        let _session = mid.admit_player("mid", 2).unwrap();
        assert_eq!(a.handshakes.available_permits(), 1);
        let next = a.begin(ip(6)).unwrap();
        assert!(
            tokio::time::timeout(Duration::from_millis(50), kept.wait())
                .await
                .is_err(),
            "an admitted session lost its connection"
        );
        assert!(new.admit_player("new", 3).is_ok(), "a free slot was there");
        drop((newest, next));
        assert_eq!(a.handshakes.available_permits(), 3, "no slot leaked");
        assert!(a.per_address.lock().unwrap().is_empty());
    }

    #[tokio::test]
    async fn the_slot_taken_is_from_the_address_with_the_most_handshakes() {
        let a = Admission::new(limits());
        let (x, y): (IpAddr, IpAddr) = ([127, 0, 0, 2].into(), [127, 0, 0, 3].into());
        let oldest = a.begin(y).unwrap();
        let (x1, _x2) = (a.begin(x).unwrap(), a.begin(x).unwrap());
        let (kept, lost) = (oldest.eviction(), x1.eviction());
        let _z = a.begin([127, 0, 0, 4].into()).unwrap();
        tokio::time::timeout(Duration::from_secs(1), lost.wait())
            .await
            .expect("the oldest of the address with two");
        assert!(
            tokio::time::timeout(Duration::from_millis(50), kept.wait())
                .await
                .is_err(),
            "the oldest overall, alone from its address, kept its slot"
        );
    }

    #[tokio::test]
    async fn a_handshake_keeps_its_slot_until_it_is_evictable() {
        let a = Admission::new(Limits {
            evictable_after: Duration::from_secs(3600),
            ..limits()
        });
        let ip = |n: u8| IpAddr::from([127, 0, 0, n]);
        let _held = [a.begin(ip(2)), a.begin(ip(3)), a.begin(ip(4))];
        assert_eq!(a.begin(ip(5)).unwrap_err(), Refused::Handshakes);
    }

    #[tokio::test]
    async fn an_ipv6_slash_64_shares_one_address_worth_of_handshakes() {
        let a = Admission::new(limits());
        let ip = |s: &str| s.parse::<IpAddr>().unwrap();
        let _first = a.begin(ip("2001:db8:1:2::1")).unwrap();
        let _second = a.begin(ip("2001:db8:1:2:ffff::9")).unwrap();
        assert_eq!(
            a.begin(ip("2001:db8:1:2:abcd::7")).unwrap_err(),
            Refused::PerAddress,
            "the same /64"
        );
        assert!(a.begin(ip("2001:db8:1:3::1")).is_ok(), "another /64");
        assert_eq!(sharing_limits(ip("::ffff:10.0.0.1")), ip("10.0.0.1"));
        assert_eq!(sharing_limits(ip("10.0.0.1")), ip("10.0.0.1"));
    }

    #[tokio::test]
    async fn sessions_and_admin_sessions_have_their_own_room() {
        let a = Admission::new(limits());
        let ip: IpAddr = [127, 0, 0, 1].into();
        let p1 = a.begin(ip).unwrap().admit_player("ana", 1).unwrap();
        let _p2 = a.begin(ip).unwrap().admit_player("bo", 2).unwrap();
        assert_eq!(
            a.begin(ip).unwrap().admit_player("cy", 3).unwrap_err(),
            Refused::Sessions
        );
        let _admin = a.begin(ip).unwrap().admit_admin().unwrap();
        assert_eq!(
            a.begin(ip).unwrap().admit_admin().unwrap_err(),
            Refused::AdminSessions
        );
        drop(p1);
        assert!(a.begin(ip).unwrap().admit_player("cy", 4).is_ok());
        assert!(
            a.per_address.lock().unwrap().is_empty(),
            "no handshake left"
        );
    }
}
