//! The web console in a real browser: headless Chromium loads the page
//! from a `strata-server` process that bots are playing on, signs in with
//! an admin token in the URL fragment, and the test checks what it drew:
//! map tiles on the canvas (a screenshot that is not blank), a marker per
//! player, charts that gained points from successive samples, and the 3-D
//! view's glTF of the chunks around the players, fetched and parsed.
//!
//! On a cluster node it also tints each region by the node that writes it,
//! with a legend of those nodes.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use strata_tests::chromium::{self, attribute};
use strata_tests::{binary, spawn_bots, Server, SERVER_CONFIG};

/// How long the page runs per load, in Chromium's virtual time.
const BUDGET_MS: u32 = 15_000;
/// Charts that must have drawn two samples or more.
const CHARTS: [&str; 3] = ["c-players", "c-latency", "c-phases"];
/// How long the bots may take to join and the page to show them.
const SHOW_TIMEOUT: Duration = Duration::from_secs(90);

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn admin_token(data_dir: &Path) -> String {
    let out = Command::new(binary("strata-admin"))
        .args([
            "token", "issue", "--player", "ops", "--role", "admin", "--ttl", "1h",
        ])
        .arg("--data-dir")
        .arg(data_dir)
        .output()
        .expect("strata-admin runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .last()
        .unwrap()
        .trim()
        .to_string()
}

fn number(dom: &str, marker: &str, attr: &str) -> u64 {
    attribute(dom, marker, attr)
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// The triangle count of the glTF the 3-D view fetched and parsed, drawn
/// or not (no WebGL2); `None` before one parsed (`no-webgl2` is set at the
/// page's start, before any fetch).
fn scene_parsed(dom: &str) -> Option<u64> {
    let state = attribute(dom, "id=\"scene-state\"", "data-state")?;
    if !matches!(state.as_str(), "drawn" | "parsed-no-webgl2") {
        return None;
    }
    attribute(dom, "id=\"scene-state\"", "data-triangles")?
        .parse()
        .ok()
}

/// Distinct colours in the screenshot's map canvas area (its top-left
/// 800 x 560 CSS pixels, below the header).
fn map_colours(png_path: &Path) -> usize {
    let file = std::fs::File::open(png_path).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let mut colours = std::collections::HashSet::new();
    for y in 80..620.min(info.height as usize) {
        for x in 10..800.min(info.width as usize) {
            let i = (y * info.width as usize + x) * channels;
            colours.insert([buf[i], buf[i + 1], buf[i + 2]]);
        }
    }
    colours.len()
}

#[test]
fn chromium_shows_the_live_map_players_and_charts() {
    let Some(chrome) = chromium::binary_or_skip("chromium_shows_the_live_map_players_and_charts")
    else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let port = free_port();
    let config = format!(
        "[engine]\ntick_ms = 10\n[console]\nlisten = \"127.0.0.1:{port}\"\nsample_ms = 250\n"
    );
    let server = Server::start_with(&data, "127.0.0.1:0", &config);
    let bots = spawn_bots(
        &server,
        &["--bots", "4", "--profile", "mixed", "--duration", "60s"],
    );
    let url = format!("http://127.0.0.1:{port}/#token={}", admin_token(&data));
    let profile = tmp.path().join("chromium");

    // The page shows every bot once they stand in the world.
    let start = Instant::now();
    let dom = loop {
        let dom = chromium::run(&chrome, &profile, &url, "--dump-dom", BUDGET_MS);
        // Edits (and so the latency chart) start once every bot has joined.
        let markers = number(&dom, "id=\"map\"", "data-markers");
        let settled = scene_parsed(&dom).is_some_and(|t| t > 0);
        let charted = CHARTS
            .iter()
            .all(|c| number(&dom, &format!("id=\"{c}\""), "data-points") >= 2);
        if (markers >= 4 && settled && charted) || start.elapsed() > SHOW_TIMEOUT {
            break dom;
        }
        std::thread::sleep(Duration::from_secs(2));
    };
    assert_eq!(
        attribute(&dom, "id=\"status\"", "data-state").as_deref(),
        Some("live"),
        "signed in and watching: {dom} {}",
        std::fs::read_to_string(profile.with_extension("log")).unwrap_or_default()
    );
    // The 3-D view fetched and parsed the glTF of the chunks around the
    // bots, triangles and all (drawn with WebGL2 where the browser has it).
    let triangles = scene_parsed(&dom);
    assert!(
        triangles.is_some_and(|t| t > 0),
        "3-D view: {:?} with {triangles:?} triangles",
        attribute(&dom, "id=\"scene-state\"", "data-state")
    );
    assert!(
        number(&dom, "id=\"map\"", "data-markers") >= 4,
        "a marker per bot"
    );
    assert!(
        number(&dom, "id=\"map\"", "data-tiles-drawn") > 0,
        "map tiles drawn"
    );
    // Each sample adds a point per series: two or more means it updated.
    for chart in CHARTS {
        let points = number(&dom, &format!("id=\"{chart}\""), "data-points");
        assert!(points >= 2, "{chart} has {points} points");
    }
    let edits = number(&dom, "id=\"c-edits\"", "data-points");
    assert!(
        edits >= 1,
        "edit rates are charted from the second sample on"
    );

    // The screenshot's map area is a drawn map, not a blank canvas.
    let shot = tmp.path().join("console.png");
    chromium::run(
        &chrome,
        &profile,
        &url,
        &format!("--screenshot={}", shot.display()),
        BUDGET_MS,
    );
    let colours = map_colours(&shot);
    assert!(colours > 100, "the map canvas shows {colours} colours");
    if let Some(keep) = std::env::var_os("STRATA_CONSOLE_SCREENSHOT") {
        std::fs::copy(&shot, keep).unwrap();
    }
    drop(bots);
    server.stop();
}

#[test]
fn chromium_maps_which_node_writes_each_region() {
    use std::collections::BTreeSet;
    use strata_server::cluster::ClusterConfig;
    use strata_server::sequencer::regions::{RegionId, DEFAULT_REGION_CHUNKS};
    use strata_server::store::pg::PgConfig;
    use strata_server::store::{ChunkStore, PgStore, RegionAccess};
    let Some(chrome) = chromium::binary_or_skip("chromium_maps_which_node_writes_each_region")
    else {
        return;
    };
    let Some(db) = strata_tests::postgres::database("console_regions_browser") else {
        return;
    };
    // Another node holds region (0, 0): the map's centre with no player.
    let pg = PgConfig {
        url: db.url(),
        ..PgConfig::default()
    };
    let east = ClusterConfig {
        node_id: "east".into(),
        adopt: false,
        ..ClusterConfig::default()
    };
    let east = PgStore::open_node(&pg, DEFAULT_REGION_CHUNKS, &east).unwrap();
    let origin = BTreeSet::from([RegionId { x: 0, z: 0 }]);
    assert_eq!(
        east.acquire_regions(&origin).unwrap(),
        RegionAccess::Granted
    );

    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let port = free_port();
    let config = format!(
        "{SERVER_CONFIG}{}[cluster]\nnode_id = \"west\"\n[console]\nlisten = \"127.0.0.1:{port}\"\n",
        db.store_toml()
    );
    let server = Server::start_with(&data, "127.0.0.1:0", &config);
    let url = format!("http://127.0.0.1:{port}/#token={}", admin_token(&data));
    let profile = tmp.path().join("chromium");
    let start = Instant::now();
    let dom = loop {
        let dom = chromium::run(&chrome, &profile, &url, "--dump-dom", BUDGET_MS);
        if dom.contains("data-node=\"east\"") || start.elapsed() > SHOW_TIMEOUT {
            break dom;
        }
        std::thread::sleep(Duration::from_secs(2));
    };
    // 800 x 560 voxels around (0, 0) at one pixel each: 4 x 4 regions.
    let regions = number(&dom, "id=\"map\"", "data-regions");
    assert_eq!(regions, 16, "regions outlined: {dom}");
    assert!(
        dom.contains("data-node=\"east\""),
        "east in the legend: {dom}"
    );
    assert!(
        !dom.contains("id=\"region-bar\" hidden"),
        "the legend shows on a cluster node"
    );
    server.stop();
    east.close().unwrap();
}
