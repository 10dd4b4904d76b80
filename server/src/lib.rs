//! Strata's server library: the admin CLI's commands now; networking,
//! sessions and storage arrive with the server issue (#4).

pub mod admin;
