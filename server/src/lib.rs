//! Strata's server library. Networking, sessions and storage arrive with
//! the server issue (#4); the admin CLI's offline commands live here now.

pub mod admin;
