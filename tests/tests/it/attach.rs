//! Attaching gives the newest graph and map at once: against a daemon that has fused its last
//! frame and publishes no new version, each client attaches 50 times in a row and its first read
//! must return the daemon's graph (or map), never `None`: the Rust graph and occupancy
//! subscribers, the Python `GraphClient` and `OccupancyClient` (the project's venv), and both
//! Zenoh clients (Rust `RemoteGraphSubscriber`, Python `RemoteGraphClient`).

use std::process::Command;
use std::time::{Duration, Instant};

use op3dsg_ipc_types::client::RemoteGraphSubscriber;
use op3dsg_ipc_types::{GraphSubscriber, OccupancySubscriber};
use op3dsg_tests::{Daemon, health_where, unique_prefix};

use crate::zenoh_common::{free_port, python};

const ATTACHES: usize = 50;
const FRAMES: u64 = 60;

#[test]
fn every_first_read_after_attaching_has_the_newest_graph_and_map() {
    let prefix = unique_prefix("attach");
    let port = free_port();
    let key_prefix = format!("op3dsg/attach-{}", std::process::id());
    let listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    let max_frames = format!("run.max_frames={FRAMES}");
    let args = ["--set", &max_frames, "--set", "zenoh.enabled=true", "--set", &listen, "--set", &key];
    let daemon = Daemon::start(&prefix, &args);

    // The daemon's last graph: every frame fused and the version unchanged for two seconds.
    let mut health = daemon.health_subscriber("attach-health");
    health_where(&mut health, "every frame captured", Duration::from_secs(120), |h| h.frames_captured >= FRAMES);
    let (version, instance) = settled_graph(&prefix);
    assert!(version > 0, "the daemon published a graph");

    for i in 0..ATTACHES {
        let mut graphs = GraphSubscriber::open(&prefix, &format!("attach-graph-{i}")).expect("open the graph");
        let graph = graphs.latest().expect("read the graph");
        let graph = graph.unwrap_or_else(|| panic!("graph attach {i}: the first read gave no graph"));
        assert_eq!((graph.version(), graph.instance_id()), (version, instance), "graph attach {i}");
    }
    for i in 0..ATTACHES {
        let mut maps = OccupancySubscriber::open(&prefix, &format!("attach-map-{i}")).expect("open the map");
        let map = maps.latest().expect("read the map");
        assert!(map.is_some(), "occupancy attach {i}: the first read gave no map");
    }

    let endpoint = format!("tcp/127.0.0.1:{port}");
    for i in 0..ATTACHES {
        let mut remote = RemoteGraphSubscriber::connect(&endpoint, &key_prefix).expect("connect over Zenoh");
        let graph = remote.latest().expect("read over Zenoh");
        let graph = graph.unwrap_or_else(|| panic!("Zenoh attach {i}: the first read gave no graph"));
        assert_eq!((graph.version(), graph.instance_id()), (version, instance), "Zenoh attach {i}");
    }

    // The Python clients, as a planner uses them (the README's and planners.md's first lines).
    let script = r#"
import sys
import op3dsg
prefix, endpoint, key_prefix, attaches, version, instance = sys.argv[1:7]
attaches, version, instance = int(attaches), int(version), int(instance)
for i in range(attaches):
    with op3dsg.GraphClient(prefix) as client:
        graph = client.latest()
        assert graph is not None, f"Python graph attach {i}: the first read gave no graph"
        assert (graph.version, graph.instance_id) == (version, instance), f"Python graph attach {i}: {graph.version}"
for i in range(attaches):
    with op3dsg.OccupancyClient(prefix) as client:
        assert client.latest() is not None, f"Python occupancy attach {i}: the first read gave no map"
for i in range(attaches):
    with op3dsg.RemoteGraphClient(endpoint, key_prefix) as client:
        graph = client.latest()
        assert graph is not None, f"Python Zenoh attach {i}: the first read gave no graph"
        assert (graph.version, graph.instance_id) == (version, instance), f"Python Zenoh attach {i}: {graph.version}"
print("attached", attaches)
"#;
    let out = Command::new(python())
        .args(["-c", script, &prefix, &endpoint, &key_prefix])
        .args([ATTACHES.to_string(), version.to_string(), instance.to_string()])
        .output()
        .expect("run the Python clients");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "Python clients: {stderr}");
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), format!("attached {ATTACHES}"), "{stderr}");
}

/// The graph's version and instance once it stayed the same for two seconds.
fn settled_graph(prefix: &str) -> (u64, u64) {
    let mut graphs = GraphSubscriber::open_wait(prefix, "attach-settle", Duration::from_secs(30)).expect("open");
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut seen = (0, 0);
    let mut since = Instant::now();
    loop {
        graphs.wait_for_update(Duration::from_millis(200)).expect("wait");
        if let Some(graph) = graphs.latest().expect("read") {
            let now = (graph.version(), graph.instance_id());
            if now != seen {
                seen = now;
                since = Instant::now();
            }
        }
        if seen.0 > 0 && since.elapsed() >= Duration::from_secs(2) {
            return seen;
        }
        assert!(Instant::now() < deadline, "the graph never settled (last version {})", seen.0);
    }
}

/// The first Python a planner author copies, from README.md and docs/planners.md, run as written
/// (prefix `op3dsg`, in an iceoryx2 root of this test's own) five times each against a daemon
/// that publishes no new version: each run must find the graph at once.
#[test]
fn the_readme_and_planners_python_snippets_run_as_written() {
    if !op3dsg_tests::in_own_ipc_root("attach::the_readme_and_planners_python_snippets_run_as_written") {
        return;
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let snippet = |file: &str, marker: &str| -> String {
        let text = std::fs::read_to_string(root.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        let blocks: Vec<&str> = text.split("```python\n").skip(1).filter_map(|b| b.split("```").next()).collect();
        let block = blocks.iter().find(|b| b.contains(marker));
        block.unwrap_or_else(|| panic!("{file}: no python block with {marker:?}")).to_string()
    };
    let snippets = [
        ("README.md", snippet("README.md", "GraphClient(\"op3dsg\", timeout=30).latest()")),
        ("docs/planners.md", snippet("docs/planners.md", "graphs = op3dsg.GraphClient(\"op3dsg\", timeout=30)")),
    ];
    let max_frames = format!("run.max_frames={FRAMES}");
    let daemon = Daemon::start("op3dsg", &["--set", &max_frames]);
    let mut health = daemon.health_subscriber("snippets-health");
    health_where(&mut health, "every frame captured", Duration::from_secs(120), |h| h.frames_captured >= FRAMES);
    settled_graph("op3dsg");
    for (file, code) in &snippets {
        for run in 0..5 {
            let out = Command::new(python()).args(["-c", code]).output().expect("run python");
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(out.status.success(), "{file}'s snippet, run {run}: {stderr}\n{code}");
            assert!(!String::from_utf8_lossy(&out.stdout).trim().is_empty(), "{file}'s snippet printed nothing");
        }
    }
}
