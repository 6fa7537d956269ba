//! The pose input and the health record across processes: a pose service created first by
//! someone else with iceoryx2's defaults, a second daemon on a taken prefix, `op3dsg health`
//! with every graph subscriber slot taken, and every pose rejection reason counted in health.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::{NodeBuilder, ServiceName};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use op3dsg_ipc_types::services::IpcService;
use op3dsg_ipc_types::{Health, PoseHealth, PoseKind, PoseStamped, ServiceKind};
use op3dsg_tests::{Daemon, binary, unique_prefix, wait_for};

/// Poses from the pose service, a synthetic room at 10 frames per second (its frames are stamped
/// 33.3 ms apart on scene time, so stamps advance a third as fast as the wall clock) and short
/// health periods.
const IPC_POSES: &[&str] =
    &["--set", "pose.source=\"ipc\"", "--set", "source.rate_hz=10", "--set", "health.period_ms=100"];
/// Frame `k` of the synthetic source is stamped `k * FRAME_PERIOD_NS`.
const FRAME_PERIOD_NS: u64 = 33_333_333;

/// A raw iceoryx2 pose publisher, as a navigation stack without the op3dsg client would write it.
struct RawPosePublisher {
    publisher: Publisher<IpcService, PoseStamped, ()>,
    _service: PortFactory<IpcService, PoseStamped, ()>,
    _node: iceoryx2::node::Node<IpcService>,
}

impl RawPosePublisher {
    /// Creates `<prefix>/pose` with iceoryx2's default QoS (nothing set), or opens it with no
    /// requirement when `create` is false.
    fn new(prefix: &str, create: bool) -> Self {
        let node = NodeBuilder::new()
            .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
            .create::<IpcService>()
            .expect("raw node");
        let name = ServiceName::new(&ServiceKind::Pose.name(prefix)).expect("service name");
        let builder = node.service_builder(&name).publish_subscribe::<PoseStamped>();
        let service = if create {
            builder.create().expect("create pose with defaults")
        } else {
            builder.open().expect("open pose")
        };
        let publisher = service.publisher_builder().create().expect("raw pose publisher");
        Self { publisher, _service: service, _node: node }
    }

    fn send(&self, pose: PoseStamped) -> usize {
        self.publisher.send_copy(pose).expect("send pose")
    }
}

fn camera_pose(stamp_ns: u64, x_m: f64) -> PoseStamped {
    PoseStamped {
        stamp_ns,
        kind: PoseKind::WorldFromCamera as u8,
        translation_m: [x_m, 0.0, 1.2],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
        ..PoseStamped::default()
    }
}

/// The stamp of the newest frame the daemon reported capturing.
fn newest_frame_ns(health: &Health) -> u64 {
    health.frames_captured.saturating_sub(1) * FRAME_PERIOD_NS
}

#[test]
fn daemon_starts_on_a_pose_service_created_first_with_iceoryx2_defaults_and_receives_its_poses() {
    let prefix = unique_prefix("pose-first");
    // The navigation stack comes first and creates the service with iceoryx2's defaults
    // (2 publishers, 8 subscribers, buffer 2).
    let navigation = RawPosePublisher::new(&prefix, true);
    let daemon = Daemon::start(&prefix, IPC_POSES);
    let mut health = daemon.health_subscriber("pose-first-health");
    let started = wait_for("a health record with frames", Duration::from_secs(60), || {
        health.latest().ok().flatten().filter(|h| h.frames_captured > 3)
    });
    assert_eq!(started.keyframes, 0, "no pose has been sent yet");
    // Stream poses a little ahead of the frames, every 10 ms of scene time, until frames get theirs.
    let mut next_stamp_ns = newest_frame_ns(&started);
    let last = wait_for("keyframes posed from the raw publisher's poses", Duration::from_secs(60), || {
        let h = health.latest().ok().flatten()?;
        let ahead_ns = newest_frame_ns(&h) + 300_000_000;
        while next_stamp_ns < ahead_ns {
            navigation.send(camera_pose(next_stamp_ns, next_stamp_ns as f64 * 1e-9));
            next_stamp_ns += 10_000_000;
        }
        (h.keyframes > 0 && h.pose.accepted > 0).then_some(h)
    });
    assert_eq!(last.pose.out_of_order + last.pose.future + last.pose.non_finite, 0, "{:?}", last.pose);
}

#[test]
fn second_daemon_on_a_taken_prefix_names_it_and_the_first_daemons_pid() {
    let prefix = unique_prefix("two-daemons");
    let first = Daemon::start(&prefix, &["--set", "source.rate_hz=10", "--set", "health.period_ms=100"]);
    let mut health = first.health_subscriber("two-daemons-health");
    wait_for("the first daemon's health", Duration::from_secs(60), || health.latest().ok().flatten());
    let mut second = Command::new(binary("op3dsgd"))
        .args(["--prefix", &prefix, "--set", "source.rate_hz=10"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the second op3dsgd");
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        if let Some(status) = second.try_wait().expect("poll the second daemon") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = second.kill();
            panic!("the second daemon kept running on a taken prefix");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let output = second.wait_with_output().expect("second daemon's output");
    let log = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert_eq!(status.code(), Some(1), "exit code 1 (runtime failure), log:\n{log}");
    let expected = format!("another op3dsgd already serves prefix '{prefix}' (pid {})", first.child.id());
    assert!(log.contains(&expected), "expected {expected:?} in:\n{log}");
    // The first daemon is unaffected.
    let before = health.latest().ok().flatten().map_or(0, |h| h.frames_captured);
    wait_for("the first daemon to keep running", Duration::from_secs(30), || {
        health.latest().ok().flatten().filter(|h| h.frames_captured > before)
    });
}

#[test]
fn op3dsg_health_works_with_every_graph_subscriber_slot_taken() {
    let prefix = unique_prefix("slots-full");
    let daemon = Daemon::start(
        &prefix,
        &["--set", "ipc.max_subscribers=2", "--set", "source.rate_hz=10", "--set", "health.period_ms=100"],
    );
    let _planner_a = daemon.graph_subscriber("slots-a");
    let _planner_b = daemon.graph_subscriber("slots-b");
    let third = op3dsg_ipc_types::GraphSubscriber::open(&prefix, "slots-c");
    assert!(third.is_err(), "both graph subscriber slots should be taken");
    let output = Command::new(binary("op3dsg"))
        .args(["--prefix", &prefix, "health", "--json", "--timeout-s", "30"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsg health");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "op3dsg health failed: {}\n{stdout}", String::from_utf8_lossy(&output.stderr));
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("health JSON");
    assert_eq!(report["schema_version"], op3dsg_ipc_types::SCHEMA_VERSION);
    assert!(report["stages"].as_array().is_some_and(|s| !s.is_empty()), "{report}");
    assert!(report["poses"]["accepted"].is_u64(), "{report}");
}

#[test]
fn every_pose_rejection_reason_is_counted_in_health() {
    let prefix = unique_prefix("pose-reasons");
    let daemon = Daemon::start(&prefix, IPC_POSES);
    let mut health = daemon.health_subscriber("pose-reasons-health");
    // Past the first second of scene time, so a pose stamped 0 is stale.
    let h = wait_for("frames past one second of scene time", Duration::from_secs(120), || {
        health.latest().ok().flatten().filter(|h| h.frames_captured > 40)
    });
    assert_eq!(h.pose, PoseHealth::default(), "no pose sent yet");
    // The client library refuses to send the bad ones, so write them raw.
    let raw = RawPosePublisher::new(&prefix, false);
    let good_ns = newest_frame_ns(&h) + 500_000_000;
    let bad_kind = PoseStamped { kind: 9, ..camera_pose(good_ns, 0.0) };
    let mut non_finite = camera_pose(good_ns, 0.0);
    non_finite.translation_m[1] = f64::NAN;
    let non_unit = PoseStamped { rotation_xyzw: [0.0, 0.0, 0.0, 2.0], ..camera_pose(good_ns, 0.0) };
    let base_pose = PoseStamped { kind: PoseKind::WorldFromBase as u8, ..camera_pose(good_ns + 1, 0.0) };
    let poses = [
        camera_pose(good_ns, 0.0),                   // accepted
        camera_pose(good_ns - 10_000_000, 0.0),      // out of order: before the adopted one
        camera_pose(0, 0.0),                         // stale: long before the newest frame
        camera_pose(good_ns + 100_000_000_000, 0.0), // future: 100 s ahead
        bad_kind,
        non_finite,
        non_unit,
        base_pose, // world_from_base, but the profile has no base_from_camera
    ];
    for pose in poses {
        assert_eq!(raw.send(pose), 1, "the daemon's subscriber is connected");
    }
    let expected = PoseHealth {
        accepted: 1,
        unknown_kind: 1,
        non_finite: 1,
        non_unit_quaternion: 1,
        no_base_from_camera: 1,
        out_of_order: 1,
        stale: 1,
        future: 1,
        queue_full: 0,
        no_transform_path: 0,
        frame_not_found: 0,
        extrapolation: 0,
    };
    let counted = wait_for("every reason counted once", Duration::from_secs(30), || {
        health.latest().ok().flatten().map(|h| h.pose).filter(|pose| *pose == expected)
    });
    assert_eq!(counted, expected);
    // And `op3dsg health --json` names them.
    let output = Command::new(binary("op3dsg"))
        .args(["--prefix", &prefix, "health", "--json"])
        .env("OP3DSG_LOG", "warn")
        .output()
        .expect("run op3dsg health");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).expect("health JSON");
    for reason in ["accepted", "unknown_kind", "non_finite", "non_unit_quaternion", "out_of_order", "stale", "future"] {
        assert_eq!(report["poses"][reason], 1, "{reason}: {report}");
    }
    assert!(report["frames_without_pose"].as_u64().is_some_and(|n| n > 0), "{report}");
}

#[test]
fn health_names_the_execution_provider_each_model_runs_on() {
    let prefix = unique_prefix("providers");
    // The text encoder is an ONNX model (files from ./scripts/setup-models.sh, as for
    // text_encoder_startup.rs); the PyPI ONNX Runtime offers the CPU provider only.
    let daemon = Daemon::start(
        &prefix,
        &["--set", "text_encoder.enabled=true", "--set", "source.rate_hz=10", "--set", "health.period_ms=100"],
    );
    let mut health = daemon.health_subscriber("providers-health");
    let h = wait_for("a model entry in health", Duration::from_secs(120), || {
        health.latest().ok().flatten().filter(|h| h.model_count > 0)
    });
    let model = h
        .valid_models()
        .iter()
        .find(|m| op3dsg_ipc_types::fixed_str(&m.name) == "text encoder")
        .unwrap_or_else(|| panic!("no text encoder entry in {:?}", h.valid_models()));
    assert_eq!(op3dsg_ipc_types::EXECUTION_PROVIDERS[model.provider as usize], "cpu");
    assert_eq!(op3dsg_ipc_types::EXECUTION_PROVIDERS[model.requested_provider as usize], "cpu");
    assert!(model.sessions >= 1);
}
