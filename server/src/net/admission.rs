//! Who gets in. A connection in its handshake (TLS, then `Hello` with a
//! valid token) holds a handshake slot: few of them, a few per address,
//! and only until a deadline. Only an authenticated session takes a session
//! slot, players and admins from separate pools, so a flood of connections
//! that never say Hello locks out neither players nor operators.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tracing::warn;

use crate::log_every::{LogEvery, LOG_EVERY};

/// The limits, from `[server]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Authenticated player sessions at once.
    pub sessions: u32,
    /// Authenticated admin sessions at once, beside the players'.
    pub admin_sessions: u32,
    /// Connections in their handshake at once.
    pub handshakes: u32,
    /// Connections in their handshake at once from one IP address.
    pub handshakes_per_address: u32,
    /// Handshakes in progress from which unvalidated addresses get a Retry.
    pub retry_above: u32,
    /// From the first packet to a verified Hello.
    pub handshake_timeout: Duration,
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
}

impl Refused {
    /// Metric label.
    pub fn label(self) -> &'static str {
        match self {
            Refused::Handshakes => "handshakes",
            Refused::PerAddress => "per_address",
            Refused::Sessions => "sessions",
            Refused::AdminSessions => "admin_sessions",
        }
    }

    /// What the client is told.
    pub fn message(self) -> &'static str {
        match self {
            Refused::Handshakes | Refused::PerAddress => "too many connections being set up",
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
    /// holds one, so it is bounded by `limits.handshakes`.
    per_address: Mutex<HashMap<IpAddr, u32>>,
    players: Arc<Semaphore>,
    admins: Arc<Semaphore>,
    /// Refusals are logged at most once a second, with a count.
    logged: LogEvery,
}

impl Admission {
    pub fn new(limits: Limits) -> Arc<Self> {
        let permits = |n: u32| Arc::new(Semaphore::new(n as usize));
        Arc::new(Self {
            handshakes: permits(limits.handshakes),
            players: permits(limits.sessions),
            admins: permits(limits.admin_sessions),
            per_address: Mutex::new(HashMap::new()),
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
        let Ok(permit) = self.handshakes.clone().try_acquire_owned() else {
            return Err(self.refused(Refused::Handshakes, addr));
        };
        per.insert(addr, here + 1);
        Ok(Handshake {
            _permit: permit,
            addr,
            deadline: tokio::time::Instant::now() + self.limits.handshake_timeout,
            admission: self.clone(),
        })
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

/// A connection in its handshake. Dropping it frees the slot.
#[derive(Debug)]
pub struct Handshake {
    _permit: OwnedSemaphorePermit,
    addr: IpAddr,
    /// The handshake must be done (Hello verified) by then.
    pub deadline: tokio::time::Instant,
    admission: Arc<Admission>,
}

impl Handshake {
    /// The client authenticated: trades the handshake slot for a session
    /// slot of its kind, held for the session's life.
    pub fn admit(self, admin: bool) -> Result<OwnedSemaphorePermit, Refused> {
        let (pool, why) = match admin {
            true => (&self.admission.admins, Refused::AdminSessions),
            false => (&self.admission.players, Refused::Sessions),
        };
        pool.clone()
            .try_acquire_owned()
            .map_err(|_| self.admission.refused(why, self.addr))
    }
}

impl Drop for Handshake {
    fn drop(&mut self) {
        let mut per = self
            .admission
            .per_address
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(n) = per.get_mut(&self.addr) {
            *n -= 1;
            if *n == 0 {
                per.remove(&self.addr);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            sessions: 2,
            admin_sessions: 1,
            handshakes: 3,
            handshakes_per_address: 2,
            retry_above: 2,
            handshake_timeout: Duration::from_secs(1),
        }
    }

    #[tokio::test]
    async fn handshakes_are_capped_per_address_and_in_all() {
        let a = Admission::new(limits());
        let (x, y, z) = (
            [127, 0, 0, 2].into(),
            [127, 0, 0, 3].into(),
            [127, 0, 0, 4].into(),
        );
        let x1 = a.begin(x).unwrap();
        let _x2 = a.begin(x).unwrap();
        assert_eq!(a.begin(x).unwrap_err(), Refused::PerAddress);
        let _y1 = a.begin(y).unwrap();
        assert_eq!(a.begin(z).unwrap_err(), Refused::Handshakes);
        drop(x1);
        assert!(
            a.begin(x).is_ok(),
            "a finished handshake frees both its slots"
        );
        assert_eq!(a.per_address.lock().unwrap().len(), 2);
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
        let p1 = a.begin(ip).unwrap().admit(false).unwrap();
        let _p2 = a.begin(ip).unwrap().admit(false).unwrap();
        assert_eq!(
            a.begin(ip).unwrap().admit(false).unwrap_err(),
            Refused::Sessions
        );
        let _admin = a.begin(ip).unwrap().admit(true).unwrap();
        assert_eq!(
            a.begin(ip).unwrap().admit(true).unwrap_err(),
            Refused::AdminSessions
        );
        drop(p1);
        assert!(a.begin(ip).unwrap().admit(false).is_ok());
        assert!(
            a.per_address.lock().unwrap().is_empty(),
            "no handshake left"
        );
    }
}
