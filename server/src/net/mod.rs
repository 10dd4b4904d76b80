//! The async shell: QUIC endpoint, one task per connection, bounded
//! writers. It moves bytes between sockets and the engine, nothing more.

pub mod admin_session;
pub mod admin_zones;
pub mod admission;
pub mod endpoint;
#[cfg(test)]
pub mod loopback;
pub mod player_buckets;
pub mod player_slots;
pub mod position_reads;
pub mod session;
pub mod transport_stats;
pub mod writer;
