//! The graph off the robot over Zenoh, between real processes: the daemon (synthetic default
//! scene) listens on a loopback port; `tests/python/zenoh_consumer.py`, written from
//! docs/remote.md with only PyPI `eclipse-zenoh` and numpy, connects as a client with scouting
//! off, fetches the full graph from the queryable, follows the deltas, and must hold exactly what
//! `op3dsg dump --json` prints for the same version; so must `op3dsg dump --zenoh` (the Rust
//! client). A consumer that joins late converges too, and a daemon killed and started again is
//! seen as a new instance.

use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, binary, health_where, unique_prefix};
use serde_json::Value;

mod zenoh_common;
use zenoh_common::{Consumer, assert_same_graph, dump, dump_with, free_port, instance_of, same_version};

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
