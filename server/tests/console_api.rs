//! The web console's HTTP API against a real server on 127.0.0.1: who gets
//! in, map tiles that change after an edit, server-sent events that carry
//! it, the 3-D scene as glTF, the named limits, and the confirmed admin
//! actions (which take the admin protocol's own path).

use crate::common;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use common::*;
use serde_json::Value;
use strata_client_sim::{Client, Verdict};
use strata_protocol::admin::{AdminRequest, AdminResponse};
use strata_protocol::Role;
use strata_server::admin::glb::read_glb;
use strata_server::admin::remote::AdminClient;
use strata_terrain::{Edit, FixedVec3};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// One HTTP/1.1 exchange: status, headers (lower-case names), body.
struct Reply {
    status: u16,
    headers: String,
    body: Vec<u8>,
}

impl Reply {
    fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&self.body)))
    }
}

fn request_text(method: &str, path: &str, token: Option<&str>, body: &[u8]) -> Vec<u8> {
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n{auth}\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    )
    .into_bytes();
    req.extend_from_slice(body);
    req
}

/// `GET /api/world` with `token`, keeping the connection open.
fn keep_alive(token: &str) -> String {
    let text = request_text("GET", "/api/world", Some(token), b"");
    String::from_utf8(text)
        .unwrap()
        .replace("Connection: close", "Connection: keep-alive")
}

/// Decodes a chunked body.
fn dechunk(mut raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(end) = raw.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(std::str::from_utf8(&raw[..end]).unwrap().trim(), 16)
            .expect("chunk size");
        if size == 0 {
            break;
        }
        out.extend_from_slice(&raw[end + 2..end + 2 + size]);
        raw = &raw[end + 2 + size + 2..];
    }
    out
}

async fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    token: Option<&str>,
    body: &[u8],
) -> Reply {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(&request_text(method, path, token, body))
        .await
        .unwrap();
    let mut raw = Vec::new();
    tokio::time::timeout(Duration::from_secs(30), s.read_to_end(&mut raw))
        .await
        .expect("reply in time")
        .unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("headers end");
    let head = String::from_utf8_lossy(&raw[..split]).to_ascii_lowercase();
    let status = head[9..12].parse().unwrap();
    let mut body = raw[split + 4..].to_vec();
    if head.contains("transfer-encoding: chunked") {
        body = dechunk(&body);
    }
    Reply {
        status,
        headers: head,
        body,
    }
}

async fn get(addr: SocketAddr, path: &str, token: Option<&str>) -> Reply {
    http(addr, "GET", path, token, b"").await
}

async fn action(addr: SocketAddr, token: &str, body: Value) -> Reply {
    http(
        addr,
        "POST",
        "/api/action",
        Some(token),
        body.to_string().as_bytes(),
    )
    .await
}

/// An open event stream; [`Self::until`] reads it until a text appears.
struct Events {
    stream: TcpStream,
    seen: String,
}

impl Events {
    async fn open(addr: SocketAddr, token: &str) -> Events {
        let mut stream = TcpStream::connect(addr).await.unwrap();
        stream
            .write_all(&request_text("GET", "/api/events", Some(token), b""))
            .await
            .unwrap();
        let mut ev = Events {
            stream,
            seen: String::new(),
        };
        ev.until("\r\n\r\n", Duration::from_secs(10)).await;
        assert!(ev.seen.starts_with("HTTP/1.1 200"), "{}", ev.seen);
        assert!(ev.seen.contains("text/event-stream"), "{}", ev.seen);
        ev
    }

    /// Reads until `text` has arrived (panics after `limit`).
    async fn until(&mut self, text: &str, limit: Duration) {
        let deadline = Instant::now() + limit;
        let mut buf = [0u8; 16384];
        while !self.seen.contains(text) {
            let left = deadline.saturating_duration_since(Instant::now());
            let n = tokio::time::timeout(left, self.stream.read(&mut buf))
                .await
                .unwrap_or_else(|_| panic!("no {text:?} in time; got {}", self.tail()))
                .unwrap();
            assert!(n > 0, "the stream ended before {text:?}");
            self.seen.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
    }

    /// The last sample whose text holds `text`, parsed.
    fn sample_with(&self, text: &str) -> Value {
        let line = self
            .seen
            .lines()
            .rfind(|l| l.starts_with("data:") && l.contains(text))
            .unwrap_or_else(|| panic!("no sample with {text:?}"));
        serde_json::from_str(line["data:".len()..].trim()).unwrap()
    }

    /// Reads until the server ends the stream (panics after `limit`).
    async fn until_end(&mut self, limit: Duration) {
        let deadline = Instant::now() + limit;
        let mut buf = [0u8; 16384];
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match tokio::time::timeout(left, self.stream.read(&mut buf)).await {
                Ok(Ok(0)) | Ok(Err(_)) => return,
                Ok(Ok(n)) => self.seen.push_str(&String::from_utf8_lossy(&buf[..n])),
                Err(_) => panic!("the stream did not end in time; got {}", self.tail()),
            }
        }
    }

    fn tail(&self) -> &str {
        &self.seen[self.seen.len().saturating_sub(2000)..]
    }
}

fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// A player standing at `feet` whose view has arrived.
async fn standing_player(server: &app::Running, name: &str, feet: FixedVec3) -> Client {
    let c = connect(server, name, Role::Player).await;
    c.send_position(feet).unwrap();
    let here = strata_terrain::VoxelPos::new(
        feet.x.to_f64().floor() as i32,
        feet.y.to_f64().floor() as i32,
        feet.z.to_f64().floor() as i32,
    )
    .chunk();
    assert!(eventually(Duration::from_secs(20), || c.replica().get(here).is_some()).await);
    c
}

use strata_server::app;

/// A server with its console on a free loopback port, `[console]` set by `f`.
async fn start_console(
    dir: &std::path::Path,
    f: impl FnOnce(&mut strata_server::console::ConsoleConfig),
) -> (app::Running, SocketAddr) {
    let mut cfg = test_config(dir);
    cfg.console.listen = Some("127.0.0.1:0".parse().unwrap());
    f(&mut cfg.console);
    let server = app::start(cfg).await.unwrap();
    let web = server.console_addr.expect("console address");
    (server, web)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn console_serves_admins_the_live_world_and_their_actions() {
    tokio::time::timeout(Duration::from_secs(120), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| {
            c.max_watchers = 2;
            c.sample_ms = 100;
            c.keep_snapshots = 1;
            c.regions_per_request = 3;
        })
        .await;
        let admin = token(&server, "ops", Role::Admin);
        let player = token(&server, "ana", Role::Player);

        // Who gets in: nobody without a token, no player token, no forgery.
        for path in [
            "/api/world",
            "/api/tile?tx=0&tz=0",
            "/api/events",
            "/api/scene.glb?x0=0&z0=0&x1=0&z1=0",
            "/api/regions?x0=0&z0=0&x1=0&z1=0",
        ] {
            assert_eq!(get(web, path, None).await.status, 401, "{path}");
            assert_eq!(get(web, path, Some(&player)).await.status, 403, "{path}");
            let forged = format!("{}x", &admin[..admin.len() - 1]);
            assert_eq!(get(web, path, Some(&forged)).await.status, 401, "{path}");
        }
        let kick = serde_json::json!({"confirm": true, "action": {"kick": {"player": "ana"}}});
        assert_eq!(action(web, &player, kick.clone()).await.status, 403);
        // The page is public (it holds no data) and names no other origin.
        let page = get(web, "/", None).await;
        assert_eq!(page.status, 200);
        assert!(page.headers.contains("content-security-policy: default-src 'self'"));
        assert!(String::from_utf8_lossy(&page.body).contains("<canvas id=\"map\""));
        let world = get(web, "/api/world", Some(&admin)).await;
        assert_eq!(world.status, 200);
        // The seed and the rest: nothing for a cache to keep.
        assert!(world.headers.contains("cache-control: no-store"), "{}", world.headers);
        assert!(get(web, "/api/world", None)
            .await
            .headers
            .contains("cache-control: no-store"));
        assert_eq!(world.json()["admin"], "ops");
        assert_eq!(world.json()["samples"], 0, "nothing sampled before anyone watched");
        // Alone on its store, the node writes every region.
        assert_eq!(world.json()["clustered"], false);
        let regions = get(web, "/api/regions?x0=-1&z0=0&x1=8&z1=0", Some(&admin)).await;
        assert_eq!(regions.status, 200);
        let regions = regions.json();
        let holders: Vec<(i64, &str)> = regions["regions"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| (r["x"].as_i64().unwrap(), r["holder"].as_str().unwrap()))
            .collect();
        assert_eq!(holders, [(-1, "here"), (0, "here"), (1, "here")]);
        // Two rows of those three: past `regions_per_request`.
        let many = get(web, "/api/regions?x0=-1&z0=0&x1=8&z1=8", Some(&admin)).await;
        assert_eq!(many.status, 400);
        assert!(String::from_utf8_lossy(&many.body).contains("6 regions; at most 3"));
        for bad in [
            "/api/regions?x0=1&z0=0&x1=0&z1=0",
            "/api/regions?x0=0&z0=0&x1=100000&z1=100000",
            "/api/regions?x0=0&z0=0&x1=0",
        ] {
            assert_eq!(get(web, bad, Some(&admin)).await.status, 400, "{bad}");
        }

        // A tile before and after an edit in it.
        let (feet, ground) = spot(70, 40);
        let voxels = 128;
        let tile = format!(
            "/api/tile?view=top&tx={}&tz={}",
            ground.x.div_euclid(voxels),
            ground.z.div_euclid(voxels)
        );
        let before = get(web, &tile, Some(&admin)).await;
        assert_eq!(before.status, 200);
        assert!(before.headers.contains("content-type: image/png"));
        let (w, h, pixels) = decode_png(&before.body);
        assert_eq!((w, h), (128, 128));
        let mut colours: Vec<&[u8]> = pixels.chunks(3).collect();
        colours.sort_unstable();
        colours.dedup();
        assert!(colours.len() > 20, "a drawn map, not a blank: {} colours", colours.len());
        let again = get(web, &tile, Some(&admin)).await;
        assert_eq!(again.body, before.body, "cached while nothing changed");
        let slice = get(web, &format!("{tile}&view=slice&y=-20"), Some(&admin)).await;
        assert_eq!(slice.status, 200, "{}", String::from_utf8_lossy(&slice.body));
        assert_ne!(slice.body, before.body);

        let mut events = Events::open(web, &admin).await;
        events.until("event: sample", Duration::from_secs(10)).await;
        let ana = standing_player(&server, "ana", feet).await;
        events.until("\"player\":\"ana\"", Duration::from_secs(10)).await;
        let mine = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(3.0),
            strength: 255,
        };
        let seq = match ana.edit(mine).await.unwrap() {
            Verdict::Accepted { seq } => seq,
            other => panic!("{other:?}"),
        };
        // The event stream delivers the edit, where it happened.
        events
            .until("\"kind\":\"mine\"", Duration::from_secs(10))
            .await;
        let sample = events.sample_with("\"kind\":\"mine\"");
        let edit = &sample["edits"][0];
        assert_eq!((edit["seq"].as_u64(), edit["player"].as_str()), (Some(seq), Some("ana")));
        assert_eq!(edit["at"][0].as_f64(), Some(f64::from(ground.x)));
        assert!(!sample["columns"].as_array().unwrap().is_empty(), "{sample}");
        let after = get(web, &tile, Some(&admin)).await;
        assert_eq!(after.status, 200);
        assert_ne!(after.body, before.body, "the tile was redrawn after the edit");

        // The 3-D view: glTF of the edited chunk and its neighbours above
        // and below, from the same meshes the server builds.
        let c = ground.chunk();
        let scene = get(
            web,
            &format!(
                "/api/scene.glb?x0={}&z0={}&x1={}&z1={}&y0={}&y1={}",
                c.x,
                c.z,
                c.x,
                c.z,
                c.y - 1,
                c.y + 1
            ),
            Some(&admin),
        )
        .await;
        assert_eq!(scene.status, 200, "{}", String::from_utf8_lossy(&scene.body));
        assert!(scene.headers.contains("content-type: model/gltf-binary"));
        let glb = read_glb(&scene.body).unwrap();
        let acc = &glb.json["accessors"];
        assert_eq!(acc[0]["count"], glb.mesh.positions.len());
        assert_eq!(acc[4]["count"], glb.mesh.indices.len());
        assert!(glb.mesh.indices.len() >= 3 * 100, "a surface was meshed");
        assert_eq!(glb.json["meshes"].as_array().unwrap().len(), 1);
        let huge = get(web, "/api/scene.glb?x0=-20&z0=-20&x1=20&z1=20", Some(&admin)).await;
        assert_eq!(huge.status, 400, "scene_max_chunks");
        // A thin box counts the border its meshes read: 500 x 1 x 1 chunks
        // read 502 x 3 x 3.
        let y = format!("&y0={}&y1={}", c.y, c.y);
        let thin = get(web, &format!("/api/scene.glb?x0=0&z0=0&x1=499&z1=0{y}"), Some(&admin)).await;
        assert_eq!(thin.status, 400, "{}", String::from_utf8_lossy(&thin.body));
        assert_eq!(get(web, "/api/tile?tx=0&tz=0&evil=1", Some(&admin)).await.status, 400);
        assert_eq!(get(web, "/api/tile?tx=99999999&tz=0", Some(&admin)).await.status, 400);

        // At most max_watchers event streams.
        let _second = Events::open(web, &admin).await;
        assert_eq!(get(web, "/api/events", Some(&admin)).await.status, 503);

        // Actions need confirmation, a small body and a known shape.
        let unconfirmed = serde_json::json!({"confirm": false, "action": {"kick": {"player": "ana"}}});
        assert_eq!(action(web, &admin, unconfirmed).await.status, 400);
        let big = format!("{{\"confirm\":true,\"pad\":\"{}\"}}", "x".repeat(8192));
        let r = http(web, "POST", "/api/action", Some(&admin), big.as_bytes()).await;
        assert_eq!(r.status, 413);
        let odd = serde_json::json!({"confirm": true, "action": {"format_disk": {}}});
        assert_eq!(action(web, &admin, odd).await.status, 400);

        // A zone drawn from the console is the server's zone.
        let zone = serde_json::json!({"confirm": true, "action": {"zone_add": {
            "name": "plaza", "min": [0, -10, 0], "max": [9, 10, 9]}}});
        let r = action(web, &admin, zone).await;
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        let mut cli = AdminClient::connect(server.addr, &server.cert_der, &admin)
            .await
            .unwrap();
        match cli.request(&AdminRequest::Zones).await.unwrap() {
            AdminResponse::Zones(z) => assert!(z.iter().any(|z| z.name == "plaza"), "{z:?}"),
            other => panic!("{other:?}"),
        }
        events.until("\"name\":\"plaza\"", Duration::from_secs(10)).await;
        let remove = serde_json::json!({"confirm": true, "action": {"zone_remove": {"name": "plaza"}}});
        assert_eq!(action(web, &admin, remove.clone()).await.status, 200);
        assert_eq!(action(web, &admin, remove).await.status, 409, "already gone");

        // Kick, then ban: the player's session ends and it cannot return.
        let r = action(web, &admin, kick).await;
        assert_eq!(r.status, 200);
        assert_eq!(r.json()["ok"]["Kicked"]["sessions"], 1);
        ana.closed().await;
        let ban = serde_json::json!({"confirm": true, "action": {"ban": {"player": "ana", "until": null}}});
        assert_eq!(action(web, &admin, ban).await.status, 200);
        let refused = Client::connect(server.addr, &server.cert_der, &player).await;
        assert!(refused.is_err(), "a banned player cannot connect");

        // A snapshot started from the console, watched to its end; with
        // keep_snapshots = 1 an older console snapshot goes, other files stay.
        let snaps = dir.path().join("snapshots");
        std::fs::create_dir_all(&snaps).unwrap();
        let (older, notes) = (snaps.join("strata-seq0-1.snap"), snaps.join("notes.txt"));
        std::fs::write(&older, b"an older snapshot").unwrap();
        std::fs::write(&notes, b"keep me").unwrap();
        let snap = serde_json::json!({"confirm": true, "action": "snapshot"});
        let r = action(web, &admin, snap).await;
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        let file = r.json()["ok"]["file"].as_str().unwrap().to_string();
        events.until("\"state\":\"done\"", Duration::from_secs(30)).await;
        let report = strata_server::snapshot::verify(std::path::Path::new(&file), |_| {}).unwrap();
        assert!(report.is_ok(), "{:?}", report.issues);
        assert_eq!(report.header.unwrap().seq, seq);
        assert!(!older.exists(), "the older console snapshot was removed");
        assert!(notes.exists(), "other files are left alone");

        cli.close().await;
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn console_bounds_connections_and_closes_silent_ones() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| {
            c.max_connections = 2;
            c.idle_timeout_ms = 2000;
            c.request_timeout_ms = 1500;
            c.sample_ms = 200;
        })
        .await;
        let admin = token(&server, "ops", Role::Admin);
        let mut buf = [0u8; 64];
        // Two connections never admitted (no token yet) take both slots;
        // a third closes the older of them and is served.
        let mut first = TcpStream::connect(web).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let second = TcpStream::connect(web).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let mut third = TcpStream::connect(web).await.unwrap();
        third
            .write_all(&request_text("GET", "/api/world", Some(&admin), b""))
            .await
            .unwrap();
        let n = tokio::time::timeout(Duration::from_secs(10), third.read(&mut buf))
            .await
            .expect("served: an unadmitted connection made room")
            .unwrap();
        assert!(buf[..n].starts_with(b"HTTP/1.1 200"), "{:?}", &buf[..n]);
        let closed = tokio::time::timeout(Duration::from_secs(10), first.read(&mut buf))
            .await
            .expect("the oldest unadmitted connection is closed");
        assert!(matches!(closed, Ok(0) | Err(_)), "{closed:?}");
        drop((second, third));

        // Two admitted connections (a request with the admin token each,
        // kept alive) take both slots ...
        let mut admitted = Vec::new();
        for _ in 0..2 {
            let mut c = TcpStream::connect(web).await.unwrap();
            c.write_all(keep_alive(&admin).as_bytes()).await.unwrap();
            let n = tokio::time::timeout(Duration::from_secs(10), c.read(&mut buf))
                .await
                .expect("served")
                .unwrap();
            assert!(buf[..n].starts_with(b"HTTP/1.1 200"), "{:?}", &buf[..n]);
            admitted.push(c);
        }
        // ... so a third is not served while they stay (under the 2 s idle
        // timeout) ...
        let mut third = TcpStream::connect(web).await.unwrap();
        third
            .write_all(&request_text("GET", "/api/world", None, b""))
            .await
            .unwrap();
        let waited = tokio::time::timeout(Duration::from_millis(600), third.read(&mut buf)).await;
        assert!(waited.is_err(), "served past max_connections");
        // ... and is, once one of them leaves.
        drop(admitted.remove(0));
        let n = tokio::time::timeout(Duration::from_secs(10), third.read(&mut buf))
            .await
            .expect("served once a slot is free")
            .unwrap();
        assert!(buf[..n].starts_with(b"HTTP/1.1 401"), "{:?}", &buf[..n]);
        drop((third, admitted));
        // A silent connection is closed after idle_timeout_ms; an open
        // event stream is not (its keep-alives are traffic).
        let mut events = Events::open(web, &admin).await;
        let mut silent = TcpStream::connect(web).await.unwrap();
        let closed = tokio::time::timeout(Duration::from_secs(10), silent.read(&mut buf))
            .await
            .expect("a silent connection is closed");
        assert!(matches!(closed, Ok(0) | Err(_)), "{closed:?}");
        events.seen.clear();
        events.until("event: sample", Duration::from_secs(10)).await;

        // A request trickled in a byte at a time, never silent for long, is
        // closed after request_timeout_ms all the same.
        let mut trickle = TcpStream::connect(web).await.unwrap();
        let text = request_text("GET", "/api/world", None, b"");
        let started = Instant::now();
        let mut closed_after = None;
        for b in text.iter().cycle().take(200) {
            if trickle.write_all(&[*b]).await.is_err() {
                closed_after = Some(started.elapsed());
                break;
            }
            let mut probe = [0u8; 64];
            match tokio::time::timeout(Duration::from_millis(150), trickle.read(&mut probe)).await {
                Ok(Ok(0)) | Ok(Err(_)) => {
                    closed_after = Some(started.elapsed());
                    break;
                }
                Ok(Ok(n)) => panic!("answered a trickled request: {:?}", &probe[..n]),
                Err(_) => {}
            }
        }
        let closed_after = closed_after.expect("a trickled request is closed");
        assert!(
            closed_after >= Duration::from_millis(1400) && closed_after < Duration::from_secs(10),
            "closed after {closed_after:?}"
        );

        // Nobody watching, no sampling: the sampler sleeps once the last
        // stream is gone (it may take one more sample to notice).
        drop(events);
        let samples = || async {
            get(web, "/api/world", Some(&admin)).await.json()["samples"]
                .as_u64()
                .unwrap()
        };
        tokio::time::sleep(Duration::from_millis(1000)).await;
        let after_close = samples().await;
        tokio::time::sleep(Duration::from_millis(1500)).await;
        assert_eq!(samples().await, after_close, "sampled with nobody watching");
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// Pipelined requests a client sends without reading any answer.
const UNREAD_REQUESTS: usize = 300;
/// That client's receive buffer, so the server's writes soon block.
const SMALL_RECV_BUFFER: u32 = 2048;
/// How long a request may wait for the slot such a client held.
const SLOT_FREED_WITHIN: Duration = Duration::from_secs(10);

/// A client that sends requests and never reads the answers blocks the
/// server's writes, not its reads: it is closed after idle_timeout_ms all
/// the same, so it cannot keep the only connection slot.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_cannot_keep_a_slot() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| {
            c.max_connections = 1;
            c.idle_timeout_ms = 2000;
        })
        .await;
        let socket = tokio::net::TcpSocket::new_v4().unwrap();
        socket.set_recv_buffer_size(SMALL_RECV_BUFFER).unwrap();
        let mut hog = socket.connect(web).await.unwrap();
        let request = "GET /assets/map.js HTTP/1.1\r\nHost: x\r\n\r\n";
        hog.write_all(request.repeat(UNREAD_REQUESTS).as_bytes())
            .await
            .unwrap();
        let page = tokio::time::timeout(SLOT_FREED_WITHIN, get(web, "/", None))
            .await
            .expect("served while the non-reading client is connected");
        assert_eq!(page.status, 200);
        drop(hog);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// How long an event stream may go on once its token is no longer good.
const STREAM_ENDS_WITHIN: Duration = Duration::from_secs(10);
/// Lifetime of a short-lived admin token.
const SHORT_TOKEN_TTL: Duration = Duration::from_secs(2);

/// An event stream is checked at every sample, not only when it opens: it
/// ends once its admin is banned, and once its token expires; and the
/// server's shutdown ends those still open.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_event_stream_ends_when_its_token_is_no_longer_good() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| c.sample_ms = 100).await;
        let watcher = token(&server, "eve", Role::Admin);
        let other = token(&server, "ops", Role::Admin);
        let mut banned = Events::open(web, &watcher).await;
        let mut kept = Events::open(web, &other).await;
        banned
            .until("event: sample", Duration::from_secs(10))
            .await;
        let ban = serde_json::json!({"confirm": true, "action": {"ban": {"player": "eve", "until": null}}});
        let r = action(web, &other, ban).await;
        assert_eq!(r.status, 200, "{}", String::from_utf8_lossy(&r.body));
        banned.until_end(STREAM_ENDS_WITHIN).await;
        assert_eq!(get(web, "/api/world", Some(&watcher)).await.status, 403);
        // Another admin's stream goes on.
        kept.seen.clear();
        kept.until("event: sample", Duration::from_secs(10)).await;

        // A token that expires while its stream is open.
        let short = strata_server::auth::issue(
            server.data_dir.secret(),
            "ivy",
            Role::Admin,
            SHORT_TOKEN_TTL,
            strata_server::auth::unix_now(),
        )
        .unwrap();
        let mut expiring = Events::open(web, &short).await;
        expiring.until_end(SHORT_TOKEN_TTL + STREAM_ENDS_WITHIN).await;
        // The server's shutdown ends the streams still open.
        server.shutdown().await.unwrap();
        kept.until_end(STREAM_ENDS_WITHIN).await;
    })
    .await
    .expect("test timed out");
}

/// A connection still sending its first request is not closed for a new
/// one while a silent anonymous one can be: an operator's request gets
/// through a crowd of idle connections.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_connection_closes_a_silent_one_before_one_sending_its_request() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| c.max_connections = 2).await;
        let admin = token(&server, "ops", Role::Admin);
        let text = request_text("GET", "/api/world", Some(&admin), b"");
        let (head, tail) = text.split_at(20);
        // The oldest is an operator's, its request half sent ...
        let mut operator = TcpStream::connect(web).await.unwrap();
        operator.write_all(head).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        // ... then one that sends nothing, then one more.
        let mut silent = TcpStream::connect(web).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let _third = TcpStream::connect(web).await.unwrap();
        let mut buf = [0u8; 64];
        let closed = tokio::time::timeout(Duration::from_secs(10), silent.read(&mut buf))
            .await
            .expect("the silent connection is closed");
        assert!(matches!(closed, Ok(0) | Err(_)), "{closed:?}");
        operator.write_all(tail).await.unwrap();
        let n = tokio::time::timeout(Duration::from_secs(10), operator.read(&mut buf))
            .await
            .expect("the operator is answered")
            .unwrap();
        assert!(buf[..n].starts_with(b"HTTP/1.1 200"), "{:?}", &buf[..n]);
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// Anonymous connections sending request after request (each answered
/// 401 at once) hold no slot between them: an operator's new connection
/// closes one and is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn anonymous_requests_that_come_and_go_keep_no_slot_from_an_operator() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| c.max_connections = 2).await;
        let admin = token(&server, "ops", Role::Admin);
        let anonymous = String::from_utf8(request_text("GET", "/api/world", None, b""))
            .unwrap()
            .replace("Connection: close", "Connection: keep-alive");
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut crowd = Vec::new();
        for _ in 0..2 {
            let (stop, anonymous) = (stop.clone(), anonymous.clone());
            let mut c = TcpStream::connect(web).await.unwrap();
            crowd.push(tokio::spawn(async move {
                let mut buf = [0u8; 4096];
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    if c.write_all(anonymous.as_bytes()).await.is_err() {
                        break;
                    }
                    match c.read(&mut buf).await {
                        Ok(0) | Err(_) => break,
                        Ok(_) => {}
                    }
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
            }));
        }
        // Past the crowd's first second (a connection just accepted keeps
        // its slot that long).
        tokio::time::sleep(Duration::from_millis(1_500)).await;
        let mut operator = TcpStream::connect(web).await.unwrap();
        operator
            .write_all(&request_text("GET", "/api/world", Some(&admin), b""))
            .await
            .unwrap();
        let mut buf = [0u8; 64];
        let n = tokio::time::timeout(Duration::from_secs(10), operator.read(&mut buf))
            .await
            .expect("the operator is served")
            .unwrap();
        assert!(buf[..n].starts_with(b"HTTP/1.1 200"), "{:?}", &buf[..n]);
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for c in crowd {
            let _ = c.await;
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// Connections admitted by a token hold their slots only while it stays
/// good: once it expired, a new connection closes them and is served.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_admitted_by_a_token_no_longer_good_give_up_their_slots() {
    tokio::time::timeout(Duration::from_secs(60), async {
        let dir = tempfile::tempdir().unwrap();
        let (server, web) = start_console(dir.path(), |c| {
            c.max_connections = 2;
            c.idle_timeout_ms = 30_000;
        })
        .await;
        let short = strata_server::auth::issue(
            server.data_dir.secret(),
            "eve",
            Role::Admin,
            SHORT_TOKEN_TTL,
            strata_server::auth::unix_now(),
        )
        .unwrap();
        let keep_alive = keep_alive(&short);
        let mut buf = [0u8; 64];
        let mut held = Vec::new();
        for _ in 0..2 {
            let mut c = TcpStream::connect(web).await.unwrap();
            c.write_all(keep_alive.as_bytes()).await.unwrap();
            let n = tokio::time::timeout(Duration::from_secs(10), c.read(&mut buf))
                .await
                .expect("served")
                .unwrap();
            assert!(buf[..n].starts_with(b"HTTP/1.1 200"), "{:?}", &buf[..n]);
            held.push(c);
        }
        // Past the token's expiry (whole seconds), another admin gets in.
        tokio::time::sleep(SHORT_TOKEN_TTL + Duration::from_secs(1)).await;
        let admin = token(&server, "ops", Role::Admin);
        let r = tokio::time::timeout(
            Duration::from_secs(10),
            get(web, "/api/world", Some(&admin)),
        )
        .await
        .expect("served: a lapsed admission made room");
        assert_eq!(r.status, 200);
        for c in &mut held {
            // The rest of the first answer, then the end.
            let mut rest = Vec::new();
            let end = tokio::time::timeout(Duration::from_secs(5), c.read_to_end(&mut rest)).await;
            assert!(end.is_ok(), "a lapsed connection is closed");
        }
        server.shutdown().await.unwrap();
    })
    .await
    .expect("test timed out");
}

/// On a cluster node the map's overlay names who writes each region: this
/// node where its players edited, another node with its address, free
/// elsewhere.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_a_cluster_node_the_console_names_each_regions_writer() {
    use std::collections::BTreeSet;
    use strata_server::cluster::ClusterConfig;
    use strata_server::sequencer::regions::{RegionId, DEFAULT_REGION_CHUNKS};
    use strata_server::store::pg::PgConfig;
    use strata_server::store::{ChunkStore, PgStore, RegionAccess, StoreBackend};
    let Some(db) = strata_tests::postgres::database("console_regions") else {
        return;
    };
    tokio::time::timeout(Duration::from_secs(120), async {
        let dir = tempfile::tempdir().unwrap();
        let mut cfg = test_config(dir.path());
        cfg.console.listen = Some("127.0.0.1:0".parse().unwrap());
        cfg.store.backend = StoreBackend::Postgres;
        cfg.store.postgres.url = db.url();
        cfg.cluster = Some(ClusterConfig {
            node_id: "west".into(),
            ..ClusterConfig::default()
        });
        let server = app::start(cfg).await.unwrap();
        let web = server.console_addr.expect("console address");
        let admin = token(&server, "ops", Role::Admin);

        // Another node holds region (1, 0).
        let pg = PgConfig {
            url: db.url(),
            ..PgConfig::default()
        };
        let east = ClusterConfig {
            node_id: "east".into(),
            advertise: "10.0.0.2:7777".into(),
            ..ClusterConfig::default()
        };
        let east = tokio::task::spawn_blocking(move || {
            let store = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &east).unwrap();
            let region = BTreeSet::from([RegionId { x: 1, z: 0 }]);
            assert_eq!(
                store.acquire_regions(&region).unwrap(),
                RegionAccess::Granted
            );
            store
        })
        .await
        .unwrap();
        // A player's edit claims region (0, 0) for this node.
        let (feet, ground) = spot(70, 40);
        let ana = standing_player(&server, "ana", feet).await;
        let mine = Edit::Mine {
            center: FixedVec3::from_voxels(ground.x, ground.y, ground.z),
            radius: r(3.0),
            strength: 255,
        };
        assert!(matches!(
            ana.edit(mine).await.unwrap(),
            Verdict::Accepted { .. }
        ));

        let world = get(web, "/api/world", Some(&admin)).await.json();
        assert_eq!(world["clustered"], true);
        assert_eq!(world["node_id"], "west");
        assert_eq!(world["region_chunks"], 8);
        let reply = get(web, "/api/regions?x0=0&z0=0&x1=23&z1=7", Some(&admin)).await;
        assert_eq!(reply.status, 200);
        let regions = reply.json()["regions"].clone();
        let got: Vec<(i64, i64, String)> = regions
            .as_array()
            .unwrap()
            .iter()
            .map(|r| {
                let who = match r["holder"].as_str().unwrap() {
                    "node" => format!(
                        "{}@{}",
                        r["node"].as_str().unwrap(),
                        r["addr"].as_str().unwrap()
                    ),
                    h => h.to_string(),
                };
                (r["x"].as_i64().unwrap(), r["z"].as_i64().unwrap(), who)
            })
            .collect();
        assert_eq!(
            got,
            [
                (0, 0, "here".to_string()),
                (1, 0, "east@10.0.0.2:7777".to_string()),
                (2, 0, "free".to_string()),
            ]
        );
        ana.close().await;
        tokio::task::spawn_blocking(move || east.close().unwrap())
            .await
            .unwrap();
        server.shutdown().await.unwrap();
    })
    .await
    .expect("within the test timeout");
}

/// Threads of process `pid` named `prefix*`, with the CPU ticks (user and
/// system) each has used, from `/proc`.
fn threads_named(pid: u32, prefix: &str) -> Vec<u64> {
    let mut out = Vec::new();
    for t in std::fs::read_dir(format!("/proc/{pid}/task"))
        .unwrap()
        .flatten()
    {
        let comm = std::fs::read_to_string(t.path().join("comm")).unwrap_or_default();
        if !comm.starts_with(prefix) {
            continue;
        }
        let stat = std::fs::read_to_string(t.path().join("stat")).unwrap_or_default();
        // Fields after the name's closing parenthesis, from the state
        // (field 3): utime and stime are fields 14 and 15.
        let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
        let f: Vec<&str> = rest.split_whitespace().collect();
        let field = |n: usize| {
            f.get(n - 3)
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0)
        };
        out.push(field(14) + field(15));
    }
    out
}

/// Scenes asked for before the render threads must show CPU time.
const RENDER_TRIES: usize = 20;

/// Renders run on the console's own pool of `render_threads`, not on
/// threads the engine ticks on: a 3-D view's meshing is done by them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn renders_run_on_the_consoles_own_threads() {
    tokio::time::timeout(Duration::from_secs(120), async {
        let root = tempfile::tempdir().unwrap();
        let data = root.path().join("data");
        let web = free_metrics_addr();
        let config = format!("[console]\nlisten = \"{web}\"\nrender_threads = 3\n");
        let (child, _) = spawn_server(&data, &config);
        let dd = strata_server::datadir::DataDir::open_existing(&data).unwrap();
        let admin = strata_server::auth::issue(
            dd.secret(),
            "ops",
            Role::Admin,
            Duration::from_secs(600),
            strata_server::auth::unix_now(),
        )
        .unwrap();
        let pid = child.id();
        // The console may start after the address is printed: once it
        // answers, its pool is there.
        let started = Instant::now();
        while TcpStream::connect(web).await.is_err()
            || get(web, "/api/world", Some(&admin)).await.status != 200
        {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "the console answers"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert_eq!(threads_named(pid, "strata-render-").len(), 3);
        let before: u64 = threads_named(pid, "strata-render-").iter().sum();
        // 8 x 3 x 8 chunks meshed, about the surface.
        let y = spot(128, 128).1.chunk().y;
        let path = format!(
            "/api/scene.glb?x0=0&z0=0&x1=7&z1=7&y0={}&y1={}",
            y - 1,
            y + 1
        );
        // CPU time is counted in clock ticks (10 ms), and one scene may
        // fall between them on a loaded machine: renders are asked again
        // until the pool's threads show some, a bounded number of times.
        let mut used = before;
        for _ in 0..RENDER_TRIES {
            let scene = get(web, &path, Some(&admin)).await;
            assert_eq!(
                scene.status,
                200,
                "{}",
                String::from_utf8_lossy(&scene.body)
            );
            let glb = read_glb(&scene.body).unwrap();
            assert!(glb.mesh.indices.len() >= 3 * 1000, "a surface was meshed");
            used = threads_named(pid, "strata-render-").iter().sum();
            if used > before {
                break;
            }
        }
        assert!(
            used > before,
            "the render threads did the work: {before} -> {used} ticks \
             after {RENDER_TRIES} scenes"
        );
    })
    .await
    .expect("test finished in time");
}
