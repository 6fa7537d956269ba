//! Real shared-memory tests of the service layer: a [`GraphServer`] in this process, the planner
//! client library (`op3dsg_ipc_types::client`) in this process and in a separately spawned
//! `op3dsg` CLI process.

use std::process::{Command, Output, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use glam::DQuat;
use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_drivers::source::SourceKind;
use op3dsg_ipc_types::client::open_or_create_pose_service;
use op3dsg_ipc_types::services::DEFAULT_POSE_BUFFER;
use op3dsg_ipc_types::{
    EdgeKind, EdgeOrigin, GraphSubscriber, Health, NodeKind, Pose, PoseKind, PosePublisher, PoseStamped, QueueHealth,
    StageHealth, relation_id, write_fixed_str,
};
use op3dsg_runtime::graph::{GraphEdge, GraphNode, SceneGraph};
use op3dsg_runtime::ipc::{GraphOrigin, GraphServer, HealthReport, IpcConfig, graph_to_scene_graph};

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// A prefix no other test (or test run) uses.
fn unique_prefix() -> String {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    format!("op3dsg-test-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::SeqCst))
}

fn server(prefix: &str) -> GraphServer {
    let config = IpcConfig { prefix: prefix.to_owned(), ..IpcConfig::default() };
    GraphServer::open(&config, "op3dsg-test-server").expect("open server")
}

fn cabinet_graph(version: u64) -> SceneGraph {
    let (_, part_of) = relation_id("part of").expect("canonical");
    let (_, pull) = relation_id("pull to open or close").expect("canonical");
    SceneGraph {
        version,
        stamp_ns: 1_000_000_000 + version,
        nodes: vec![
            GraphNode {
                id: 1,
                kind: NodeKind::Object,
                parent_id: None,
                label: "cabinet".into(),
                confidence: 0.9,
                centre_m: [1.0, 0.3, 0.45],
                box_min_m: [0.7, 0.0, 0.0],
                box_max_m: [1.3, 0.6, 0.9],
                obb: Default::default(),
                observation_count: 12,
                affordance_bits: 0,
                last_seen_stamp_ns: 1_000,
                first_seen_stamp_ns: 0,
                missing: false,
                ..Default::default()
            },
            GraphNode {
                id: 2,
                kind: NodeKind::Part,
                parent_id: Some(1),
                label: "cabinet handle".into(),
                confidence: 0.8,
                centre_m: [1.0, 0.61, 0.7],
                box_min_m: [0.95, 0.6, 0.68],
                box_max_m: [1.05, 0.63, 0.72],
                obb: Default::default(),
                observation_count: 5,
                first_seen_stamp_ns: 0,
                missing: false,
                affordance_bits: op3dsg_ipc_types::affordance_bits(["hook_pull"]).expect("canonical"),
                last_seen_stamp_ns: 1_000,
                ..Default::default()
            },
        ],
        edges: vec![
            GraphEdge {
                source_id: 2,
                target_id: 1,
                kind: EdgeKind::Spatial,
                relation_id: part_of,
                confidence: 1.0,
                origin: EdgeOrigin::Geometry,
            },
            GraphEdge {
                source_id: 2,
                target_id: 1,
                kind: EdgeKind::Functional,
                relation_id: pull,
                confidence: 0.95,
                origin: EdgeOrigin::Knowledge,
            },
        ],
    }
}

/// Runs the CLI with `args`, keeping the server's connections updated (so the late subscriber
/// gets the history) until it exits; kills it after 20 s.
fn run_cli(server: &GraphServer, args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_op3dsg"))
        .args(args)
        .env_remove("OP3DSG_PREFIX")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn op3dsg");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        server.update_connections().expect("update connections");
        if child.try_wait().expect("poll child").is_some() {
            break;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let output = child.wait_with_output().expect("collect killed child");
            panic!("op3dsg {args:?} did not finish in 20 s; stderr: {}", String::from_utf8_lossy(&output.stderr));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.wait_with_output().expect("collect child output")
}

#[test]
fn late_cli_process_dumps_the_current_graph_as_json() {
    let prefix = unique_prefix();
    let mut server = server(&prefix);
    let graph = cabinet_graph(7);
    let report = server.publish_graph(&graph).expect("publish");
    assert_eq!((report.nodes_written, report.edges_written, report.truncated), (2, 2, false));

    let started = Instant::now();
    let output = run_cli(&server, &["dump", "--json", "--prefix", &prefix, "--timeout-s", "15"]);
    let elapsed = started.elapsed();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "op3dsg dump failed: {stderr}");
    let json: GraphJson = serde_json::from_slice(&output.stdout).expect("stdout is graph JSON");
    json.check().expect("consistent graph JSON");
    assert_eq!(json.graph_version, 7);
    assert_eq!(json.source, "op3dsgd");
    assert_eq!(json.nodes.len(), 2);
    let handle = json.node(2).expect("handle node");
    assert_eq!((handle.label.as_str(), handle.kind.as_str(), handle.parent), ("cabinet handle", "part", Some(1)));
    assert_eq!(handle.affordances, ["hook_pull"]);
    assert_eq!(handle.box_max_m, [1.05, 0.63, 0.72]);
    let cabinet = json.node(1).expect("cabinet node");
    assert_eq!(cabinet.box_min_m, [0.7, 0.0, 0.0]);
    assert_eq!(json.edges.len(), 2);
    assert_eq!(json.edges[1].relation, "pull to open or close");
    assert_eq!(json.edges[1].origin, "knowledge");
    eprintln!("late-joining `op3dsg dump --json` process round trip: {elapsed:?}");
}

#[test]
fn late_cli_process_reads_health_and_table_dump() {
    let prefix = unique_prefix();
    let mut server = server(&prefix);
    let mut health =
        Health { frames_captured: 300, keyframes: 42, graph_version: 7, source_connected: 1, ..Default::default() };
    // What the daemon's publisher stamps into every health record and graph header.
    let origin = GraphOrigin::new(SourceKind::Replay, "map");
    origin.stamp_health(&mut health);
    server.set_origin(origin);
    health.stage_count = 1;
    health.stages[0] = StageHealth {
        processed: 42,
        rate_hz: 2.5,
        latency_p50_us: 1500.0,
        latency_p99_us: 4000.0,
        ..StageHealth::default()
    };
    write_fixed_str(&mut health.stages[0].name, "fusion");
    health.queue_count = 1;
    health.queues[0] = QueueHealth { depth: 1, capacity: 4, dropped: 3, pushed: 300, ..QueueHealth::default() };
    write_fixed_str(&mut health.queues[0].name, "frames");
    server.publish_health(&health).expect("publish health");
    server.publish_graph(&cabinet_graph(1)).expect("publish graph");

    let output = run_cli(&server, &["health", "--json", "--prefix", &prefix, "--timeout-s", "15"]);
    assert!(output.status.success(), "op3dsg health failed: {}", String::from_utf8_lossy(&output.stderr));
    let report: HealthReport = serde_json::from_slice(&output.stdout).expect("stdout is health JSON");
    assert_eq!((report.frames_captured, report.keyframes, report.graph_version), (300, 42, 7));
    assert!(report.source_connected);
    assert_eq!((report.source_kind.as_str(), report.world_frame.as_str()), ("replay", "map"));
    assert_eq!(report.stages.len(), 1);
    assert_eq!(report.stages[0].name, "fusion");
    assert_eq!(report.stages[0].rate_hz, 2.5);
    assert_eq!(report.queues[0].name, "frames");
    assert_eq!(report.queues[0].dropped, 3);

    let output = run_cli(&server, &["--prefix", &prefix, "dump", "--timeout-s", "15"]);
    let table = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "op3dsg dump failed: {}", String::from_utf8_lossy(&output.stderr));
    assert!(table.contains("cabinet handle") && table.contains("hook_pull") && table.contains("part of"), "{table}");
    assert!(table.lines().next().is_some_and(|l| l.contains("source replay  frame map")), "{table}");

    let output = run_cli(&server, &["--prefix", &prefix, "dump", "--json", "--timeout-s", "15"]);
    assert!(output.status.success(), "op3dsg dump --json failed: {}", String::from_utf8_lossy(&output.stderr));
    let json: GraphJson = serde_json::from_slice(&output.stdout).expect("stdout is graph JSON");
    assert_eq!((json.source_kind.as_deref(), json.world_frame.as_deref()), (Some("replay"), Some("map")));
}

#[test]
fn cli_without_daemon_fails_with_a_clear_message() {
    let prefix = unique_prefix();
    let output = Command::new(env!("CARGO_BIN_EXE_op3dsg"))
        .args(["dump", "--prefix", &prefix, "--timeout-s", "0.3"])
        .output()
        .expect("run op3dsg");
    assert_eq!(output.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains(&format!(
            "no op3dsgd is serving under prefix '{prefix}' in IPC root {} (service {prefix}/graph not found)",
            op3dsg_ipc_types::IpcRoot::resolve().path().display()
        )),
        "{stderr}"
    );
}

#[test]
fn in_process_client_gets_history_updates_and_poses() {
    let prefix = unique_prefix();
    let mut server = server(&prefix);
    let first = server.publish_graph(&cabinet_graph(1)).expect("publish");
    assert_eq!(first.version, 1);

    // A client that joins late gets version 1 from the history once the server updates its
    // connections.
    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-client").expect("open client");
    server.update_connections().expect("update connections");
    let graph = graphs.latest_if_newer(0).expect("read").map(graph_to_scene_graph).expect("history sample");
    assert_eq!(graph, cabinet_graph(1));
    assert!(!graphs.poll().expect("read"), "nothing new");
    assert!(graphs.latest_if_newer(1).expect("read").is_none(), "nothing newer than version 1");
    assert!(server.subscriber_count() >= 1);

    // Newer versions: the event fires and the newest sample wins.
    let mut publish_ns = Vec::new();
    for version in 2..=4 {
        let t = Instant::now();
        server.publish_graph(&cabinet_graph(version)).expect("publish");
        publish_ns.push(t.elapsed());
    }
    assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
    let received_at = op3dsg_runtime::world::clock::wall_clock_ns();
    let graph = graphs.latest_if_newer(1).expect("read").expect("new sample");
    assert_eq!(graph.version(), 4);
    assert!(!graph.capacity_exceeded());
    assert_eq!(graph.instance_id(), server.instance_id());
    assert_ne!(graph.instance_id(), 0);
    eprintln!(
        "publish_graph (encode + loan + copy + send + notify) took {publish_ns:?}; \
         publish-to-read latency {} us",
        received_at.saturating_sub(graph.publish_time_ns()) / 1000
    );
    assert!(!graphs.wait_for_update(Duration::from_millis(20)).expect("wait"), "no event pending");

    // Poses: valid ones arrive; the client refuses a bad quaternion, and one sent past it on a
    // raw iceoryx2 publisher is dropped and counted by the daemon.
    let poses = PosePublisher::open(&prefix, "op3dsg-test-nav").expect("open pose publisher");
    let q = DQuat::from_rotation_z(0.5);
    let pose = Pose::new([1.0, 2.0, 0.3], [q.x, q.y, q.z, q.w]);
    poses.publish(10, PoseKind::WorldFromCamera, &pose, "camera_color_optical_frame").expect("send pose");
    poses.publish(20, PoseKind::WorldFromBase, &pose, "base_link").expect("send pose");
    let bad = Pose::new([0.0; 3], [0.0, 0.0, 0.0, 2.0]);
    assert!(poses.publish(30, PoseKind::WorldFromCamera, &bad, "base_link").is_err(), "client refuses norm 2");
    assert!(poses.publish(40, PoseKind::WorldFromCamera, &pose, &"x".repeat(40)).is_err(), "frame id too long");
    let raw_node =
        op3dsg_runtime::ipc::create_node(&op3dsg_ipc_types::IpcRoot::resolve(), "op3dsg-test-raw-nav").expect("node");
    let raw_poses = open_or_create_pose_service(&raw_node, &prefix, DEFAULT_POSE_BUFFER)
        .expect("open pose service")
        .factory
        .publisher_builder()
        .create()
        .expect("raw pose publisher");
    let bad = PoseStamped { stamp_ns: 30, rotation_xyzw: [0.0, 0.0, 0.0, 2.0], ..PoseStamped::default() };
    raw_poses.send_copy(bad).expect("send raw pose");
    let mut out: Vec<PoseStamped> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    while (out.len() < 2 || server.invalid_pose_count() < 1) && Instant::now() < deadline {
        server.poll_poses(&mut out).expect("poll poses");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(out.iter().map(|p| p.stamp_ns).collect::<Vec<_>>(), [10, 20]);
    assert_eq!(out[1].kind, PoseKind::WorldFromBase as u8);
    assert!((out[0].translation_m[1] - 2.0).abs() < 1e-12);
    assert_eq!(op3dsg_ipc_types::fixed_str(&out[0].frame_id), "camera_color_optical_frame");
    assert_eq!(server.invalid_pose_count(), 1);
}

#[test]
fn client_started_before_the_daemon_waits_for_it() {
    let prefix = unique_prefix();
    let waiting_prefix = prefix.clone();
    let waiter = std::thread::Builder::new()
        .name("early-client".into())
        .spawn(move || {
            GraphSubscriber::open_wait(&waiting_prefix, "op3dsg-test-early", Duration::from_secs(10)).map(|_| ())
        })
        .expect("spawn");
    std::thread::sleep(Duration::from_millis(300));
    let _server = server(&prefix);
    waiter.join().expect("join").expect("client connected once the daemon came up");
}

#[test]
fn watch_prints_updates_and_exits_cleanly_on_ctrl_c() {
    use std::io::{BufRead, BufReader};
    let prefix = unique_prefix();
    let mut child = Command::new(env!("CARGO_BIN_EXE_op3dsg"))
        .args(["--prefix", &prefix, "watch", "--interval-ms", "50"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn op3dsg watch");
    // The daemon starts after the client: watch must wait for it.
    std::thread::sleep(Duration::from_millis(300));
    let mut server = server(&prefix);
    let stdout = child.stdout.take().expect("piped stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::Builder::new()
        .name("watch-reader".into())
        .spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        })
        .expect("spawn reader");
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut seen = None;
    let mut version = 0;
    while seen.is_none() && Instant::now() < deadline {
        version += 1;
        server.publish_graph(&cabinet_graph(version)).expect("publish");
        server.update_connections().expect("update connections");
        while let Ok(line) = rx.recv_timeout(Duration::from_millis(50)) {
            if line.contains("objects 1 parts 1 edges 2") {
                seen = Some(line);
                break;
            }
        }
    }
    let status = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("run kill");
    assert!(status.success());
    let deadline = Instant::now() + Duration::from_secs(10);
    let exit = loop {
        if let Some(exit) = child.try_wait().expect("poll child") {
            break exit;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("op3dsg watch ignored Ctrl-C");
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let _ = reader.join();
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
    }
    assert!(seen.is_some(), "watch never printed the graph; stderr: {stderr}");
    assert!(stderr.contains(&format!("waiting for op3dsgd under prefix {prefix}")), "{stderr}");
    assert!(exit.success(), "watch exit {exit:?}; stderr: {stderr}");
}
