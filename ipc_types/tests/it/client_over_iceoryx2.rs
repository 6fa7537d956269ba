//! The client against a stand-in daemon over real iceoryx2 shared memory: graph history and
//! updates, views of the received graph, contract checks, health without a graph slot, poses
//! both ways, a client started before the daemon, and a subscriber in another process.

use crate::common;

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{FakeDaemon, unique_prefix, write_kitchen};
use iceoryx2::port::subscriber::SubscriberCreateError;
use op3dsg_ipc_types::client::open_or_create_pose_service;
use op3dsg_ipc_types::services::{DEFAULT_POSE_BUFFER, DEFAULT_PREFIX};
use op3dsg_ipc_types::{
    EdgeKind, EdgeOrigin, ErrorCause, GraphSubscriber, GraphView, Health, HealthSubscriber, NAME_CAPACITY_BYTES,
    NodeKind, Operation, Pose, PoseError, PoseKind, PosePublisher, SCHEMA_VERSION, ServiceKind, SnapshotError,
    StageHealth, write_fixed_str,
};

/// Polls `latest_if_newer` (updating the stand-in's connections) until a graph newer than
/// `last_seen` arrives or 5 s pass; returns its version.
fn wait_for_version(daemon: &FakeDaemon, graphs: &mut GraphSubscriber, last_seen: u64) -> Option<u64> {
    let deadline = Instant::now() + Duration::from_secs(5);
    while Instant::now() < deadline {
        daemon.update_connections();
        if let Some(graph) = graphs.latest_if_newer(last_seen).expect("read graph") {
            return Some(graph.version());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

#[test]
fn late_subscriber_gets_the_current_graph_then_only_the_newest_update() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 2);
    daemon.publish_graph(|s| write_kitchen(s, 1));

    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect("open graph");
    assert_eq!(graphs.prefix(), prefix);
    assert!(graphs.graph().is_none(), "nothing copied before the first read");
    assert_eq!(wait_for_version(&daemon, &mut graphs, 0), Some(1), "history sample");

    let graph = graphs.latest().expect("read").expect("graph held");
    assert_eq!(graph.version(), 1, "the same graph again when nothing is new");
    assert_eq!((graph.objects().count(), graph.parts().count(), graph.edge_count()), (4, 3, 6));
    assert_eq!(graph.stamp_ns(), 1_000_000_001);
    let parts: Vec<u32> = graph.parts_of(1).map(|n| n.id()).collect();
    assert_eq!(parts, [2, 3]);
    let knob = graph.find_by_label("knob").next().expect("knob");
    assert_eq!((knob.kind(), knob.parent().map(|p| p.label())), (NodeKind::Part, Some("stove")));
    assert_eq!(knob.centre_m(), [5.5, 0.25, 0.75]);
    let from_handle: Vec<_> = graph.edges_from(2).map(|e| (e.phrase(), e.kind(), e.origin(), e.target_id())).collect();
    assert_eq!(
        from_handle,
        [
            ("part of", EdgeKind::Spatial, EdgeOrigin::Geometry, 1),
            ("pull to open or close", EdgeKind::Functional, EdgeOrigin::Knowledge, 1),
        ]
    );
    let to_tv: Vec<_> = graph.edges_to(20).map(|e| (e.source().map(|n| n.label()), e.phrase())).collect();
    assert_eq!(to_tv, [(Some("remote"), "remote to control")]);
    let pullable: Vec<u32> = graph.find_by_affordance("pinch_pull").expect("canonical").map(|n| n.id()).collect();
    assert_eq!(pullable, [3]);
    let handles: Vec<u32> = graph.find_by_label_containing("Handle").map(|n| n.id()).collect();
    assert_eq!(handles, [2, 3]);
    assert!(graphs.latest_if_newer(1).expect("read").is_none(), "version 1 already seen");

    // Three versions while the planner is busy: it wakes once and reads the newest.
    for version in 2..=4 {
        daemon.publish_graph(|s| write_kitchen(s, version));
    }
    assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
    assert_eq!(graphs.latest_if_newer(1).expect("read").map(|g| g.version()), Some(4));
    assert!(graphs.latest_if_newer(4).expect("read").is_none());
    assert!(!graphs.wait_for_update(Duration::from_millis(20)).expect("wait"), "nothing pending");
    // A zero timeout only looks (iceoryx2's own timed wait would take it as "no limit").
    assert!(!graphs.wait_for_update(Duration::ZERO).expect("wait"), "nothing pending, at once");

    // A queued sample counts as an update even when its event was already consumed.
    daemon.publish_graph(|s| write_kitchen(s, 5));
    assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
    assert!(graphs.wait_for_update(Duration::ZERO).expect("wait"), "sample still queued");
    assert_eq!(graphs.latest().expect("read").map(|g| g.version()), Some(5));

    // A version going back within one instance is new too.
    daemon.publish_graph(|s| write_kitchen(s, 1));
    assert_eq!(wait_for_version(&daemon, &mut graphs, 5), Some(1));
    assert!(!graphs.restarted());

    // A restarted daemon (another instance id) whose count has reached the version already seen:
    // still new, and flagged as a restart.
    daemon.publish_graph(|s| {
        write_kitchen(s, 1);
        s.header.instance_id = common::INSTANCE_ID + 1;
    });
    assert_eq!(wait_for_version(&daemon, &mut graphs, 1), Some(1), "same version, new instance");
    assert!(graphs.restarted());
    assert_eq!(graphs.graph().map(|g| (g.instance_id(), g.restarted())), Some((common::INSTANCE_ID + 1, true)));
    daemon.publish_graph(|s| {
        write_kitchen(s, 2);
        s.header.instance_id = common::INSTANCE_ID + 1;
    });
    assert_eq!(wait_for_version(&daemon, &mut graphs, 1), Some(2));
    assert!(!graphs.restarted(), "the same new instance again");
}

#[test]
fn a_sample_of_another_schema_is_an_error_naming_both_versions() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 2);
    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect("open graph");
    daemon.publish_graph(|s| write_kitchen(s, 3));
    assert_eq!(wait_for_version(&daemon, &mut graphs, 0), Some(3));

    daemon.publish_graph(|s| {
        write_kitchen(s, 4);
        s.header.schema_version = SCHEMA_VERSION + 1;
    });
    assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
    let err = graphs.latest().expect_err("schema mismatch");
    let found = SCHEMA_VERSION + 1;
    assert_eq!(err.cause(), ErrorCause::InvalidGraph(SnapshotError::SchemaVersion { found, expected: SCHEMA_VERSION }));
    assert_eq!((err.service(), err.operation()), (ServiceKind::Graph, Operation::Receive));
    assert_eq!(
        err.to_string(),
        format!(
            "{prefix}/graph: receive: invalid sample: header.schema_version: found {found}, this build reads {SCHEMA_VERSION}"
        )
    );
    // The bad sample is gone and the last good graph is still there.
    assert_eq!(graphs.latest().expect("read").map(|g| g.version()), Some(3));
}

/// Polls `with_latest` (updating the stand-in's connections) until it lends a sample or 5 s
/// pass; returns what `read` made of it.
fn wait_for_view<R>(daemon: &FakeDaemon, graphs: &mut GraphSubscriber, read: impl Fn(GraphView<'_>) -> R) -> Option<R> {
    let deadline = Instant::now() + Duration::from_secs(5);
    while Instant::now() < deadline {
        daemon.update_connections();
        if let Some(result) = graphs.with_latest(&read).expect("read through the view") {
            return Some(result);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    None
}

#[test]
fn the_view_reads_the_sample_in_shared_memory_and_refuses_a_bad_one() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 2);
    let mut graphs = GraphSubscriber::open(&prefix, "op3dsg-test-view").expect("open graph");
    assert!(graphs.with_latest(|_| ()).expect("nothing yet").is_none(), "nothing published: closure not called");
    daemon.publish_graph(|s| write_kitchen(s, 1));
    let read = |view: GraphView<'_>| {
        let knob = view.find_by_label("knob").next().map(|n| (n.id(), n.parent().map(|p| p.label().to_owned())));
        let parts: Vec<u32> = view.parts_of(1).map(|n| n.id()).collect();
        let from_handle: Vec<_> = view.edges_from(2).map(|e| (e.phrase().to_owned(), e.origin())).collect();
        let remote = view.edges_to(20).next().and_then(|e| e.source()).map(|n| n.label().to_owned());
        let pullable: Vec<u32> = view.find_by_affordance("pinch_pull").expect("canonical").map(|n| n.id()).collect();
        (view.version(), view.restarted(), knob, parts, from_handle, remote, pullable, view.to_graph().expect("valid"))
    };
    let (version, restarted, knob, parts, from_handle, remote, pullable, copy) =
        wait_for_view(&daemon, &mut graphs, read).expect("the history sample through the view");
    assert_eq!((version, restarted), (1, false));
    assert_eq!(knob, Some((11, Some("stove".to_owned()))));
    assert_eq!(parts, [2, 3]);
    assert_eq!(
        from_handle,
        [("part of".to_owned(), EdgeOrigin::Geometry), ("pull to open or close".to_owned(), EdgeOrigin::Knowledge)]
    );
    assert_eq!((remote.as_deref(), pullable), (Some("remote"), vec![3]));
    assert_eq!((copy.version(), copy.node_count(), copy.edge_count()), (1, 7, 6));
    assert_eq!(copy.node(11).and_then(|n| n.parent()).map(|p| p.label()), Some("stove"), "the copy is a whole graph");
    assert!(graphs.with_latest(|_| ()).expect("read").is_none(), "taken: nothing new until the next sample");
    assert!(graphs.graph().is_none(), "the view copies nothing into the owned graph");

    // A sample of another schema is refused before the closure runs; the next good one is read.
    daemon.publish_graph(|s| {
        write_kitchen(s, 2);
        s.header.schema_version = SCHEMA_VERSION + 1;
    });
    assert!(graphs.wait_for_update(Duration::from_secs(5)).expect("wait"));
    let err = graphs.with_latest(|_| unreachable!("a refused sample is never lent")).expect_err("schema mismatch");
    let found = SCHEMA_VERSION + 1;
    assert_eq!(err.cause(), ErrorCause::InvalidGraph(SnapshotError::SchemaVersion { found, expected: SCHEMA_VERSION }));
    assert!(err.to_string().starts_with(&format!("{prefix}/graph: receive: invalid sample: header.schema_version")));

    // A restarted daemon's graph is flagged on the view as on the owned graph.
    daemon.publish_graph(|s| {
        write_kitchen(s, 1);
        s.header.instance_id = common::INSTANCE_ID + 1;
    });
    let seen = wait_for_view(&daemon, &mut graphs, |v| (v.version(), v.instance_id(), v.restarted()));
    assert_eq!(seen, Some((1, common::INSTANCE_ID + 1, true)));
}

#[test]
fn without_a_daemon_open_fails_clearly_and_open_wait_waits_for_it() {
    let prefix = unique_prefix();
    let err = GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect_err("no daemon");
    assert!(err.is_not_serving());
    let expected = format!(
        "{prefix}/graph: open: no op3dsgd is serving under prefix '{prefix}' in IPC root {} (service {prefix}/graph not found)",
        op3dsg_ipc_types::IpcRoot::resolve().path().display()
    );
    assert!(err.to_string().starts_with(&expected), "{err}");
    let err = HealthSubscriber::open(&prefix, "op3dsg-test-monitor").expect_err("no daemon");
    assert!(err.is_not_serving() && err.service() == ServiceKind::Health);
    let started = Instant::now();
    let err = GraphSubscriber::open_wait(&prefix, "op3dsg-test-planner", Duration::from_millis(250)).expect_err("none");
    assert!(err.is_not_serving() && started.elapsed() >= Duration::from_millis(250));

    let err = GraphSubscriber::open("bad prefix", "op3dsg-test-planner").expect_err("invalid prefix");
    assert!(matches!(err.cause(), ErrorCause::InvalidPrefix(_)), "{err}");
    assert!(err.to_string().contains("invalid character ' '"), "{err}");

    let waiting_prefix = prefix.clone();
    let waiter = std::thread::Builder::new()
        .name("early-planner".into())
        .spawn(move || GraphSubscriber::open_wait(&waiting_prefix, "op3dsg-test-early", Duration::from_secs(20)))
        .expect("spawn early planner");
    std::thread::sleep(Duration::from_millis(300));
    let daemon = FakeDaemon::start(&prefix, 2);
    let mut graphs = waiter.join().expect("join early planner").expect("opened once the daemon came up");
    daemon.publish_graph(|s| write_kitchen(s, 9));
    assert_eq!(wait_for_version(&daemon, &mut graphs, 0), Some(9));
}

#[test]
fn health_is_read_without_a_graph_subscriber_slot() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start(&prefix, 1);
    let _planner = GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect("the one graph slot");
    let err = GraphSubscriber::open(&prefix, "op3dsg-test-second").expect_err("slots full");
    assert_eq!(err.cause(), ErrorCause::CreateSubscriber(SubscriberCreateError::ExceedsMaxSupportedSubscribers));
    assert!(err.to_string().contains("every subscriber slot of the service is taken"), "{err}");

    let mut health = Health { frames_captured: 300, keyframes: 42, graph_version: 7, ..Health::default() };
    health.stage_count = 1;
    health.stages[0] = StageHealth { processed: 42, rate_hz: 2.5, ..StageHealth::default() };
    write_fixed_str(&mut health.stages[0].name, "fusion");
    daemon.publish_health(&health);

    let mut monitor = HealthSubscriber::open(&prefix, "op3dsg-test-monitor").expect("open health");
    let deadline = Instant::now() + Duration::from_secs(5);
    let received = loop {
        daemon.update_connections();
        if let Some(h) = monitor.latest().expect("read health") {
            break h;
        }
        assert!(Instant::now() < deadline, "no health record within 5 s");
        std::thread::sleep(Duration::from_millis(5));
    };
    assert_eq!((received.frames_captured, received.keyframes, received.graph_version), (300, 42, 7));
    assert_eq!(op3dsg_ipc_types::fixed_str(&received.valid_stages()[0].name), "fusion");
    assert_eq!(monitor.latest().expect("read").map(|h| h.keyframes), Some(42), "kept when nothing is new");

    let other = Health { schema_version: SCHEMA_VERSION + 1, ..Health::default() };
    daemon.publish_health(&other);
    let err = monitor.latest().expect_err("other schema");
    assert_eq!(err.cause(), ErrorCause::HealthSchemaVersion { found: SCHEMA_VERSION + 1, expected: SCHEMA_VERSION });
    assert_eq!(monitor.latest().expect("read").map(|h| h.keyframes), Some(42), "bad record not kept");
}

#[test]
fn health_is_read_when_only_the_health_service_exists() {
    let prefix = unique_prefix();
    let daemon = FakeDaemon::start_health_only(&prefix);
    let mut monitor =
        HealthSubscriber::open_wait(&prefix, "op3dsg-test-monitor", Duration::from_secs(5)).expect("open");
    assert!(monitor.latest().expect("read").is_none(), "nothing published yet");
    daemon.publish_health(&Health { uptime_ns: 5_000_000_000, source_connected: 1, ..Health::default() });
    let deadline = Instant::now() + Duration::from_secs(5);
    while monitor.latest().expect("read").is_none() {
        assert!(Instant::now() < deadline, "no health record within 5 s");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(monitor.latest().expect("read").map(|h| (h.uptime_ns, h.source_connected)), Some((5_000_000_000, 1)));
    assert!(GraphSubscriber::open(&prefix, "op3dsg-test-planner").expect_err("no graph").is_not_serving());
}

#[test]
fn poses_reach_the_daemon_side_and_bad_ones_are_refused_before_sending() {
    let prefix = unique_prefix();
    // The navigation stack starts first and creates `pose`; the daemon then opens it asking for
    // a larger buffer than the client created, and gets the existing one.
    let poses = PosePublisher::open(&prefix, "op3dsg-test-nav").expect("open pose publisher");
    let daemon_node = common::node("op3dsg-test-daemon");
    let service = open_or_create_pose_service(&daemon_node, &prefix, DEFAULT_POSE_BUFFER * 2).expect("daemon side");
    assert!(service.smaller_buffer);
    let again = open_or_create_pose_service(&daemon_node, &prefix, DEFAULT_POSE_BUFFER).expect("same buffer");
    assert!(!again.smaller_buffer);
    let subscriber = service.factory.subscriber_builder().create().expect("daemon pose subscriber");

    let world_from_base = Pose::from_translation_yaw([1.0, 2.0, 0.0], 0.5);
    let reached = poses.publish(10, PoseKind::WorldFromBase, &world_from_base, "base_link").expect("send");
    assert_eq!(reached, 1);
    let world_from_camera = Pose::new([0.5, 0.0, 1.2], [0.5, -0.5, 0.5, -0.5]);
    poses.publish(20, PoseKind::WorldFromCamera, &world_from_camera, "camera_color_optical_frame").expect("send");

    let refuse = |stamp_ns, pose: Pose, frame_id: &str| {
        let err = poses.publish(stamp_ns, PoseKind::WorldFromCamera, &pose, frame_id).expect_err("refused");
        assert_eq!((err.service(), err.operation()), (ServiceKind::Pose, Operation::Publish));
        match err.cause() {
            ErrorCause::InvalidPose(e) => (e, err.to_string()),
            other => panic!("unexpected cause {other:?}"),
        }
    };
    let (e, message) = refuse(30, Pose::new([0.0; 3], [f64::NAN, 0.0, 0.0, 1.0]), "base_link");
    assert!(matches!(e, PoseError::NonFiniteRotation { .. }), "{message}");
    assert!(message.starts_with(&format!("{prefix}/pose: publish: invalid pose: non-finite quaternion")), "{message}");
    let (e, message) = refuse(40, Pose::new([0.0; 3], [0.0, 0.0, 0.0, 2.0]), "base_link");
    assert_eq!(e, PoseError::NonUnitQuaternion { norm: 2.0 });
    assert!(message.ends_with("quaternion norm 2 is not 1 (tolerance 0.001)"), "{message}");
    let (e, _) = refuse(50, Pose::new([f64::INFINITY, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]), "base_link");
    assert!(matches!(e, PoseError::NonFiniteTranslation { .. }));
    let (e, _) = refuse(60, Pose::IDENTITY, &"x".repeat(NAME_CAPACITY_BYTES + 1));
    assert_eq!(e, PoseError::FrameIdTooLong { len: NAME_CAPACITY_BYTES + 1 });
    let mut raw = op3dsg_ipc_types::PoseStamped { kind: 7, rotation_xyzw: [0.0, 0.0, 0.0, 1.0], ..Default::default() };
    let err = poses.publish_stamped(&raw).expect_err("unknown kind");
    assert_eq!(err.cause(), ErrorCause::InvalidPose(PoseError::UnknownKind { value: 7 }));
    raw.kind = PoseKind::WorldFromCamera as u8;
    raw.stamp_ns = 70;
    poses.publish_stamped(&raw).expect("valid raw pose");

    let mut received = Vec::new();
    while let Some(sample) = subscriber.receive().expect("receive pose") {
        received.push(*sample.payload());
    }
    assert_eq!(received.iter().map(|p| p.stamp_ns).collect::<Vec<_>>(), [10, 20, 70], "refused poses never sent");
    let base = &received[0];
    assert_eq!((base.pose_kind(), base.frame_id_str()), (Some(PoseKind::WorldFromBase), "base_link"));
    assert_eq!(
        (base.translation_m, base.rotation_xyzw),
        (world_from_base.translation_m, world_from_base.rotation_xyzw)
    );
    assert_eq!(received[1].frame_id_str(), "camera_color_optical_frame");
    assert_eq!(received[1].rotation_xyzw, [0.5, -0.5, 0.5, -0.5]);
}

const CHILD_PREFIX_ENV: &str = "OP3DSG_IPC_TEST_CHILD_PREFIX";
const CHILD_VERSIONS: u64 = 3;

/// The reader half of [`graph_reaches_a_subscriber_in_another_process`], run in a child process.
#[test]
#[ignore = "run by graph_reaches_a_subscriber_in_another_process in a child process"]
fn child_process_reader() {
    let prefix = std::env::var(CHILD_PREFIX_ENV).expect("started by the parent test with a prefix");
    let mut graphs = GraphSubscriber::open_wait(&prefix, "op3dsg-test-child", Duration::from_secs(20)).expect("open");
    let mut last_seen = 0;
    let mut versions_seen = 0;
    while versions_seen < CHILD_VERSIONS {
        graphs.wait_for_update(Duration::from_millis(100)).expect("wait");
        if let Some(graph) = graphs.latest_if_newer(last_seen).expect("read") {
            last_seen = graph.version();
            versions_seen += 1;
            let handle = graph.node(2).expect("cabinet handle");
            println!(
                "child: version {} objects {} parts {} edges {} handle parent {}",
                graph.version(),
                graph.objects().count(),
                graph.parts().count(),
                graph.edge_count(),
                handle.parent().map(|p| p.label()).unwrap_or("none"),
            );
        }
    }
}

#[test]
fn graph_reaches_a_subscriber_in_another_process() {
    let prefix = unique_prefix();
    assert_ne!(prefix, DEFAULT_PREFIX);
    let mut child = Command::new(std::env::current_exe().expect("test binary path"))
        .args(["--ignored", "--exact", "client_over_iceoryx2::child_process_reader", "--nocapture", "--test-threads=1"])
        .env(CHILD_PREFIX_ENV, &prefix)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn child test process");
    // The child starts before the daemon and waits for it.
    std::thread::sleep(Duration::from_millis(200));
    let daemon = FakeDaemon::start(&prefix, 2);
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut version = 0;
    let status = loop {
        if let Some(status) = child.try_wait().expect("poll child") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let output = child.wait_with_output().expect("collect killed child");
            panic!("child reader did not finish in 30 s; stderr: {}", String::from_utf8_lossy(&output.stderr));
        }
        version += 1;
        daemon.publish_graph(|s| write_kitchen(s, version));
        daemon.update_connections();
        std::thread::sleep(Duration::from_millis(50));
    };
    let output = child.wait_with_output().expect("collect child output");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(status.success(), "child failed: {stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    let lines: Vec<&str> = stdout.lines().filter(|l| l.contains("child: version")).collect();
    assert_eq!(lines.len(), CHILD_VERSIONS as usize, "{stdout}");
    assert!(lines.iter().all(|l| l.ends_with("objects 4 parts 3 edges 6 handle parent cabinet")), "{stdout}");
}
