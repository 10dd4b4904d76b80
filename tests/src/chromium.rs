//! Headless Chromium for the web console test: Debian's `chromium`, named
//! by `STRATA_CHROMIUM` (`scripts/test` installs it and sets it) or found
//! at `/usr/bin/chromium`. Without it the test fails under `CI=true` and
//! otherwise says that it did not run.
//!
//! Chromium runs with its background networking off and a throwaway
//! profile; the page it loads is served by the test's own server.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::Guard;

/// Environment variable naming the Chromium binary.
pub const CHROMIUM_ENV: &str = "STRATA_CHROMIUM";
/// Where Debian installs it.
pub const DEFAULT_CHROMIUM: &str = "/usr/bin/chromium";
/// Longest one Chromium run may take.
pub const RUN_TIMEOUT: Duration = Duration::from_secs(90);

/// The Chromium binary, or `None` (after saying so) outside CI. Under
/// `CI=true` a missing Chromium fails the test.
pub fn binary_or_skip(test: &str) -> Option<PathBuf> {
    let named = std::env::var_os(CHROMIUM_ENV).map(PathBuf::from);
    let path = named
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_CHROMIUM));
    if path.is_file() {
        return Some(path);
    }
    let why = match named {
        Some(p) => format!("{CHROMIUM_ENV}={} is not a file", p.display()),
        None => format!("{CHROMIUM_ENV} is not set and {DEFAULT_CHROMIUM} is missing"),
    };
    crate::not_run(test, "Chromium (apt-get install chromium)", &why)
}

/// One headless page load of `url`; `what` is `--dump-dom` or
/// `--screenshot=FILE`. Returns stdout (the DOM for `--dump-dom`).
pub fn run(bin: &Path, profile: &Path, url: &str, what: &str, budget_ms: u32) -> String {
    let child = Command::new(bin)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-default-apps",
            "--window-size=1200,1400",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--virtual-time-budget={budget_ms}"))
        .arg(what)
        .arg(url)
        .stdout(Stdio::piped())
        // Its log goes beside the profile (with stderr closed, Chromium
        // prints no DOM at all).
        .stderr(log_file(profile))
        .spawn()
        .expect("chromium starts");
    let (status, out) = crate::wait_with_output(Guard(child), RUN_TIMEOUT);
    assert!(status.success(), "chromium exited with {status}");
    out
}

/// `PROFILE.log`, appended to.
fn log_file(profile: &Path) -> std::fs::File {
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(profile.with_extension("log"))
        .expect("chromium log file")
}

/// The value of `attr` on the element whose tag text contains `marker`
/// (e.g. `id="map"`) in a dumped DOM.
pub fn attribute(dom: &str, marker: &str, attr: &str) -> Option<String> {
    let at = dom.find(marker)?;
    let start = dom[..at].rfind('<')?;
    let end = at + dom[at..].find('>')?;
    let tag = &dom[start..end];
    let key = format!("{attr}=\"");
    let from = tag.find(&key)? + key.len();
    let len = tag[from..].find('"')?;
    Some(tag[from..from + len].to_string())
}
