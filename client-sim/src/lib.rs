//! Headless Strata client. Filled by the client-simulator issue (#5).
