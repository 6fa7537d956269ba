//! Map snapshots with the real daemon: a kill -9 loses nothing a snapshot held (the restarted
//! daemon's first graph holds the snapshot's nodes, ids and all, and its versions go on from
//! there, with a new instance id); SIGKILL in the middle of a snapshot write leaves the previous
//! snapshot intact; a corrupted snapshot is moved aside (never deleted) and reported, and the
//! daemon starts empty. The snapshot file is read back with `op3dsg map info --json`.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_ipc_types::SNAPSHOT_STATES;
use op3dsg_tests::{Daemon, binary, unique_prefix, wait_for};

/// (ids, labels) of a graph's nodes, sorted by id.
fn nodes(graph: &op3dsg_ipc_types::Graph) -> Vec<(u32, String)> {
    graph.nodes().map(|n| (n.id(), n.label().to_owned())).collect()
}

/// `op3dsg map info --json --dir <dir>`: `Ok(json)` or `Err(stderr)`.
fn map_info(dir: &Path) -> Result<serde_json::Value, String> {
    let out = Command::new(binary("op3dsg"))
        .args(["map", "info", "--json", "--dir"])
        .arg(dir)
        .output()
        .expect("run op3dsg map info");
    if out.status.success() {
        Ok(serde_json::from_slice(&out.stdout).expect("map info prints JSON"))
    } else {
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// iceoryx2 nodes (alive or dead) created by process `pid`.
fn iceoryx2_nodes_of(pid: u32) -> usize {
    use iceoryx2::node::NodeView;
    use iceoryx2::prelude::*;
    let mut found = 0;
    let of_pid =
        |id: &iceoryx2::identifiers::UniqueNodeId| id.pid::<ipc::Service>().is_ok_and(|p| p.value() as u32 == pid);
    // The daemon's iceoryx2 files are in this user's IPC root, not iceoryx2's default.
    let config = op3dsg_ipc_types::IpcRoot::resolve().config().expect("the IPC root's iceoryx2 config");
    let listed = Node::<ipc::Service>::list(&config, |state| {
        let matches = match &state {
            NodeState::Alive(view) => of_pid(view.id()),
            NodeState::Dead(view) => of_pid(view.id()),
            _ => false,
        };
        found += usize::from(matches);
        CallbackProgression::Continue
    });
    assert!(listed.is_ok(), "list iceoryx2 nodes: {listed:?}");
    found
}

fn snapshot_args(dir: &Path, extra: &[&str]) -> Vec<String> {
    let mut args = vec![
        "--set".to_owned(),
        format!("snapshot.dir=\"{}\"", dir.display()),
        "--set".to_owned(),
        "snapshot.period_s=0.5".to_owned(),
        "--set".to_owned(),
        "source.rate_hz=60".to_owned(),
    ];
    args.extend(extra.iter().map(|s| (*s).to_owned()));
    args
}

fn start(prefix: &str, args: &[String], env: &[(&str, &std::ffi::OsStr)]) -> Daemon {
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    Daemon::start_with_env(prefix, &args, env)
}

#[test]
fn after_kill_9_the_first_graph_holds_the_snapshot_and_versions_go_on() {
    let dir = tempfile::tempdir().expect("temp dir");
    let prefix = unique_prefix("snap-restart");
    // The source stops after 240 frames and the daemon keeps serving, so the map settles and
    // the last snapshot is exactly the last graph published before the kill.
    let args = snapshot_args(dir.path(), &["--set", "run.max_frames=240", "--set", "health.period_ms=100"]);
    let mut first = start(&prefix, &args, &[]);
    let mut graphs = first.graph_subscriber("snap-restart-graphs");
    let before = wait_for("the map to settle and its snapshot to catch up", Duration::from_secs(120), || {
        let graph = graphs.latest().ok().flatten()?.clone();
        let info = map_info(dir.path()).ok()?;
        let settled = graph.node_count() > 0 && info["graph_version"].as_u64() == Some(graph.version());
        std::thread::sleep(Duration::from_millis(700));
        // Still the same version after another snapshot period: settled.
        let again = graphs.latest().ok().flatten()?.clone();
        (settled && again.version() == graph.version()).then_some(graph)
    });
    let before_instance = before.instance_id();
    // Health tells how the map started and what was last written, without a graph subscriber.
    let mut health = first.health_subscriber("snap-restart-health");
    let written = wait_for("health to report the settled snapshot", Duration::from_secs(30), || {
        health.latest().ok().flatten().map(|h| h.snapshot).filter(|s| s.version == before.version())
    });
    assert_eq!(SNAPSHOT_STATES[written.state as usize], "started_empty", "{written:?}");
    assert!(written.written > 0 && written.last_bytes > 0 && written.last_written_unix_ms > 0, "{written:?}");
    assert_eq!((written.restored_version, written.failures), (0, 0), "{written:?}");
    drop(health);
    let first_pid = first.child.id();
    assert!(iceoryx2_nodes_of(first_pid) > 0, "the running daemon has iceoryx2 nodes");
    first.kill_9();

    // Restart on the same prefix: the dead daemon's iceoryx2 resources are cleaned up (the new
    // one would refuse a prefix a live daemon serves) and the map comes back.
    // Frames come slowly after the restart, so the restored graph is not overtaken by a newer
    // version before this subscriber polls (it takes the newest sample queued).
    let mut slow = args.clone();
    slow.extend(["--set".to_owned(), "source.rate_hz=2".to_owned()]);
    let second = start(&prefix, &slow, &[]);
    let after = wait_for("a graph from the restarted daemon", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().filter(|g| g.instance_id() != before_instance).cloned()
    });
    assert!(after.version() > before.version(), "version went from {} to {}", before.version(), after.version());
    // The restored map is published first as the next version; the daemon may already have
    // published another one (its first keyframe) by the time this subscriber polls, so allow one.
    assert!(
        after.version() <= before.version() + 2,
        "the restored map is published as the next version (or one later), found {} after {}",
        after.version(),
        before.version()
    );
    assert_eq!(nodes(&after), nodes(&before), "the first graph after the restart holds the snapshot's nodes");
    assert_eq!(iceoryx2_nodes_of(first_pid), 0, "the killed daemon's iceoryx2 resources were cleaned at restart");
    let mut health = second.health_subscriber("snap-restart-health-2");
    let restored = wait_for("health from the restarted daemon", Duration::from_secs(30), || {
        health.latest().ok().flatten().map(|h| h.snapshot)
    });
    assert_eq!(SNAPSHOT_STATES[restored.state as usize], "restored", "{restored:?}");
    assert_eq!(restored.restored_version, before.version(), "{restored:?}");
}

#[test]
fn sigkill_during_a_snapshot_write_leaves_the_previous_snapshot_intact() {
    let dir = tempfile::tempdir().expect("temp dir");
    let prefix = unique_prefix("snap-torn");
    let args = snapshot_args(dir.path(), &[]);
    // Each write pauses 3 s half-way through the temporary file.
    let delay = [("OP3DSG_TEST_SNAPSHOT_WRITE_DELAY_MS", std::ffi::OsStr::new("3000"))];
    let mut daemon = start(&prefix, &args, &delay);
    let snapshot = dir.path().join("map.snapshot");
    let temp = dir.path().join("map.snapshot.tmp");
    // A first complete snapshot with nodes, then the next write under way.
    let info = wait_for("a first snapshot with nodes", Duration::from_secs(120), || {
        map_info(dir.path()).ok().filter(|i| i["nodes"].as_u64() > Some(0))
    });
    let previous = std::fs::read(&snapshot).expect("read the first snapshot");
    // The pause is a test fault hook: only a daemon built with `--features op3dsgd/fault-hooks`
    // (as scripts/test.sh builds it) has it.
    wait_for(
        "the next snapshot write to be under way (op3dsgd built with --features op3dsgd/fault-hooks?)",
        Duration::from_secs(60),
        || temp.exists().then_some(()),
    );
    daemon.kill_9();

    assert!(temp.exists(), "the interrupted write is the temporary file");
    assert_eq!(std::fs::read(&snapshot).expect("read the snapshot"), previous, "the previous snapshot is untouched");
    let after = map_info(dir.path()).expect("the previous snapshot still reads back");
    assert_eq!(after["graph_version"], info["graph_version"]);

    // The next start removes the torn temporary file and restores the intact snapshot.
    let args = snapshot_args(dir.path(), &["--set", "snapshot.period_s=0"]);
    let second = start(&prefix, &args, &[]);
    let mut graphs = second.graph_subscriber("snap-torn-graphs");
    let graph = wait_for("the restored graph", Duration::from_secs(60), || graphs.latest().ok().flatten().cloned());
    assert!(graph.version() > info["graph_version"].as_u64().unwrap_or(0));
    assert!(!temp.exists(), "the torn temporary file is removed at start");
}

#[test]
fn a_corrupted_snapshot_is_moved_aside_and_reported_and_the_daemon_starts_empty() {
    let dir = tempfile::tempdir().expect("temp dir");
    let prefix = unique_prefix("snap-corrupt");
    // A short finite run writes its final snapshot at exit.
    let args = snapshot_args(dir.path(), &["--max-frames", "90"]);
    let mut daemon = start(&prefix, &args, &[]);
    let status = daemon.wait_exit(Duration::from_secs(120)).expect("the finite run exits");
    assert!(status.success(), "{status}");
    let snapshot = dir.path().join("map.snapshot");
    let mut bytes = std::fs::read(&snapshot).expect("the final snapshot exists");
    assert!(map_info(dir.path()).expect("it reads back")["nodes"].as_u64() > Some(0));

    // One bit flipped in the payload.
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    std::fs::write(&snapshot, &bytes).expect("corrupt the snapshot");
    let err = map_info(dir.path()).expect_err("map info refuses the corrupt snapshot");
    assert!(err.contains("checksum mismatch"), "{err}");

    let out = Command::new(binary("op3dsgd"))
        .args(["--prefix", &prefix, "--max-frames", "1"])
        .args(["--set", &format!("snapshot.dir=\"{}\"", dir.path().display()), "--set", "source.rate_hz=0"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsgd");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("map snapshot unusable: moved aside, starting with an empty map"), "{log}");
    assert!(log.contains("checksum mismatch"), "{log}");
    let aside: Vec<_> = std::fs::read_dir(dir.path())
        .expect("list the snapshot directory")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("map.snapshot.corrupt-")))
        .collect();
    assert_eq!(aside.len(), 1, "one file moved aside: {aside:?}");
    assert_eq!(std::fs::read(&aside[0]).expect("read the moved file"), bytes, "moved aside unchanged, never deleted");
    // It started empty: the one frame it fused made the map its final snapshot holds.
    let info = map_info(dir.path()).expect("the new final snapshot reads back");
    assert!(info["keyframes"].as_u64() <= Some(1), "{info}");
}

#[test]
fn the_conceptgraphs_fusion_maps_the_scene_and_leaves_a_saved_map_as_it_is() {
    let dir = tempfile::tempdir().expect("temp dir");
    // A saved OP3DSG map first.
    let mut daemon = start(&unique_prefix("snap-cg-first"), &snapshot_args(dir.path(), &["--max-frames", "60"]), &[]);
    let status = daemon.wait_exit(Duration::from_secs(120)).expect("the finite run exits");
    assert!(status.success(), "{status}");
    let snapshot = dir.path().join("map.snapshot");
    let saved = std::fs::read(&snapshot).expect("the final snapshot exists");
    let list = || {
        let mut files: Vec<_> = std::fs::read_dir(dir.path()).expect("list").flatten().map(|e| e.file_name()).collect();
        files.sort();
        files
    };
    let before = list();

    // ConceptGraphs' fusion (it has no saved form): it maps the scene, and the snapshot
    // directory is neither restored from (which would move the OP3DSG map aside) nor written.
    let prefix = unique_prefix("snap-cg");
    let args = snapshot_args(
        dir.path(),
        &["--set", "fusion.method=\"conceptgraphs\"", "--set", "run.max_frames=150", "--set", "health.period_ms=100"],
    );
    let daemon = start(&prefix, &args, &[]);
    let mut graphs = daemon.graph_subscriber("snap-cg-graphs");
    let graph = wait_for("a graph with nodes from the conceptgraphs fusion", Duration::from_secs(120), || {
        graphs.latest().ok().flatten().filter(|g| g.node_count() > 0).cloned()
    });
    assert!(graph.nodes().any(|n| !n.label().is_empty()), "labelled nodes");
    let mut health = daemon.health_subscriber("snap-cg-health");
    let state = wait_for("health", Duration::from_secs(30), || health.latest().ok().flatten().map(|h| h.snapshot));
    assert_eq!(SNAPSHOT_STATES[state.state as usize], "off", "{state:?}");
    drop(daemon);
    assert_eq!(list(), before, "nothing moved aside or added");
    assert_eq!(std::fs::read(&snapshot).expect("read the snapshot"), saved, "the saved map is untouched");
}
