//! The graph and the map out to ROS 2, through Zenoh, without ROS: the daemon (synthetic default
//! scene) with `[ros2.out]` markers, occupancy and graph JSON on, a Zenoh router standing in for
//! `rmw_zenohd` or zenoh-bridge-ros2dds, and `tests/python/ros2_subscriber.py` (PyPI
//! `eclipse-zenoh`, `rosbags`, `xxhash` only, written from rmw_zenoh's and the bridge's published
//! formats) subscribed in each key style. What it decodes must be the graph `op3dsg dump --json`
//! prints: a box per node on its oriented box, parts coloured apart, a label per node; with
//! rmw_zenoh keys every message carries an attachment whose GID is that of the publisher's
//! liveliness token, and the node is announced.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_tests::{Daemon, health_where, unique_prefix};
use serde_json::Value;

use crate::zenoh_common;
use zenoh_common::{dump, free_port, python};

use crate::ros2_common;
use ros2_common::{Killed, router, script};

/// Frames of the synthetic run.
const FRAMES: u64 = 300;

/// `Marker` shapes and actions (visualization_msgs/msg/Marker).
const CUBE: i64 = 1;
const TEXT_VIEW_FACING: i64 = 9;
const LINE_LIST: i64 = 5;
const DELETEALL: i64 = 3;

/// Runs the daemon with the ROS output in `style` under a subscriber; what the subscriber saw
/// and `op3dsg dump --json` of the final graph.
fn run(style: &str) -> (Value, Value) {
    let port = free_port();
    let _router = router(port);
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut subscriber = Killed(
        Command::new(python())
            .arg(script("ros2_subscriber.py"))
            .args(["--key-style", style, "--distro", "humble", "--connect", &endpoint])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("start ros2_subscriber.py"),
    );
    let mut out = BufReader::new(subscriber.0.stdout.take().expect("stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("subscriber output");
    assert!(line.contains("ready"), "ros2_subscriber.py did not start: {line}");

    let prefix = unique_prefix(&format!("ros2-out-{style}"));
    let sets = [
        format!("run.max_frames={FRAMES}"),
        "run.exit_at_end=false".to_owned(),
        format!("ros2.key_style=\"{style}\""),
        format!("ros2.connect=[\"{endpoint}\"]"),
        "ros2.out.markers=true".to_owned(),
        "ros2.out.occupancy=true".to_owned(),
        "ros2.out.graph_json=true".to_owned(),
        "ros2.out.period_ms=200".to_owned(),
        // A noisy detector (split objects, false positives): the map merges
        // and removes nodes it had published, whose markers must then be deleted.
        "detector.oracle.preset=\"field\"".to_owned(),
        "detector.oracle.split_rate=0.5".to_owned(),
        "detector.oracle.false_positives_per_frame=2".to_owned(),
    ];
    let args: Vec<&str> = sets.iter().flat_map(|kv| ["--set", kv.as_str()]).collect();
    let daemon = Daemon::start(&prefix, &args);
    let mut health = daemon.health_subscriber(&format!("ros2-out-{style}-health"));
    health_where(&mut health, "every frame", Duration::from_secs(240), |h| h.frames_captured >= FRAMES);
    // The last version fused and sent (at most a period later).
    std::thread::sleep(Duration::from_secs(3));
    let dumped = dump(&prefix);
    let stage = op3dsg_json(&["--prefix", &prefix, "health", "--json"])["stages"]
        .as_array()
        .and_then(|s| s.iter().find(|s| s["name"] == "ros2_out").cloned());
    assert_eq!(stage.as_ref().map(|s| s["errors"].as_u64()), Some(Some(0)), "the stage ros2_out: {stage:?}");

    drop(subscriber.0.stdin.take());
    line.clear();
    out.read_line(&mut line).expect("subscriber summary");
    let seen: Value = serde_json::from_str(&line).expect("subscriber JSON");
    assert_eq!(seen["event"], "done", "{seen}");
    (seen, dumped)
}

fn op3dsg_json(args: &[&str]) -> Value {
    let output = Command::new(op3dsg_tests::binary("op3dsg")).args(args).output().expect("run op3dsg");
    assert!(output.status.success(), "op3dsg {args:?}: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("JSON")
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn close(a: &Value, b: &Value, what: &str) {
    let (a, b) = (a.as_array().expect(what), b.as_array().expect(what));
    assert_eq!(a.len(), b.len(), "{what}");
    for (x, y) in a.iter().zip(b) {
        assert!((f(x) - f(y)).abs() < 1e-4, "{what}: {a:?} vs {b:?}");
    }
}

/// The decoded topics hold the dumped graph: one box and one label per node, the JSON the same
/// version; the grid is the map's.
fn assert_graph_seen(seen: &Value, dumped: &Value) {
    let topics = &seen["topics"];
    for topic in ["/op3dsg/markers", "/op3dsg/occupancy", "/op3dsg/graph_json"] {
        assert!(topics[topic]["received"].as_u64() >= Some(1), "{topic}: {}", topics[topic]);
        assert_eq!(topics[topic]["errors"], serde_json::json!([]), "{topic}: rosbags decodes every payload");
    }
    let json = &topics["/op3dsg/graph_json"]["last"];
    assert_eq!(json["graph_version"], dumped["graph_version"], "the JSON of the final version");
    let ids = |g: &Value| g["nodes"].as_array().map(|n| n.iter().map(|n| n["id"].clone()).collect::<Vec<_>>());
    assert_eq!(ids(json), ids(dumped));

    let markers = topics["/op3dsg/markers"]["last"].as_array().expect("markers");
    let first_actions = &topics["/op3dsg/markers"]["markers_actions"][0];
    assert!(
        first_actions.as_array().is_some_and(|a| a.iter().any(|p| p[1].as_i64() == Some(DELETEALL))),
        "the first array clears the markers of an earlier run: {first_actions}"
    );
    let frame = markers[0]["frame_id"].as_str().unwrap_or_default().to_owned();
    assert!(!frame.is_empty() && markers.iter().all(|m| m["frame_id"] == frame.as_str()), "one frame");
    let nodes = dumped["nodes"].as_array().expect("nodes");
    assert!(nodes.len() >= 3, "the synthetic kitchen maps objects: {dumped}");
    let mut colours = std::collections::BTreeMap::new();
    for node in nodes {
        let ns = if node["kind"] == "part" { "parts" } else { "objects" };
        let find = |ns: &str, kind: i64| {
            markers.iter().find(|m| m["ns"] == ns && m["id"] == node["id"] && m["type"].as_i64() == Some(kind))
        };
        let cube = find(ns, CUBE).unwrap_or_else(|| panic!("a {ns} cube for node {}", node["id"]));
        let obb = &node["obb"];
        close(&cube["position"], &obb["centre_m"], "box centre");
        close(&cube["scale"], &obb["size_m"], "box size");
        // The cube turned by the box's yaw about up: its x axis at the yaw.
        let q = cube["orientation"].as_array().expect("orientation").iter().map(f).collect::<Vec<_>>();
        assert!((q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-6, "unit quaternion {q:?}");
        colours.insert(ns, cube["color"].clone());
        let label = find("labels", TEXT_VIEW_FACING).unwrap_or_else(|| panic!("a label for node {}", node["id"]));
        assert_eq!(label["text"], node["label"]);
    }
    if colours.len() == 2 {
        assert_ne!(colours["parts"], colours["objects"], "parts coloured apart");
    }
    let has_parts = nodes.iter().any(|n| n["kind"] == "part" && n["parent"].is_u64());
    let part_of = markers.iter().find(|m| m["ns"] == "edges" && m["id"] == 0);
    if has_parts {
        let lines = part_of.expect("part-of lines");
        assert_eq!(lines["type"].as_i64(), Some(LINE_LIST));
        assert!(lines["points"].as_u64() >= Some(2));
    }

    // Applied in order, the arrays leave RViz with a box for each node of the final graph and
    // nothing else: the boxes of nodes the map removed were deleted.
    let cubes = |list: &Value, with_type: bool| -> std::collections::BTreeSet<(String, u64)> {
        list.as_array()
            .expect("rviz")
            .iter()
            .filter(|m| m[0] == "objects" || m[0] == "parts")
            .filter(|m| !with_type || m[2].as_i64() == Some(CUBE))
            .map(|m| (m[0].as_str().unwrap_or_default().to_owned(), m[1].as_u64().unwrap_or(u64::MAX)))
            .collect()
    };
    let expected: std::collections::BTreeSet<(String, u64)> = nodes
        .iter()
        .map(|n| ((if n["kind"] == "part" { "parts" } else { "objects" }).to_owned(), n["id"].as_u64().unwrap_or(0)))
        .collect();
    let rviz = &seen["rviz"];
    assert_eq!(cubes(&rviz["shown"], true), expected, "RViz's boxes after every array: {rviz}");
    let removed = cubes(&rviz["ever_added"], false).difference(&expected).count() as u64;
    assert!(removed > 0, "the noisy run removed published nodes: {rviz}");
    assert!(rviz["deleted"].as_u64() >= Some(removed), "a DELETE for every removed box: {rviz}");

    let grid = &topics["/op3dsg/occupancy"]["last"];
    assert_eq!(grid["frame_id"].as_str(), Some(frame.as_str()), "the grid in the markers' frame");
    assert_eq!(
        grid["cells"].as_u64(),
        Some(grid["width"].as_u64().unwrap_or(0) * grid["height"].as_u64().unwrap_or(0))
    );
    assert!((f(&grid["resolution"]) - 0.05).abs() < 1e-6, "{grid}");
    assert!(grid["known"].as_u64() > Some(100), "the map knows cells: {grid}");
}

#[test]
fn rmw_zenoh_subscribers_get_markers_the_map_and_the_json_with_attachments_and_tokens() {
    let (seen, dumped) = run("rmw_zenoh");
    assert_graph_seen(&seen, &dumped);
    let tokens = seen["tokens"].as_array().expect("tokens");
    assert!(
        tokens.iter().any(|t| t["token"].as_str().is_some_and(|s| s.contains("/NN/%/%/op3dsg"))),
        "the node op3dsg announced: {tokens:?}"
    );
    for (topic, mangled, dds) in [
        ("/op3dsg/markers", "%op3dsg%markers", "visualization_msgs::msg::dds_::MarkerArray_"),
        ("/op3dsg/occupancy", "%op3dsg%occupancy", "nav_msgs::msg::dds_::OccupancyGrid_"),
        ("/op3dsg/graph_json", "%op3dsg%graph_json", "std_msgs::msg::dds_::String_"),
    ] {
        let entry = &seen["topics"][topic];
        let key = format!("0{}/{dds}/TypeHashNotSupported", topic);
        assert_eq!(entry["keys"], serde_json::json!([key]), "{topic}: Humble's key");
        let attachments = entry["attachments"].as_array().expect("attachments");
        assert!(attachments.iter().all(|a| a["error"].is_null()), "{topic}: {attachments:?}");
        let seqs: Vec<i64> = attachments.iter().filter_map(|a| a["seq"].as_i64()).collect();
        // Counted from 1 per publisher, one more per message; a subscriber may miss the first
        // ones (sent before Zenoh matched it) but never sees a number twice or going back.
        assert!(seqs.first().is_some_and(|&s| s >= 1), "{topic}: sequence numbers from 1: {seqs:?}");
        assert!(seqs.windows(2).all(|w| w[1] > w[0]), "{topic}: growing per message: {seqs:?}");
        assert!(
            seqs.last().is_some_and(|&last| last - seqs[0] + 1 >= seqs.len() as i64),
            "{topic}: one number per message: {seqs:?}"
        );
        let gid = &attachments[0]["gid"];
        assert!(attachments.iter().all(|a| &a["gid"] == gid), "{topic}: one publisher GID");
        let token = tokens
            .iter()
            .find(|t| {
                t["token"].as_str().is_some_and(|s| s.contains("/MP/") && s.contains(&format!("/{mangled}/{dds}/")))
            })
            .unwrap_or_else(|| panic!("{topic}: a publisher token in {tokens:?}"));
        assert_eq!(&token["gid"], gid, "{topic}: the attachment's GID is XXH3-128 of the publisher's token");
    }
}

#[test]
fn bridge_subscribers_get_markers_the_map_and_the_json_and_the_routes_are_announced() {
    let (seen, dumped) = run("bridge");
    assert_graph_seen(&seen, &dumped);
    let tokens = seen["tokens"].as_array().expect("tokens");
    for (topic, ty) in [
        ("/op3dsg/markers", "visualization_msgs§msg§MarkerArray"),
        ("/op3dsg/occupancy", "nav_msgs§msg§OccupancyGrid"),
        ("/op3dsg/graph_json", "std_msgs§msg§String"),
    ] {
        let key = topic.trim_start_matches('/');
        assert_eq!(seen["topics"][topic]["keys"], serde_json::json!([key]), "{topic}: the bridge's key");
        let route = format!("/@ros2_lv/MP/{}/{ty}/", key.replace('/', "§"));
        assert!(
            tokens.iter().any(|t| t["token"].as_str().is_some_and(|s| s.contains(&route))),
            "{topic}: a publisher route {route} in {tokens:?}"
        );
    }
}
