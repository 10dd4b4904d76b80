//! Tickets: a node's signed statement of where a player stood, so another
//! node of the cluster (same auth secret, same world) lets the player
//! continue there (`ClientMessage::Arrive`) instead of at the spawn. A
//! server without `[cluster]` mints none and accepts none.
//!
//! The MAC covers a fixed byte layout (PROTOCOL.md, "Tickets"):
//! `strata-ticket-v2`, the world's id ([`crate::store::ChunkStore::world_id`]:
//! its length as u32 LE and bytes), the player name's length (u32 LE) and
//! bytes, the feet's x, y, z (i32 LE, 1/256 voxel) and `issued_ms` (u64 LE).
//! Bound to the world, a ticket is refused by another cluster's nodes that
//! happen to share the secret, and by its own once a restore replaced the
//! world (the positions it vouches for may not exist there).

use strata_protocol::limits::{TICKET_SKEW_MS, TICKET_TTL_MS};
use strata_protocol::{Ticket, TicketRefusal};
use strata_terrain::edit::FixedVec3;

use crate::auth::Secret;

const DOMAIN: &[u8] = b"strata-ticket-v2";

/// What signs and checks a cluster's tickets: its secret, for one world.
#[derive(Clone)]
pub struct TicketKey {
    secret: Secret,
    world: String,
}

impl std::fmt::Debug for TicketKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TicketKey")
            .field("world", &self.world)
            .finish_non_exhaustive()
    }
}

impl TicketKey {
    pub fn new(secret: Secret, world: impl Into<String>) -> Self {
        TicketKey {
            secret,
            world: world.into(),
        }
    }

    /// The world's id the tickets are bound to.
    pub fn world(&self) -> &str {
        &self.world
    }

    fn signed_bytes(&self, player: &str, feet: FixedVec3, issued_ms: u64) -> Vec<u8> {
        let mut b = Vec::with_capacity(DOMAIN.len() + 8 + self.world.len() + player.len() + 12 + 8);
        b.extend_from_slice(DOMAIN);
        for part in [self.world.as_bytes(), player.as_bytes()] {
            b.extend_from_slice(&(part.len() as u32).to_le_bytes());
            b.extend_from_slice(part);
        }
        for c in [feet.x, feet.y, feet.z] {
            b.extend_from_slice(&c.0.to_le_bytes());
        }
        b.extend_from_slice(&issued_ms.to_le_bytes());
        b
    }
}

/// A ticket for `player` standing at `feet` at `now_ms`.
pub fn mint(key: &TicketKey, player: &str, feet: FixedVec3, now_ms: u64) -> Ticket {
    Ticket {
        player: player.to_string(),
        feet,
        issued_ms: now_ms,
        mac: key.secret.sign(&key.signed_bytes(player, feet, now_ms)),
    }
}

/// Whether `ticket` lets `player` arrive at `now_ms` on a node holding
/// `key` (`None`: a server without `[cluster]`, which accepts none). The
/// cheap checks come first; the MAC last.
pub fn verify(
    key: Option<&TicketKey>,
    ticket: &Ticket,
    player: &str,
    now_ms: u64,
) -> Result<(), TicketRefusal> {
    let Some(key) = key else {
        return Err(TicketRefusal::NotClustered);
    };
    if ticket.player != player {
        return Err(TicketRefusal::OtherPlayer);
    }
    if ticket.issued_ms > now_ms.saturating_add(TICKET_SKEW_MS)
        || now_ms.saturating_sub(ticket.issued_ms) > TICKET_TTL_MS
    {
        return Err(TicketRefusal::Expired);
    }
    let f = ticket.feet;
    if ![f.x, f.y, f.z].iter().all(|c| c.in_coord_range()) {
        return Err(TicketRefusal::OutOfBounds);
    }
    let bytes = key.signed_bytes(&ticket.player, ticket.feet, ticket.issued_ms);
    if !key.secret.verify(&bytes, &ticket.mac) {
        return Err(TicketRefusal::BadSignature);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secret(b: u8) -> TicketKey {
        TicketKey::new(Secret::from_bytes([b; 32]), "world-a")
    }

    #[test]
    fn a_ticket_is_accepted_by_its_clusters_world_only_for_its_player_and_while_fresh() {
        let feet = FixedVec3::from_voxels(100, 40, -7);
        let t = mint(&secret(1), "ann", feet, 1_000_000);
        assert_eq!(verify(Some(&secret(1)), &t, "ann", 1_000_500), Ok(()));
        assert_eq!(
            verify(Some(&secret(2)), &t, "ann", 1_000_500),
            Err(TicketRefusal::BadSignature)
        );
        assert_eq!(
            verify(
                Some(&TicketKey::new(Secret::from_bytes([1; 32]), "world-b")),
                &t,
                "ann",
                1_000_500
            ),
            Err(TicketRefusal::BadSignature),
            "another world's nodes, with the same secret"
        );
        assert_eq!(
            verify(None, &t, "ann", 1_000_500),
            Err(TicketRefusal::NotClustered)
        );
        assert_eq!(
            verify(Some(&secret(1)), &t, "bob", 1_000_500),
            Err(TicketRefusal::OtherPlayer)
        );
        assert_eq!(
            verify(Some(&secret(1)), &t, "ann", 1_000_000 + TICKET_TTL_MS + 1),
            Err(TicketRefusal::Expired)
        );
        assert_eq!(
            verify(Some(&secret(1)), &t, "ann", 1_000_000 - TICKET_SKEW_MS - 1),
            Err(TicketRefusal::Expired)
        );
    }

    #[test]
    fn any_changed_field_breaks_the_signature() {
        let feet = FixedVec3::from_voxels(3, 4, 5);
        let t = mint(&secret(7), "ann", feet, 50_000);
        let mut moved = t.clone();
        moved.feet.x.0 += 1;
        assert_eq!(
            verify(Some(&secret(7)), &moved, "ann", 50_000),
            Err(TicketRefusal::BadSignature)
        );
        let mut later = t.clone();
        later.issued_ms += 1;
        assert_eq!(
            verify(Some(&secret(7)), &later, "ann", 50_000),
            Err(TicketRefusal::BadSignature)
        );
        let mut far = t;
        far.feet.z.0 = i32::MAX;
        assert_eq!(
            verify(Some(&secret(7)), &far, "ann", 50_000),
            Err(TicketRefusal::OutOfBounds)
        );
    }
}
