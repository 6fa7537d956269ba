//! The graph off the robot over Zenoh, between real processes: the daemon (synthetic default
//! scene) listens on a loopback port; `tests/python/zenoh_consumer.py`, written from
//! docs/remote.md with only PyPI `eclipse-zenoh` and numpy, connects as a client with scouting
//! off, fetches the full graph from the queryable, follows the deltas, and must hold exactly what
//! `op3dsg dump --json` prints for the same version; so must `op3dsg dump --zenoh` (the Rust
//! client). A consumer that joins late converges too, and a daemon killed and started again is
//! seen as a new instance.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, binary, health_where, unique_prefix, wait_for};
use serde_json::{Value, json};

fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(path.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", path.display());
    path
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").expect("bind a free port").local_addr().expect("port").port()
}

/// A consumer process, driven over its stdin and stdout; killed on drop.
struct Consumer {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
}

impl Consumer {
    fn start(port: u16, key_prefix: &str) -> Self {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_consumer.py");
        let mut child = Command::new(python())
            .arg(script)
            .args(["--connect", &format!("tcp/127.0.0.1:{port}"), "--prefix", key_prefix])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("run zenoh_consumer.py");
        let stdin = child.stdin.take().expect("stdin");
        let stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let mut consumer = Self { child, stdin, stdout };
        assert_eq!(consumer.read()["ready"], json!(true), "the consumer connects");
        consumer
    }

    fn read(&mut self) -> Value {
        let mut line = String::new();
        self.stdout.read_line(&mut line).expect("read the consumer's answer");
        assert!(!line.is_empty(), "the consumer ended (its stderr is above)");
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("consumer answer {line:?}: {e}"))
    }

    /// The consumer's graph once it holds one of `instance_id` at `min_version` or later.
    fn state(&mut self, instance_id: u64, min_version: u64) -> Value {
        let command = json!({"cmd": "state", "instance_id": instance_id, "min_version": min_version, "timeout_s": 120});
        writeln!(self.stdin, "{command}").expect("write to the consumer");
        let answer = self.read();
        assert!(answer.get("error").is_none(), "consumer: {answer}");
        answer
    }
}

impl Drop for Consumer {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "{}", json!({"cmd": "quit"}));
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_daemon(prefix: &str, port: u16, key_prefix: &str) -> Daemon {
    let listen = format!("zenoh.listen=[\"tcp/127.0.0.1:{port}\"]");
    let key = format!("zenoh.key_prefix=\"{key_prefix}\"");
    // 300 frames (10 s at the camera rate), then the last graph is served unchanged.
    let args = ["--set", "zenoh.enabled=true", "--set", &listen, "--set", &key, "--set", "run.max_frames=300"];
    Daemon::start(prefix, &args)
}

/// The instance id of the daemon's graphs, from its iceoryx2 graph service.
fn instance_of(daemon: &Daemon) -> u64 {
    let mut graphs = daemon.graph_subscriber("zenoh-test-instance");
    wait_for("a first graph over iceoryx2", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().map(op3dsg_ipc_types::Graph::instance_id)
    })
}

fn dump(prefix: &str) -> Value {
    dump_with(&["--prefix", prefix, "dump", "--json", "--timeout-s", "30"])
}

/// `op3dsg dump --json --zenoh`: the Rust client's view over Zenoh.
fn dump_zenoh(port: u16, key_prefix: &str) -> Value {
    let endpoint = format!("tcp/127.0.0.1:{port}");
    dump_with(&["dump", "--json", "--timeout-s", "30", "--zenoh", &endpoint, "--key-prefix", key_prefix])
}

fn dump_with(args: &[&str]) -> Value {
    let output = Command::new(binary("op3dsg")).args(args).output().expect("run op3dsg dump");
    assert!(output.status.success(), "op3dsg dump: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("dump JSON")
}

/// `op3dsg dump --json` and the consumer's graph at the same version: the daemon's versions stop
/// once its 300 frames are fused, so the two meet.
fn same_version(daemon: &Daemon, consumer: &mut Consumer, instance_id: u64) -> (Value, Value) {
    let deadline = Instant::now() + Duration::from_secs(300);
    loop {
        let dumped = dump(&daemon.prefix);
        let version = dumped["graph_version"].as_u64().expect("graph_version");
        let held = consumer.state(instance_id, version);
        if held["graph_version"].as_u64() == Some(version) {
            return (dumped, held);
        }
        assert!(Instant::now() < deadline, "dump and consumer never met at one version");
    }
}

fn assert_same_graph(dumped: &Value, held: &Value) {
    let nodes = |g: &Value| -> Vec<(u64, String, String, Value, Vec<f64>)> {
        g["nodes"]
            .as_array()
            .expect("nodes")
            .iter()
            .map(|n| {
                let centre = n["centre_m"].as_array().expect("centre").iter().map(|v| v.as_f64().expect("f")).collect();
                let label = n["label"].as_str().expect("label").to_owned();
                (
                    n["id"].as_u64().expect("id"),
                    label,
                    n["kind"].as_str().expect("kind").to_owned(),
                    n["parent"].clone(),
                    centre,
                )
            })
            .collect()
    };
    let (a, b) = (nodes(dumped), nodes(held));
    assert!(!a.is_empty(), "the daemon's graph has nodes");
    assert_eq!(a.len(), b.len(), "node count");
    for (x, y) in a.iter().zip(&b) {
        assert_eq!((&x.0, &x.1, &x.2, &x.3), (&y.0, &y.1, &y.2, &y.3), "node {}", x.0);
        for (u, v) in x.4.iter().zip(&y.4) {
            assert!((u - v).abs() <= 1e-5 * u.abs().max(1.0), "node {} centre {:?} vs {:?}", x.0, x.4, y.4);
        }
    }
    let edges = |g: &Value| -> Vec<(u64, u64, String, String, String)> {
        let mut edges: Vec<_> = g["edges"]
            .as_array()
            .expect("edges")
            .iter()
            .map(|e| {
                let text = |k: &str| e[k].as_str().expect("text").to_owned();
                (
                    e["source"].as_u64().expect("s"),
                    e["target"].as_u64().expect("t"),
                    text("kind"),
                    text("relation"),
                    text("origin"),
                )
            })
            .collect();
        edges.sort();
        edges
    };
    assert_eq!(edges(dumped), edges(held), "edges");
}

#[test]
fn a_python_consumer_follows_the_graph_over_zenoh_joins_late_and_sees_a_restart() {
    let port = free_port();
    let key_prefix = format!("op3dsg/test-{}", std::process::id());
    let prefix = unique_prefix("zenoh");
    let mut daemon = start_daemon(&prefix, port, &key_prefix);
    let mut early = Consumer::start(port, &key_prefix);
    let instance = instance_of(&daemon);
    // Compared once every frame is fused: the richest graph of the run, reached through deltas.
    let mut health = daemon.health_subscriber("zenoh-test-health");
    health_where(&mut health, "all 300 frames captured", Duration::from_secs(300), |h| h.frames_captured >= 300);

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
