//! A real server on 127.0.0.1 with port 0 and a temp data dir, plus tokens.
#![allow(dead_code)]

use std::path::Path;
use std::time::Duration;

use strata_client_sim::Client;
use strata_protocol::Role;
use strata_server::app::{self, Running};
use strata_server::auth;
use strata_server::config::ServerConfig;
use strata_terrain::{Fixed, FixedVec3};

/// Every network test gives up after this long.
pub const TEST_TIMEOUT: Duration = Duration::from_secs(60);

/// A config for tests: loopback, port 0, no spawn protection, fast ticks.
pub fn test_config(data_dir: &Path) -> ServerConfig {
    let mut cfg = ServerConfig::default();
    cfg.server.listen = "127.0.0.1:0".parse().unwrap();
    cfg.server.data_dir = data_dir.to_path_buf();
    cfg.validation.spawn_protection_radius = 0;
    cfg.interest.view_radius = 2;
    cfg.engine.tick_ms = 5;
    cfg
}

pub async fn start(data_dir: &Path) -> Running {
    app::start(test_config(data_dir))
        .await
        .expect("server starts")
}

pub fn token(server: &Running, player: &str, role: Role) -> String {
    auth::issue(
        server.data_dir.secret(),
        player,
        role,
        Duration::from_secs(3600),
        auth::unix_now(),
    )
    .unwrap()
}

pub async fn connect(server: &Running, player: &str, role: Role) -> Client {
    Client::connect(server.addr, &server.cert_der, &token(server, player, role))
        .await
        .expect("client connects")
}

/// Feet position in fixed point.
pub fn at(x: f64, y: f64, z: f64) -> FixedVec3 {
    FixedVec3::from_f64([x, y, z]).unwrap()
}

pub fn r(v: f64) -> Fixed {
    Fixed::from_f64(v).unwrap()
}

/// Polls `f` every 20 ms until it is true or `limit` passes.
pub async fn eventually(limit: Duration, mut f: impl FnMut() -> bool) -> bool {
    let start = std::time::Instant::now();
    while start.elapsed() < limit {
        if f() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    f()
}
