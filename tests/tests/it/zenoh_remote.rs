//! The graph off the robot over Zenoh, between real processes: the daemon (synthetic default
//! scene) listens on a loopback port; `tests/python/zenoh_consumer.py`, written from
//! docs/remote.md with only PyPI `eclipse-zenoh` and numpy, connects as a client with scouting
//! off, fetches the full graph from the queryable, follows the deltas, and must hold exactly what
//! `op3dsg dump --json` prints for the same version; so must `op3dsg dump --zenoh` (the Rust
//! client). A consumer that joins late converges too, and a daemon killed and started again is
//! seen as a new instance.

use std::net::TcpListener;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use op3dsg_ipc_types::OccupancyHeader;
use op3dsg_ipc_types::client::RemoteRequester;
use op3dsg_ipc_types::iceoryx2::prelude::NodeBuilder;
use op3dsg_ipc_types::services::IpcService;
use op3dsg_tests::{Daemon, binary, health_where, latest_map, open_occupancy_service, unique_prefix};
use serde_json::Value;

use crate::zenoh_common;
use zenoh_common::{Consumer, assert_same_graph, dump, dump_with, free_port, instance_of, python, same_version};

fn start_daemon(prefix: &str, port: u16, key_prefix: &str) -> Daemon {
    let listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    // 300 frames (10 s at the camera rate), then the last graph is served unchanged.
    let args = ["--set", "zenoh.enabled=true", "--set", &listen, "--set", &key, "--set", "run.max_frames=300"];
    Daemon::start(prefix, &args)
}

/// `op3dsg dump --json --zenoh`: the Rust client's view over Zenoh.
fn dump_zenoh(port: u16, key_prefix: &str) -> Value {
    let endpoint = format!("tcp/127.0.0.1:{port}");
    dump_with(&["dump", "--json", "--timeout-s", "30", "--zenoh", &endpoint, "--key-prefix", key_prefix])
}

#[test]
fn a_python_consumer_follows_the_graph_over_zenoh_joins_late_and_sees_a_restart() {
    let port = free_port();
    let key_prefix = format!("op3dsg/test-{}", std::process::id());
    let prefix = unique_prefix("zenoh");
    let mut daemon = start_daemon(&prefix, port, &key_prefix);
    let mut early = Consumer::start(port, &key_prefix);
    let instance = instance_of(&daemon);
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let watch = Command::new(binary("op3dsg"))
        .args(["watch", "--interval-ms", "200", "--zenoh", &endpoint, "--key-prefix", &key_prefix])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start op3dsg watch --zenoh");
    // Compared once every frame is fused: the richest graph of the run, reached through deltas.
    let mut health = daemon.health_subscriber("zenoh-test-health");
    health_where(&mut health, "all 300 frames captured", Duration::from_secs(300), |h| h.frames_captured >= 300);
    std::thread::sleep(Duration::from_secs(2));
    watch_followed(watch);

    let (dumped, held) = same_version(&daemon, &mut early, instance);
    assert_same_graph(&dumped, &held);
    let stats = &held["stats"];
    assert!(stats["deltas_applied"].as_u64() > Some(0), "the early consumer followed deltas: {stats}");
    assert!(stats["health"].as_u64() > Some(0), "health records arrived: {stats}");
    assert_eq!(held["instance_id"].as_u64(), Some(instance));
    let (node_count, edge_count) =
        (held["nodes"].as_array().map_or(0, Vec::len), held["edges"].as_array().map_or(0, Vec::len));
    let deltas = stats["deltas_applied"].as_u64().unwrap_or(1).max(1);
    eprintln!(
        "zenoh: version {} ({node_count} nodes, {edge_count} edges): a full graph is {} B; {deltas} deltas, {} B each on \
         average; consumer {stats}",
        held["graph_version"],
        40 + 112 + 144 * node_count + 64 * edge_count,
        stats["delta_bytes"].as_u64().unwrap_or(0) / deltas,
    );

    // The Rust client: `op3dsg dump --zenoh` from "another computer" prints what `op3dsg dump`
    // prints over iceoryx2.
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let local = dump(&daemon.prefix);
        let remote = dump_zenoh(port, &key_prefix);
        if local["graph_version"] == remote["graph_version"] {
            assert_same_graph(&local, &remote);
            break;
        }
        assert!(Instant::now() < deadline, "op3dsg dump and op3dsg dump --zenoh never met at one version");
    }

    let mut late = Consumer::start(port, &key_prefix);
    let (dumped, held) = same_version(&daemon, &mut late, instance);
    assert_same_graph(&dumped, &held);
    assert!(held["stats"]["fulls"].as_u64() >= Some(1), "the late consumer started from a full graph");
    drop(late);

    daemon.kill_9();
    let prefix = unique_prefix("zenoh-restarted");
    let restarted = start_daemon(&prefix, port, &key_prefix);
    let new_instance = instance_of(&restarted);
    assert_ne!(new_instance, instance);
    let (dumped, held) = same_version(&restarted, &mut early, new_instance);
    assert_same_graph(&dumped, &held);
    assert_eq!(held["stats"]["restarts"].as_u64(), Some(1), "the consumer saw the new instance: {held}");
}

#[test]
fn bad_zenoh_settings_stop_the_daemon_at_start_naming_the_key() {
    let run = |args: &[&str]| {
        let output = Command::new(binary("op3dsgd"))
            .arg("--prefix")
            .arg(unique_prefix("zenoh-bad"))
            .args(["--set", "zenoh.enabled=true"])
            .args(args)
            .stdin(Stdio::null())
            .output()
            .expect("run op3dsgd");
        assert!(!output.status.success(), "op3dsgd {args:?} started");
        String::from_utf8_lossy(&output.stderr).into_owned()
    };
    let stderr = run(&["--set", "zenoh.listen=[\"127.0.0.1:7447\"]"]);
    assert!(stderr.contains("zenoh.listen: \"127.0.0.1:7447\" is not a Zenoh endpoint"), "{stderr}");
    let stderr = run(&["--set", "zenoh.key_prefix=\"op3dsg/**\""]);
    assert!(stderr.contains("zenoh.key_prefix:"), "{stderr}");
    // A port another process holds: the session does not open, and the daemon says where to look.
    let taken = TcpListener::bind("127.0.0.1:0").expect("bind a port");
    let port = taken.local_addr().expect("port").port();
    let stderr = run(&["--set", &format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]")]);
    assert!(stderr.contains("zenoh.listen") && stderr.contains(&port.to_string()), "{stderr}");
}

// The daemon's requests over Zenoh: once its graph has settled, `op3dsg query --zenoh`,
// `op3dsg goal --zenoh` and `op3dsg health --zenoh` must give what the same commands give over
// iceoryx2 (real MiniLM from `.models/`), and `tests/python/zenoh_query.py` (PyPI
// `eclipse-zenoh` and the standard library, written from docs/remote.md) the same hits. Without
// a daemon, or under another key prefix, the commands fail in time naming the endpoint and key.

/// Frames of the daemon in the request tests (5 s at the camera rate).
const REQUEST_FRAMES: u64 = 150;

fn op3dsg(args: &[&str]) -> Output {
    Command::new(binary("op3dsg")).args(args).output().expect("run op3dsg")
}

fn json_of(args: &[&str]) -> Value {
    let output = op3dsg(args);
    assert!(output.status.success(), "op3dsg {args:?}: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("JSON")
}

/// The reply without what differs between two answers of the same graph (timings).
fn without_timings(mut reply: Value) -> Value {
    if let Some(object) = reply.as_object_mut() {
        object.remove("encode_us");
        object.remove("score_us");
    }
    reply
}

#[test]
fn query_goal_and_health_over_zenoh_answer_as_over_iceoryx2() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let key_prefix = format!("op3dsg/query-test-{}", std::process::id());
    let prefix = unique_prefix("zenoh-query");
    let listen = format!("zenoh.listen=[\"{endpoint}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    let frames = format!("run.max_frames={REQUEST_FRAMES}");
    let daemon = Daemon::start(
        &prefix,
        &[
            "--set",
            "zenoh.enabled=true",
            "--set",
            &listen,
            "--set",
            &key,
            "--set",
            &frames,
            "--set",
            "text_encoder.enabled=true",
        ],
    );
    let mut health = daemon.health_subscriber("zenoh-query-health");
    health_where(&mut health, "every frame captured", Duration::from_secs(300), |h| {
        h.frames_captured >= REQUEST_FRAMES
    });
    let zenoh = ["--zenoh", endpoint.as_str(), "--key-prefix", key_prefix.as_str()];
    let local = |args: &[&str]| json_of(&[&["--prefix", &prefix], args].concat());
    let remote = |args: &[&str]| json_of(&[args, &zenoh[..]].concat());

    // The graph and the occupancy map settle once the last frame is fused: both transports then
    // answer alike (hits, scores and approach poses).
    let text = "somewhere to wash my hands";
    let query = ["query", "--json", "--k", "5", "--timeout-s", "20", text];
    let started = Instant::now();
    let (here, there) = loop {
        let (here, there) = (without_timings(local(&query)), without_timings(remote(&query)));
        if here == there || started.elapsed() > Duration::from_secs(120) {
            break (here, there);
        }
        std::thread::sleep(Duration::from_millis(500));
    };
    assert_eq!(here, there, "op3dsg query over iceoryx2 and over Zenoh");
    let hits = here["hits"].as_array().expect("hits");
    assert!(!hits.is_empty(), "the query found nodes: {here}");
    eprintln!("query over Zenoh: {} hits at graph version {}, top {}", hits.len(), here["graph_version"], hits[0]);

    // A goal by node id: the same request on the same service.
    let node = hits[0]["node_id"].as_u64().expect("node id").to_string();
    let goal = ["goal", "--json", "--timeout-s", "20", node.as_str()];
    let goal_of = |args: &[&str]| {
        let output = op3dsg(args);
        (output.status.code(), serde_json::from_slice::<Value>(&output.stdout).expect("goal JSON"))
    };
    let started = Instant::now();
    let (goal_here, goal_there) = loop {
        let here = goal_of(&[&["--prefix", prefix.as_str()], &goal[..]].concat());
        let there = goal_of(&[&goal[..], &zenoh[..]].concat());
        if here == there || started.elapsed() > Duration::from_secs(60) {
            break (here, there);
        }
        std::thread::sleep(Duration::from_millis(500));
    };
    assert_eq!(goal_here, goal_there, "op3dsg goal over iceoryx2 and over Zenoh (exit code, JSON)");

    // Health: the same record form, the same source, frame and graph.
    let health_here = local(&["health", "--json"]);
    let health_there = remote(&["health", "--json", "--timeout-s", "10"]);
    let keys = |v: &Value| v.as_object().map(|o| o.keys().cloned().collect::<Vec<_>>()).unwrap_or_default();
    assert_eq!(keys(&health_here), keys(&health_there));
    for field in ["source_kind", "world_frame", "graph_version"] {
        assert_eq!(health_here[field], health_there[field], "health field {field}");
    }
    assert_eq!(health_there["source_kind"], "synthetic");
    let text_form = op3dsg(&[&["health"][..], &zenoh[..]].concat());
    assert!(text_form.status.success() && String::from_utf8_lossy(&text_form.stdout).contains("world frame"));

    // A consumer in Python from the documented bytes alone.
    python_agrees(&endpoint, &key_prefix, text, &here, &health_here);

    // The occupancy map: what iceoryx2 carries, over Zenoh.
    occupancy_agrees(&prefix, &endpoint, &key_prefix);

    // Another key prefix: no daemon answers, and the error says which key on which endpoint.
    let wrong = format!("{key_prefix}-not-there");
    let started = Instant::now();
    let output = op3dsg(&["query", "--timeout-s", "1", text, "--zenoh", &endpoint, "--key-prefix", &wrong]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "a query under a prefix nobody serves succeeded");
    assert!(stderr.contains(&format!("{wrong}/query")) && stderr.contains(&endpoint), "{stderr}");
    assert!(started.elapsed() < Duration::from_secs(10), "gave up in time: {:?}", started.elapsed());
    drop(daemon);
}

#[test]
fn without_a_daemon_the_zenoh_commands_name_the_endpoint() {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    for args in [&["health", "--timeout-s", "1"][..], &["query", "--timeout-s", "1", "sink"][..], &["goal", "3"][..]] {
        let started = Instant::now();
        let output = op3dsg(&[args, &["--zenoh", &endpoint, "--key-prefix", "op3dsg/nobody"][..]].concat());
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "op3dsg {args:?} without a daemon succeeded");
        assert!(stderr.contains(&endpoint), "op3dsg {args:?}: {stderr}");
        assert!(started.elapsed() < Duration::from_secs(30), "op3dsg {args:?} took {:?}", started.elapsed());
    }
}

/// `op3dsg watch --zenoh` printed the graph's versions as they came (a line per version or per
/// interval, the versions never going back) with the health record the daemon publishes.
fn watch_followed(mut watch: std::process::Child) {
    let _ = watch.kill();
    let output = watch.wait_with_output().expect("op3dsg watch output");
    let text = String::from_utf8_lossy(&output.stdout);
    let versions: Vec<u64> =
        text.lines().filter_map(|line| line.strip_prefix('v')?.split(' ').next()?.parse().ok()).collect();
    assert!(versions.len() >= 5, "op3dsg watch --zenoh printed {} graph lines:\n{text}", versions.len());
    assert!(versions.windows(2).all(|w| w[0] <= w[1]), "versions went back: {versions:?}");
    assert!(versions.last() > versions.first(), "the graph moved on: {versions:?}");
    let last = text.lines().last().unwrap_or_default();
    assert!(last.contains("synthetic in") && last.contains("| frames ") && last.contains("| fusion "), "{last}");
}

/// `<key_prefix>/occupancy` (the Rust client's `RemoteRequester::occupancy`) answers the map the
/// daemon publishes on `<prefix>/occupancy` over iceoryx2: the same cells and the same header,
/// but for the figures of each send (its time, the integration cost of the period before it).
fn occupancy_agrees(prefix: &str, endpoint: &str, key_prefix: &str) {
    let node = NodeBuilder::new()
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("a plain iceoryx2 node");
    let subscriber = open_occupancy_service(&node, prefix).subscriber_builder().create().expect("occupancy subscriber");
    let remote = RemoteRequester::connect(endpoint, key_prefix).expect("zenoh client");
    let sent_alike =
        |h: &OccupancyHeader| OccupancyHeader { publish_time_ns: 0, integrate_p50_us: 0, integrate_p99_us: 0, ..*h };
    let mut local = None;
    let started = Instant::now();
    loop {
        latest_map(&subscriber, &mut local);
        // The query asks with congestion control drop (as op3dsg does): under load a reply can be
        // lost (docs/remote.md), and the querier asks again, as a consumer would.
        let (envelope, header, cells) = match remote.occupancy(Duration::from_secs(10)) {
            Ok(answer) => answer,
            Err(e) if started.elapsed() < Duration::from_secs(60) => {
                eprintln!("occupancy over Zenoh: no answer ({e}), asking again");
                continue;
            }
            Err(e) => panic!("the map over Zenoh: no answer within a minute: {e}"),
        };
        assert_eq!(envelope.instance_id, header.instance_id, "the envelope names the map's daemon instance");
        assert_eq!(cells.len(), header.cell_count());
        if let Some((here, here_cells)) = &local
            && sent_alike(here) == sent_alike(&header)
            && *here_cells == cells
        {
            assert!(header.keyframes_integrated > 0 && header.free_cells > 0, "a map that was built: {header:?}");
            eprintln!(
                "occupancy over Zenoh: map {} of {}x{} cells, {} free, {} occupied, {} keyframes",
                envelope.version,
                header.width_cells,
                header.height_cells,
                header.free_cells,
                header.occupied_cells,
                header.keyframes_integrated
            );
            return;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the occupancy maps over iceoryx2 and Zenoh never agreed: {local:?} vs {header:?}"
        );
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// `tests/python/zenoh_query.py` gets the hits of `here` (an `op3dsg query --json` reply for
/// `text`) and a health record of the form of `health_here`.
fn python_agrees(endpoint: &str, key_prefix: &str, text: &str, here: &Value, health_here: &Value) {
    let keys = |v: &Value| v.as_object().map(|o| o.keys().cloned().collect::<Vec<_>>()).unwrap_or_default();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_query.py");
    let output = Command::new(python())
        .arg(&script)
        .args(["--connect", endpoint, "--prefix", key_prefix, "--text", text, "--k", "5"])
        .output()
        .expect("run zenoh_query.py");
    assert!(output.status.success(), "zenoh_query.py: {}", String::from_utf8_lossy(&output.stderr));
    let py: Value = serde_json::from_slice(&output.stdout).expect("zenoh_query.py JSON");
    assert_eq!(py["status"], "ok", "{py}");
    assert_eq!(py["graph_version"], here["graph_version"]);
    let ids = |hits: &Value| -> Vec<(u64, String)> {
        hits.as_array()
            .map(|h| h.iter().map(|h| (h["node_id"].as_u64().unwrap_or(0), h["label"].to_string())).collect())
            .unwrap_or_default()
    };
    assert_eq!(ids(&py["hits"]), ids(&here["hits"]), "python hits {py}");
    let output = Command::new(python())
        .arg(&script)
        .args(["--connect", endpoint, "--prefix", key_prefix, "--health"])
        .output()
        .expect("run zenoh_query.py --health");
    assert!(output.status.success(), "zenoh_query.py --health: {}", String::from_utf8_lossy(&output.stderr));
    let py: Value = serde_json::from_slice(&output.stdout).expect("health JSON");
    assert_eq!(keys(&py), keys(health_here));
}
