//! strata-client-sim's integration tests, one module per file beside this
//! one, in one test binary (the server and client are linked once). Run one
//! file's tests with `cargo test -p strata-client-sim --test integration -- bots::`.

mod bots;
mod hostile;
mod prediction;
mod prediction_net;
mod replica;
mod replica_checks;
