//! What [`super::Session::poll`] hands the game loop.

use strata_protocol::{ChunkVersion, ErrorCode, PositionRefusal, RejectReason};
use strata_terrain::edit::FixedVec3;
use strata_terrain::ChunkPos;

/// One thing that happened since the last poll. Every edit the session
/// took gets exactly one of `EditAccepted`, `EditRejected` or
/// `EditFailed`, and `Disconnected` comes once, last.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// The server sequenced edit `ticket` as `seq`; `changes` are the
    /// chunk versions it made durable (empty when it changed nothing).
    EditAccepted {
        ticket: u64,
        seq: u64,
        changes: Vec<ChunkVersion>,
    },
    /// The server refused edit `ticket`.
    EditRejected { ticket: u64, reason: RejectReason },
    /// No verdict will come for edit `ticket`: the connection ended, or the
    /// verdict took longer than [`crate::client::EDIT_TIMEOUT`].
    EditFailed { ticket: u64, error: String },
    /// The visible copy of a chunk changed, or it left the view (then
    /// [`super::Session::chunk`] returns `None`). A mesh reads its 26
    /// neighbours' border voxels, so theirs may change too.
    ChunkChanged { pos: ChunkPos },
    /// A server refused position report `seq` (as that node numbered it,
    /// on a cluster) and keeps the previous position, `at` (none before the
    /// first; `at.to_f64()` in voxels); rate-bounded: not every refused
    /// report is answered, and only the newest refusal not yet polled is
    /// kept. Move the player back to `at`: the server checks each report
    /// from there. On a cluster every node checks the walls of its own
    /// regions, so a refusal may come from any node connected.
    PositionRefused {
        seq: u32,
        reason: PositionRefusal,
        at: Option<FixedVec3>,
    },
    /// Every chunk of the view around chunk `center` at `radius` has
    /// arrived (except forgotten ones): the view is loaded. Its chunks are
    /// held now; their `ChunkChanged` events may still follow.
    ViewLoaded { center: ChunkPos, radius: u8 },
    /// The connection ended: `code` is the server's reason when it gave one.
    Disconnected {
        code: Option<ErrorCode>,
        message: String,
    },
}
