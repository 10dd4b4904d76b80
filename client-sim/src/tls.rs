//! Client TLS (pinned server certificate); shared with `strata-admin`.

pub use strata_server::client_tls::*;
