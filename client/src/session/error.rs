//! Why a [`super::Session`] call failed.

use strata_terrain::mesh::MeshError;
use thiserror::Error;

use crate::client::ClientError;
use crate::edits::EditBuildError;

#[derive(Debug, Error)]
pub enum SessionError {
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("cannot start the connection's runtime: {0}")]
    Runtime(std::io::Error),
    #[error("too many edits or requests in flight; poll events and try again")]
    Busy,
    #[error("bad edit: {0}")]
    Edit(#[from] EditBuildError),
    #[error("bad position: not finite or out of the fixed-point range")]
    BadPosition,
    #[error(transparent)]
    Mesh(#[from] MeshError),
}
