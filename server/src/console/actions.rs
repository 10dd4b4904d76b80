//! Admin actions from the console: kick, ban, unban, add or remove a
//! protected zone, start a snapshot. Each request must say
//! `"confirm": true` (the page asks the operator first) and is logged with
//! the admin who sent it. They run through the admin protocol's own
//! request handler, so they behave exactly like `strata-admin`'s online
//! commands.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;
use strata_protocol::admin::{AdminRequest, ZoneSpec};
use strata_terrain::VoxelPos;
use tracing::info;

use super::Console;
use crate::net::admin_session::answer;

/// The body of `POST /api/action`.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionRequest {
    /// Must be true: the operator confirmed the action.
    pub confirm: bool,
    pub action: Action,
}

/// One admin action.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Action {
    /// End every live session of the player.
    Kick {
        player: String,
    },
    /// Refuse the player's logins until `until` (unix seconds; none:
    /// forever) and end its live sessions.
    Ban {
        player: String,
        until: Option<u64>,
    },
    Unban {
        player: String,
    },
    /// A protected zone: an inclusive voxel box no player may edit.
    ZoneAdd {
        name: String,
        min: [i32; 3],
        max: [i32; 3],
    },
    ZoneRemove {
        name: String,
    },
    /// Start an online snapshot written on the server.
    Snapshot,
}

/// Why an action was not done.
#[derive(Debug, thiserror::Error)]
pub enum ActionError {
    #[error("the action was not confirmed: send \"confirm\": true")]
    NotConfirmed,
    /// The server refused it (as it would `strata-admin`).
    #[error("{0}")]
    Refused(String),
    /// The engine could not be asked (overloaded or stopping).
    #[error("{0}")]
    Unavailable(String),
}

fn voxel([x, y, z]: [i32; 3]) -> VoxelPos {
    VoxelPos::new(x, y, z)
}

/// Does a confirmed action; the answer is the admin protocol's response
/// (or the snapshot's status) as JSON.
pub async fn run(
    console: &Arc<Console>,
    claims: &crate::auth::Claims,
    req: ActionRequest,
) -> Result<Value, ActionError> {
    let admin = claims.player.as_str();
    if !req.confirm {
        return Err(ActionError::NotConfirmed);
    }
    info!(%admin, action = ?req.action, "console action");
    let request = match req.action {
        Action::Snapshot => {
            let status = console
                .snapshots
                .start(&console.ctx, claims)
                .await
                .map_err(ActionError::Refused)?;
            return serde_json::to_value(status)
                .map_err(|e| ActionError::Unavailable(e.to_string()));
        }
        Action::Kick { player } => AdminRequest::Kick { player },
        Action::Ban { player, until } => AdminRequest::Ban { player, until },
        Action::Unban { player } => AdminRequest::Unban { player },
        Action::ZoneAdd { name, min, max } => AdminRequest::ZoneAdd(ZoneSpec {
            name,
            min: voxel(min),
            max: voxel(max),
        }),
        Action::ZoneRemove { name } => AdminRequest::ZoneRemove { name },
    };
    // Given up past the limit (a stalled engine or store): dropping the
    // request lets go of the write turn it may hold.
    let limit = crate::net::admin_session::ENGINE_ANSWER_LIMIT;
    let response = tokio::time::timeout(limit, answer(&console.ctx, request))
        .await
        .map_err(|_| {
            ActionError::Unavailable(format!(
                "the server did not answer within {} s; the change may or may not have been made",
                limit.as_secs()
            ))
        })?
        .map_err(ActionError::Unavailable)?;
    if let strata_protocol::admin::AdminResponse::Refused { message } = response {
        info!(%admin, %message, "console action refused");
        return Err(ActionError::Refused(message));
    }
    info!(%admin, ?response, "console action done");
    serde_json::to_value(&response).map_err(|e| ActionError::Unavailable(e.to_string()))
}
