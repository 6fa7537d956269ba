//! The live view in a real Foxglove app in a real browser: Foxglove Studio's own app code (the
//! prebuilt bundle of npm `@foxglove/studio-base` 1.48.0, served from `.deps/browser` on
//! loopback by `tests/browser/serve.mjs`, nothing fetched at run time) in Debian's `chromium`,
//! headless, driven by `tests/browser/foxglove_check.mjs` (npm `puppeteer-core`). The app
//! imports `docs/foxglove-live-layout.json` through its own "Import layout" button, connects to
//! the daemon (synthetic default scene) with its own `foxglove.websocket.v1` offer, and the check
//! reads from the page: the connection is up, the topics list holds the scene, occupancy, tf and
//! health topics with their schema names, Problems says "No problems found", the 3D panel differs
//! from the empty grid it showed before connecting, and a health value is in the Plot legend.
//! Screenshots go to `target/tmp/live-view-app/`. `./scripts/setup-browser.sh` (run by
//! scripts/test.sh) installs chromium and the npm packages.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use op3dsg_tests::{Daemon, unique_prefix, wait_for};
use serde_json::Value;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

/// The app check's JSON summary of one run against the live view on `port`, the page offering
/// the subprotocols of `mode` (`native`: the app's own offer).
fn check(port: u16, mode: &str) -> Value {
    let studio = repo(".deps/browser/node_modules/@foxglove/studio-base/assets/index.js");
    assert!(studio.is_file(), "{} missing: run ./scripts/setup-browser.sh (scripts/test.sh does)", studio.display());
    let chromium = Command::new("chromium").arg("--version").output();
    assert!(
        chromium.is_ok_and(|o| o.status.success()),
        "chromium not found: run ./scripts/setup-browser.sh (Debian: apt-get install chromium)"
    );
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("live-view-app").join(mode);
    let _ = std::fs::remove_dir_all(&out);
    let output = Command::new("node")
        .arg(repo("tests/browser/foxglove_check.mjs"))
        .arg(format!("ws://127.0.0.1:{port}"))
        .arg(repo("docs/foxglove-live-layout.json"))
        .arg(mode)
        .arg(&out)
        .output()
        .expect("run node tests/browser/foxglove_check.mjs");
    let summary: Value = serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!("foxglove_check.mjs printed no summary ({e}): {}", String::from_utf8_lossy(&output.stderr))
    });
    println!("{}", serde_json::to_string_pretty(&summary).unwrap_or_default());
    summary
}

#[test]
fn foxglove_studio_in_chromium_opens_the_layout_draws_the_scene_and_plots_health() {
    let port = std::net::TcpListener::bind("127.0.0.1:0").expect("bind").local_addr().expect("port").port();
    let bind = format!("live_view.bind=\"127.0.0.1:{port}\"");
    let _daemon = Daemon::start(&unique_prefix("live-app"), &["--set", "live_view.enabled=true", "--set", &bind]);
    wait_for("the live view listening", Duration::from_secs(60), || {
        std::net::TcpStream::connect(("127.0.0.1", port)).ok()
    });
    let summary = check(port, "native");
    assert_eq!(summary["fatal"], Value::Null, "the check ran: {summary}");
    assert_eq!(summary["layoutLoaded"].as_array().map(Vec::len), Some(3), "the layout's three panels: {summary}");
    assert_eq!(summary["subprotocol"]["offeredByPage"][0][0], "foxglove.websocket.v1", "the app's own offer");
    assert_eq!(summary["subprotocol"]["serverAnswered"][0], "foxglove.websocket.v1");
    assert_eq!(summary["connection"]["up"], true, "connected: {}", summary["connection"]);
    let topics = summary["topics"].as_array().expect("topics");
    for (topic, schema) in [
        ("/op3dsg/scene", "foxglove.SceneUpdate"),
        ("/op3dsg/occupancy", "foxglove.Grid"),
        ("/tf", "foxglove.FrameTransform"),
        ("/op3dsg/health", "op3dsg.Health"),
    ] {
        assert!(
            topics.iter().any(|t| t["topic"] == topic && t["schema"] == schema),
            "{topic} ({schema}) in the app's topics list: {topics:?}"
        );
    }
    assert_eq!(summary["problems"]["entries"], Value::Array(vec![]), "Problems: {}", summary["problems"]);
    assert_eq!(summary["problems"]["text"], "No problems found");
    let drawn = summary["threeD"]["diffVsEmptyGrid"]["sceneChangedFraction"].as_f64().unwrap_or(0.0);
    assert!(drawn > 0.02, "the 3D panel shows the scene: {} of its pixels differ from the empty grid", drawn);
    assert_eq!(summary["plot"]["healthValueShown"], true, "a health value in the plot: {}", summary["plot"]);
    assert_eq!(summary["pageErrors"], Value::Array(vec![]), "the page threw: {}", summary["pageErrors"]);
}
