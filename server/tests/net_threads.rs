//! `[server] net_threads` sizes the real server process's async runtime.

use crate::common;

use std::time::Duration;

use common::*;

/// The server's threads named as tokio names its runtime's workers.
fn runtime_threads(pid: u32) -> usize {
    std::fs::read_dir(format!("/proc/{pid}/task"))
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .filter(|name| name.trim_end() == "tokio-rt-worker")
        .count()
}

#[tokio::test]
async fn the_runtime_has_the_configured_threads() {
    tokio::time::timeout(TEST_TIMEOUT, async {
        for threads in [1, 3] {
            let root = tempfile::tempdir().unwrap();
            let data = root.path().join("data");
            let config = format!("[server]\nnet_threads = {threads}\n");
            let (child, addr) = spawn_server(&data, &config);
            // A session served on them.
            let c = process_client(&data, addr, "ana").await;
            let pong = c.ping(7).await;
            assert!(pong.is_ok(), "{pong:?}");
            // Workers start as the runtime does; allow for a slow box.
            let seen = eventually(Duration::from_secs(5), || {
                runtime_threads(child.id()) == threads
            })
            .await;
            assert!(
                seen,
                "{threads} configured, {} running",
                runtime_threads(child.id())
            );
        }
    })
    .await
    .expect("bounded");
}
