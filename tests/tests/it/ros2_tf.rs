//! Poses from a ROS 2 robot's tf tree, through Zenoh, without ROS: `tests/python/ros2_tf_publisher.py`
//! (PyPI `eclipse-zenoh` and `rosbags` only, written from rmw_zenoh's and zenoh-bridge-ros2dds's
//! published formats) sends `/tf_static` and `/tf` for the ICL-NUIM living room's ground-truth
//! trajectory, split into a Stretch-like chain `map → odom → base_link → link_head_tilt →
//! camera_link → camera_color_optical_frame`; a Zenoh router (`tests/python/zenoh_router.py`)
//! stands in for `rmw_zenohd` or the bridge. The daemon on the replay with `pose.source = "ros2"`
//! must build the graph it builds with the recording's own poses (same node ids, boxes within
//! 1 mm) with the static transforms sent before it started; malformed payloads, a missing camera
//! frame, a broken chain and future stamps are refused and counted by reason, and fusion resumes
//! when good transforms do.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_tests::{Daemon, health_where, unique_prefix};
use serde_json::Value;

use crate::zenoh_common;
use zenoh_common::{dump, free_port};

use crate::ros2_common;
use ros2_common::{Killed, publish, router, static_publisher, trajectory};

/// Frames of the replay in each run.
const FRAMES: u64 = 90;

fn icl_dir() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1").map(|dir| dir.canonicalize().expect("canonical path"))
}

/// What both tests stand on: the recording's trajectory file and a router on a free port.
struct RosWorld {
    port: u16,
    trajectory: PathBuf,
    _dir: tempfile::TempDir,
    _router: Killed,
}

impl RosWorld {
    /// `None` without the shared ICL sequence (a test that needs it fails with `CI=true`).
    fn start() -> Option<Self> {
        let icl = icl_dir()?;
        let dir = tempfile::tempdir().expect("tempdir");
        let trajectory = dir.path().join("trajectory.json");
        self::trajectory(&icl, &trajectory);
        let port = free_port();
        Some(Self { port, trajectory, _dir: dir, _router: router(port) })
    }
}

fn daemon(prefix: &str, extra: &[&str]) -> Daemon {
    let profile = Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles/replay-icl.toml");
    let frames = format!("run.max_frames={FRAMES}");
    let mut args = vec![
        "--profile",
        profile.to_str().expect("path"),
        "--set",
        &frames,
        "--set",
        "run.exit_at_end=false",
        "--set",
        "world.frame_id=\"map\"",
    ];
    args.extend_from_slice(extra);
    Daemon::start(prefix, &args)
}

/// [`daemon`] with its log (warnings) written to `log`.
fn daemon_logged(prefix: &str, extra: &[&str], log: &Path) -> Daemon {
    let profile = Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles/replay-icl.toml");
    let child = Command::new(op3dsg_tests::binary("op3dsgd"))
        .args(["--prefix", prefix, "--profile", profile.to_str().expect("path")])
        .args(["--set", &format!("run.max_frames={FRAMES}"), "--set", "run.exit_at_end=false"])
        .args(["--set", "world.frame_id=\"map\""])
        .args(extra)
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .stderr(std::fs::File::create(log).expect("log file"))
        .spawn()
        .expect("spawn op3dsgd");
    Daemon { child, prefix: prefix.to_owned() }
}

/// The tf input's warnings about `reason` in a daemon log: the first (with the error, which
/// holds `error_text`) comes once; the rest only give the count, at powers of two.
fn assert_logged_once(log: &str, reason: &str, error_text: &str, count: u64) {
    let lines: Vec<&str> = log.lines().filter(|l| l.contains("no camera pose from tf")).collect();
    let first = lines.iter().filter(|l| !l.contains("count=") && l.contains(error_text)).count();
    let counted = lines.iter().filter(|l| l.contains("count=") && l.contains(reason)).count() as u64;
    assert_eq!(counted, u64::from(count.ilog2()), "{reason}: the rest at powers of two up to {count}: {lines:#?}");
    assert_eq!(first, 1, "{reason}: the first warning: {lines:#?}");
}

fn ros2_args(port: u16, style: &str) -> Vec<String> {
    [
        "pose.source=\"ros2\"".to_owned(),
        format!("ros2.key_style=\"{style}\""),
        format!("ros2.connect=[\"tcp/127.0.0.1:{port}\"]"),
        // The whole trajectory arrives at once, ahead of the replay: the gate keeps it all.
        "pose.max_wait_ms=5000".to_owned(),
        "pose.future_tolerance_ms=60000".to_owned(),
        "pose.buffer_len=1000".to_owned(),
    ]
    .into_iter()
    .flat_map(|kv| ["--set".to_owned(), kv])
    .collect()
}

/// Node ids equal, boxes within 1 mm.
fn assert_same_nodes(with_tf: &Value, with_frames: &Value) {
    let nodes = |g: &Value| g["nodes"].as_array().cloned().unwrap_or_default();
    let (a, b) = (nodes(with_tf), nodes(with_frames));
    let ids = |n: &[Value]| n.iter().map(|n| n["id"].as_u64()).collect::<Vec<_>>();
    assert_eq!(ids(&a), ids(&b), "node ids with tf poses and with the recording's poses");
    assert!(!a.is_empty(), "the replay mapped something");
    for (x, y) in a.iter().zip(&b) {
        for key in ["box_min_m", "box_max_m", "centre_m"] {
            let (p, q) = (x[key].as_array().expect(key), y[key].as_array().expect(key));
            for (u, v) in p.iter().zip(q) {
                let d = (u.as_f64().unwrap_or(f64::NAN) - v.as_f64().unwrap_or(f64::NAN)).abs();
                assert!(d <= 1e-3, "node {} {key}: {p:?} vs {q:?}", x["id"]);
            }
        }
    }
}

/// The same graph as with the recording's poses, the static links fetched from a publisher that
/// came first, three truncated payloads counted, the chain in health. `rate`: /tf messages per
/// second (0: as fast as the publisher goes).
fn same_graph_as_the_recordings_poses(style: &str, rate: &str) {
    let Some(world) = RosWorld::start() else { return };
    let (port, traj) = (world.port, world.trajectory.as_path());

    // The robot's static transforms were sent before the daemon started.
    let _statics = static_publisher(port, style, traj);
    let prefix = unique_prefix(&format!("ros2-{style}"));
    let args = ros2_args(port, style);
    let with_tf = daemon(&prefix, &args.iter().map(String::as_str).collect::<Vec<_>>());
    let done = publish(port, style, traj, &["--malformed", "3", "--no-static", "--rate", rate]);
    assert_eq!(done["published"].as_u64(), Some(211), "{done}");
    let mut health = with_tf.health_subscriber("ros2-health");
    let h = health_where(&mut health, "every frame", Duration::from_secs(240), |h| h.frames_captured >= FRAMES);
    assert_eq!(h.frames_without_pose, 0, "every frame got its pose from tf: {:?}", h.pose);
    assert!(h.pose.accepted >= FRAMES, "{:?}", h.pose);

    let reference = daemon(&unique_prefix(&format!("ros2-reference-{style}")), &[]);
    let mut ref_health = reference.health_subscriber("ros2-ref-health");
    health_where(&mut ref_health, "every frame", Duration::from_secs(240), |h| h.frames_captured >= FRAMES);
    std::thread::sleep(Duration::from_secs(3));
    assert_same_nodes(&dump(&prefix), &dump(&reference.prefix));

    // The three truncated payloads: errors of the stage ros2_tf, nothing else refused.
    let report = op3dsg_json(&["--prefix", &prefix, "health", "--json"]);
    let stage = report["stages"].as_array().and_then(|s| s.iter().find(|s| s["name"] == "ros2_tf")).cloned();
    assert_eq!(stage.as_ref().map(|s| s["errors"].as_u64()), Some(Some(3)), "{report}");
    for reason in ["no_transform_path", "frame_not_found", "extrapolation", "non_finite"] {
        assert_eq!(report["poses"][reason].as_u64(), Some(0), "{reason}: {report}");
    }
    // The chain of the last lookup, with the static part fetched from the earlier publisher.
    let tf = &report["tf"];
    assert_eq!(
        tf["path"], "map -> odom -> base_link -> link_head_tilt -> camera_link -> camera_color_optical_frame",
        "{report}"
    );
    assert_eq!(tf["static_messages"].as_u64(), Some(1), "{report}");
    let (dynamic, newest) = (tf["dynamic_messages"].as_u64().unwrap_or(0), tf["newest_data_ns"].as_u64());
    if rate == "0" {
        // Everything arrived before the replay ended.
        assert_eq!((dynamic, newest), (211, done["last_stamp_ns"].as_u64()), "{report}");
    } else {
        // The input ends with the replay's last frame (stamped 2.97 s, of the 7 s trajectory).
        assert!((90..=211).contains(&dynamic), "{report}");
        assert!(newest <= done["last_stamp_ns"].as_u64() && newest >= Some(2_966_000_000), "{report}");
    }
    assert!(tf["data_age_s"].as_f64().is_some(), "{report}");
}

#[test]
fn tf_over_the_bridge_gives_the_graph_of_the_recordings_poses_and_bad_payloads_are_counted() {
    same_graph_as_the_recordings_poses("bridge", "0");
}

#[test]
fn tf_over_rmw_zenoh_gives_the_graph_of_the_recordings_poses_and_bad_payloads_are_counted() {
    // At the trajectory's own 30 Hz, as a robot sends it: the replay waits for its poses.
    same_graph_as_the_recordings_poses("rmw_zenoh", "30");
}

#[test]
fn a_missing_camera_frame_is_counted_and_poses_resume() {
    let Some(world) = RosWorld::start() else { return };
    let (port, traj) = (world.port, world.trajectory.as_path());
    let prefix = unique_prefix("ros2-camera");
    let mut args = ros2_args(port, "bridge");
    // Poses up to 10 s ahead of the newest frame are adopted (the good trajectory's tail after
    // the replay's last frame); 600 s ahead is a future stamp.
    args.extend(["--set", "pose.max_wait_ms=500", "--set", "pose.future_tolerance_ms=10000"].map(str::to_owned));
    let d = daemon(&prefix, &args.iter().map(String::as_str).collect::<Vec<_>>());
    // The camera's own link never published: no pose at all, each stamp counted once.
    publish(port, "bridge", traj, &["--omit-frame", "camera_color_optical_frame"]);
    let mut health = d.health_subscriber("ros2-camera-health");
    let h = health_where(&mut health, "missing frames counted", Duration::from_secs(120), |h| {
        h.pose.frame_not_found >= 200
    });
    assert_eq!(h.pose.accepted, 0, "{:?}", h.pose);
    // Then the whole chain: the input resumes with good transforms. The replay's 90 frames are
    // over by now (0 to 3 s), so only the poses after its last frame are still of use: adopted.
    publish(port, "bridge", traj, &[]);
    let h = health_where(&mut health, "poses accepted", Duration::from_secs(120), |h| h.pose.accepted >= 100);
    assert!(h.pose.frame_not_found >= 200, "{:?}", h.pose);
}

#[test]
fn rmw_zenoh_statics_from_before_a_broken_chain_and_future_stamps_then_fusion_resumes() {
    let Some(world) = RosWorld::start() else { return };
    let (port, traj) = (world.port, world.trajectory.as_path());
    // rmw_zenoh keys; the static transforms were sent before the daemon started (transient
    // local): without them every lookup would miss the camera frame (frame_not_found).
    let _statics = static_publisher(port, "rmw_zenoh", traj);
    let prefix = unique_prefix("ros2-chain");
    let mut args = ros2_args(port, "rmw_zenoh");
    // The whole recording: frames keep coming through the three phases (the gate and the tf
    // input live as long as they do).
    args.extend(
        ["--set", "pose.max_wait_ms=500", "--set", "pose.future_tolerance_ms=10000", "--set", "run.max_frames=0"]
            .map(str::to_owned),
    );
    let log_dir = tempfile::tempdir().expect("tempdir");
    let log = log_dir.path().join("op3dsgd.log");
    let d = daemon_logged(&prefix, &args.iter().map(String::as_str).collect::<Vec<_>>(), &log);
    // base_link never hangs under odom: map -> odom and base_link -> ... -> camera are two trees.
    publish(port, "rmw_zenoh", traj, &["--omit-frame", "base_link", "--no-static"]);
    let mut health = d.health_subscriber("ros2-chain-health");
    let h = health_where(&mut health, "broken chain counted", Duration::from_secs(120), |h| {
        h.pose.no_transform_path >= 200
    });
    assert_eq!((h.pose.accepted, h.pose.frame_not_found), (0, 0), "{:?}", h.pose);
    // The whole chain, stamped 600 s ahead of every frame: looked up, then refused by the gate
    // as future poses.
    publish(port, "rmw_zenoh", traj, &["--stamp-offset-ns", "600000000000", "--no-static"]);
    let h = health_where(&mut health, "future stamps counted", Duration::from_secs(120), |h| h.pose.future >= 200);
    assert_eq!(h.pose.accepted, 0, "{:?}", h.pose);
    let (keyframes, fused) = (h.keyframes, h.detections_fused);
    assert!(h.frames_captured < 200, "frames left for the good transforms: {}", h.frames_captured);
    // Good transforms again: the frames still to come get their poses and are fused.
    publish(port, "rmw_zenoh", traj, &["--no-static"]);
    let h = health_where(&mut health, "fusion resumed", Duration::from_secs(120), |h| {
        h.pose.accepted > 0 && h.keyframes > keyframes && h.detections_fused > fused
    });
    assert!(h.graph_version > 0, "{h:?}");
    let text = std::fs::read_to_string(&log).expect("daemon log");
    // The first names the break: base_link's tree and the map's are apart.
    assert_logged_once(&text, "no_transform_path", "no transform path from", h.pose.no_transform_path);
    let first = text.lines().find(|l| l.contains("no transform path from")).unwrap_or_default();
    assert!(first.contains("base_link"), "the log names the missing link: {first}");
}

fn op3dsg_json(args: &[&str]) -> Value {
    let output = Command::new(op3dsg_tests::binary("op3dsg")).args(args).output().expect("run op3dsg");
    assert!(output.status.success(), "op3dsg {args:?}: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("JSON")
}
