//! The Foxglove live view between real processes: the daemon (synthetic default scene) serves
//! `[live_view]` on a free loopback port; `tests/python/foxglove_client.py`, written from
//! Foxglove's published WebSocket protocol specification with only PyPI `websockets` and
//! `protobuf`, subscribes, decodes `foxglove.SceneUpdate` against the schema the server
//! advertises, and must see the boxes of the graph `op3dsg dump --json` prints for the same
//! version. A viewer that subscribes to everything and never reads must not slow fusion, and
//! viewers connecting and leaving in a loop must not grow the daemon.

use std::io::{BufRead, BufReader};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_ipc_types::{Health, HealthSubscriber, fixed_str};
use op3dsg_tests::{Daemon, binary, health_where, unique_prefix, wait_for};
use serde_json::{Value, json};

fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(path.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", path.display());
    path
}

fn client() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python/foxglove_client.py")
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("bind a free port").local_addr().expect("port").port()
}

/// The daemon with the live view on `port` (and `extra` settings), `frames` frames of the
/// synthetic scene, then serving its last graph.
fn start_daemon(name: &str, port: u16, frames: u64, extra: &[&str]) -> Daemon {
    let bind = format!("live_view.bind=\"127.0.0.1:{port}\"");
    let max_frames = format!("run.max_frames={frames}");
    let mut args = vec!["--set", "live_view.enabled=true", "--set", &bind, "--set", &max_frames];
    for setting in extra {
        args.extend(["--set", setting]);
    }
    Daemon::start(&unique_prefix(name), &args)
}

fn url(port: u16) -> String {
    format!("ws://127.0.0.1:{port}")
}

fn dump(prefix: &str) -> Value {
    let output = Command::new(binary("op3dsg"))
        .args(["--prefix", prefix, "dump", "--json", "--timeout-s", "30"])
        .output()
        .expect("run op3dsg dump");
    assert!(output.status.success(), "op3dsg dump: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("dump JSON")
}

/// `count` scene updates as the client decoded them.
fn scenes(port: u16, count: usize) -> Vec<Value> {
    let output = Command::new(python())
        .arg(client())
        .args(["scene", "--url", &url(port), "--count", &count.to_string(), "--timeout-s", "30"])
        .output()
        .expect("run foxglove_client.py");
    assert!(output.status.success(), "foxglove_client.py scene: {}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8_lossy(&output.stdout).lines().map(|l| serde_json::from_str(l).expect("scene JSON")).collect()
}

fn all_frames_captured(daemon: &Daemon, frames: u64) -> HealthSubscriber {
    let mut health = daemon.health_subscriber("live-view-test-health");
    let what = format!("all {frames} frames captured");
    health_where(&mut health, &what, Duration::from_secs(300), |h| h.frames_captured >= frames);
    health
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array().expect("array").iter().map(|x| x.as_f64().expect("number")).collect()
}

fn close(a: &[f64], b: &[f64], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!((x - y).abs() < 1e-4, "{what}: {a:?} vs {b:?}");
    }
}

/// The scene's boxes, labels and lines are the dumped graph's.
fn assert_scene_is_graph(scene: &Value, graph: &Value) {
    assert_eq!(scene["deletions"][0]["type"], 1, "every update first deletes all entities");
    let entities = scene["entities"].as_array().expect("entities");
    let nodes = graph["nodes"].as_array().expect("nodes");
    assert!(!nodes.is_empty(), "the graph has nodes");
    let node_entities: Vec<&Value> =
        entities.iter().filter(|e| e["id"].as_str().unwrap_or("").starts_with("node/")).collect();
    assert_eq!(node_entities.len(), nodes.len(), "one entity per node");
    let (mut object_colours, mut part_colours) = (Vec::new(), Vec::new());
    for (entity, node) in node_entities.iter().zip(nodes) {
        let id = node["id"].as_u64().expect("id");
        assert_eq!(entity["id"], format!("node/{id}"));
        assert_eq!(entity["metadata"]["kind"], node["kind"]);
        assert_eq!(entity["texts"][0], node["label"], "the label");
        let cube = &entity["cubes"][0];
        let obb = &node["obb"];
        let size = f64s(&obb["size_m"]);
        if size.iter().all(|s| *s > 0.0) {
            close(&f64s(&cube["centre"]), &f64s(&obb["centre_m"]), &format!("node {id}: centre"));
            close(&f64s(&cube["size"]), &size, &format!("node {id}: size"));
        } else {
            let (min, max) = (f64s(&node["box_min_m"]), f64s(&node["box_max_m"]));
            let extent: Vec<f64> = min.iter().zip(&max).map(|(a, b)| b - a).collect();
            close(&f64s(&cube["size"]), &extent, &format!("node {id}: axis-aligned size"));
        }
        let colour = f64s(&cube["colour"]);
        if node["kind"] == "part" { part_colours.push(colour) } else { object_colours.push(colour) }
    }
    assert!(object_colours.windows(2).all(|w| w[0] == w[1]), "objects share one colour");
    assert!(part_colours.windows(2).all(|w| w[0] == w[1]), "parts share one colour");
    if let (Some(o), Some(p)) = (object_colours.first(), part_colours.first()) {
        assert_ne!(o, p, "parts are coloured apart from objects");
    }
    let edges = graph["edges"].as_array().expect("edges");
    for kind in ["spatial", "functional"] {
        let entity = entities.iter().find(|e| e["id"] == format!("edges/{kind}")).expect("edge entity");
        let points: usize =
            entity["lines"].as_array().expect("lines").iter().map(|l| l["points"].as_array().map_or(0, Vec::len)).sum();
        let count = edges.iter().filter(|e| e["kind"] == kind).count();
        assert_eq!(points, 2 * count, "{kind} edges: a line (two points) each");
    }
}

#[test]
fn a_foxglove_client_sees_the_boxes_of_the_graph_of_the_same_version() {
    let port = free_port();
    let daemon = start_daemon("live-view-scene", port, 300, &[]);
    let _health = all_frames_captured(&daemon, 300);
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let graph = dump(&daemon.prefix);
        let version = graph["graph_version"].as_u64().expect("graph_version");
        // The newest scene is sent again every second: a client that joins now gets it.
        let scene = scenes(port, 1).remove(0);
        if scene["graph_version"].as_u64() == Some(version) {
            assert_scene_is_graph(&scene, &graph);
            eprintln!(
                "live view: version {version}: {} entities ({} bytes) match the dumped graph",
                scene["entities"].as_array().map_or(0, Vec::len),
                scene["bytes"]
            );
            break;
        }
        assert!(Instant::now() < deadline, "the scene and the dump never met at one version");
    }
}

/// What `foxglove_client.py handshake` saw when offering `offer` (comma-separated names).
fn handshake(port: u16, offer: &str) -> Value {
    client_json(&["handshake", "--url", &url(port), "--offer", offer, "--timeout-s", "30"])
}

/// The one JSON line `foxglove_client.py` prints for `args` (its mode first).
fn client_json(args: &[&str]) -> Value {
    let output = Command::new(python()).arg(client()).args(args).output().expect("run foxglove_client.py");
    assert!(output.status.success(), "foxglove_client.py {}: {}", args[0], String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap_or_else(|e| panic!("foxglove_client.py {}: JSON: {e}", args[0]))
}

/// A client offering the protocol's first name (`foxglove.websocket.v1`, all that Foxglove Studio
/// and Lichtblick releases offer), the SDK's (`foxglove.sdk.v1`) or both connects, gets the name
/// it offered (the newest of several) and the channels; any other offer is refused with HTTP 400
/// naming the accepted ones. The client is PyPI `websockets`, which checks that the server picked
/// a subprotocol the client offered.
#[test]
fn a_foxglove_client_connects_with_either_name_of_the_protocol() {
    let port = free_port();
    let _daemon = start_daemon("live-view-names", port, 60, &[]);
    for (offer, picked) in [
        ("foxglove.websocket.v1", "foxglove.websocket.v1"),
        ("foxglove.sdk.v1", "foxglove.sdk.v1"),
        ("foxglove.websocket.v1,foxglove.sdk.v1", "foxglove.sdk.v1"),
        ("foxglove.sdk.v1,foxglove.websocket.v1", "foxglove.sdk.v1"),
    ] {
        let seen = handshake(port, offer);
        assert_eq!((&seen["status"], &seen["subprotocol"]), (&json!(101), &json!(picked)), "{offer}: {seen}");
        assert_eq!(seen["first_op"], "serverInfo", "{offer}: {seen}");
        let topics = seen["topics"].as_array().expect("topics");
        for topic in ["/op3dsg/scene", "/tf", "/op3dsg/health"] {
            assert!(topics.contains(&json!(topic)), "{offer}: {topic} advertised: {seen}");
        }
    }
    for offer in ["chat", ""] {
        let seen = handshake(port, offer);
        assert_eq!(seen["status"], 400, "{offer:?}: {seen}");
        let body = seen["body"].as_str().expect("body");
        assert!(
            body.contains("foxglove.sdk.v1.1, foxglove.sdk.v1 or foxglove.websocket.v1"),
            "{offer:?}: the answer names the accepted subprotocols: {body}"
        );
    }
}

/// The `fusion` stage's p99 latencies, µs, of the health records over `span`.
fn fusion_p99s(health: &mut HealthSubscriber, span: Duration) -> Vec<f64> {
    let (mut seen, mut p99s) = (0u64, Vec::new());
    let end = Instant::now() + span;
    while Instant::now() < end {
        if let Ok(Some(h)) = health.latest()
            && h.stamp_ns != seen
        {
            seen = h.stamp_ns;
            p99s.extend(fusion_stage(&h));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    p99s
}

fn fusion_stage(h: &Health) -> Option<f64> {
    h.stages[..h.stage_count as usize]
        .iter()
        .find(|s| fixed_str(&s.name) == "fusion" && s.latency_p99_us > 0.0)
        .map(|s| f64::from(s.latency_p99_us))
}

fn median(mut v: Vec<f64>) -> f64 {
    assert!(!v.is_empty(), "no fusion figures");
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_viewer_that_never_reads_does_not_slow_fusion() {
    let port = free_port();
    // Long enough for two windows; images on, so the stalled viewer's backlog fills fast.
    let daemon = start_daemon("live-view-stall", port, 1500, &["live_view.images=true", "live_view.image_scale=1"]);
    let mut health = daemon.health_subscriber("live-view-stall-health");
    health_where(&mut health, "fusion under way", Duration::from_secs(120), |h| h.frames_captured >= 150);
    let without = median(fusion_p99s(&mut health, Duration::from_secs(10)));
    let mut stalled = Killed(
        Command::new(python())
            .arg(client())
            .args(["stall", "--url", &url(port)])
            .stdout(Stdio::piped())
            .spawn()
            .expect("start the stalled viewer"),
    );
    let mut line = String::new();
    BufReader::new(stalled.0.stdout.take().expect("stdout")).read_line(&mut line).expect("read");
    assert_eq!(line.trim(), "subscribed", "the stalled viewer subscribed to every channel");
    let with = median(fusion_p99s(&mut health, Duration::from_secs(10)));
    assert!(matches!(stalled.0.try_wait(), Ok(None)), "the stalled viewer is still connected");
    eprintln!("live view: fusion p99 {without:.0} µs without a viewer, {with:.0} µs with one that never reads");
    // Generous: the map grows between the two windows, and the machine is shared.
    assert!(with <= 3.0 * without + 5_000.0, "a viewer that never reads slowed fusion: p99 {without} → {with} µs");
    let h = health.latest().ok().flatten().expect("health");
    assert!(h.frames_captured > 300, "capture went on");
}

fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("read /proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next().and_then(|n| n.parse().ok()))
        .expect("VmRSS")
}

fn churn(port: u16, cycles: u32) -> Value {
    client_json(&["churn", "--url", &url(port), "--clients", "5", "--cycles", &cycles.to_string()])
}

#[test]
fn five_viewers_connecting_and_leaving_in_a_loop_leak_nothing() {
    let port = free_port();
    let daemon = start_daemon("live-view-churn", port, 150, &["live_view.images=true"]);
    let _health = all_frames_captured(&daemon, 150);
    // The graph no longer changes: what grows from here is the live view's.
    std::thread::sleep(Duration::from_secs(2));
    let pid = daemon.child.id();
    churn(port, 5);
    let warm = rss_kib(pid);
    let run = churn(port, 40);
    assert!(run["messages_read"].as_u64() >= Some(200), "every viewer read a message: {run}");
    let after = wait_for("the daemon's memory", Duration::from_secs(5), || Some(rss_kib(pid)));
    eprintln!("live view: RSS {warm} KiB after warm-up, {after} KiB after 200 more viewers came and went");
    assert!(after <= warm + 16 * 1024, "RSS grew from {warm} to {after} KiB over 40 cycles of 5 viewers");
    // The shutdown ladder ends the live view too, with a viewer connected.
    let mut viewer = Killed(
        Command::new(python())
            .arg(client())
            .args(["stall", "--url", &url(port)])
            .stdout(Stdio::piped())
            .spawn()
            .expect("start a viewer"),
    );
    let mut line = String::new();
    BufReader::new(viewer.0.stdout.take().expect("stdout")).read_line(&mut line).expect("read");
    let mut daemon = daemon;
    daemon.sigterm();
    let status = daemon.wait_exit(Duration::from_secs(60)).expect("op3dsgd ends after SIGTERM");
    assert!(status.success(), "op3dsgd with a viewer connected exits cleanly on SIGTERM: {status}");
}
