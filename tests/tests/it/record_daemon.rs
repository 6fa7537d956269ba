//! The MCAP recorder in the real daemon, read back by an independent reader (PyPI `mcap` in the
//! project venv, `tests/python/mcap_check.py`): channels, schemas, counts, order, SceneUpdates
//! equal to their graph versions; record-then-replay through `source.kind = "mcap"` gives the
//! identical final graph; kill -9 leaves a readable file; a failing disk stops the recording,
//! not the daemon.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, mcap_files, unique_prefix, wait_for};
use serde_json::Value;

fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(path.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", path.display());
    path
}

/// The independent reader's summary of `file`.
fn check(file: &Path) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/mcap_check.py");
    let output = Command::new(python()).arg(script).arg(file).output().expect("run mcap_check.py");
    assert!(output.status.success(), "mcap_check.py failed: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("mcap_check.py prints JSON")
}

/// Settings both runs of the replay test share: one worker and blocking queues, so no frame is
/// dropped for lack of time and the published versions do not depend on scheduling.
const DETERMINISTIC: &[&str] = &[
    "--set",
    "source.rate_hz=0",
    "--set",
    "detector.workers=1",
    "--set",
    "queues.frames.policy=block",
    "--set",
    "queues.keyframes.policy=block",
    "--set",
    "queues.graph.policy=block",
];

/// Fusion slowed by 100 ms a keyframe (the `fault-hooks` build's `OP3DSG_TEST_FUSION_DELAY_MS`).
const SLOW_FUSION: &[(&str, &str)] = &[("OP3DSG_TEST_FUSION_DELAY_MS", "100")];

/// Slower still for the replays (300 ms): reading a file is far faster than fusing it, however
/// loaded the machine, so the replay that keeps the profile's policies surely drops.
const SLOWER_FUSION: &[(&str, &str)] = &[("OP3DSG_TEST_FUSION_DELAY_MS", "300")];

/// The recording run's and the replay's final graph JSON (from `mcap_check.py`) are the same
/// bytes, and the graph is not trivially empty.
fn assert_same_final_graph(recorded: &Value, replayed: &Value) {
    let last = |run: &Value| run["last_graph"].as_str().map(str::to_owned).expect("mcap_check.py names the last graph");
    let (a, b) = (last(recorded), last(replayed));
    let graph: Value = serde_json::from_str(&a).expect("the last graph is JSON");
    let nodes = graph["nodes"].as_array().map_or(0, Vec::len);
    assert!(nodes >= 3, "the final graph has {nodes} nodes");
    assert_eq!(a, b, "final graph JSON of the replay differs from the recording run's");
}

/// The arguments of a replay of the recording `replay_path` names (a `source.mcap.path=...`
/// setting) through `source.kind = "mcap"`, recording again into `out_dir`: the recording run's
/// settings, then `extra`, then [`DETERMINISTIC`].
fn replay_args<'a>(replay_path: &'a str, out_dir: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "--set",
        "source.kind=mcap",
        "--set",
        replay_path,
        "--set",
        "source.mcap.mode=fast",
        "--set",
        "source.synthetic.frame_count=45",
        "--record",
        out_dir,
    ];
    args.extend_from_slice(extra);
    args.extend_from_slice(DETERMINISTIC);
    args
}

fn run_to_end(prefix: &str, args: &[&str]) {
    run_to_end_with(prefix, args, &[]);
}

/// `file` is a recording whose pipeline dropped keyframes after the gate: `record info` says it
/// will not replay bit for bit and why, and its replay warns, naming the queue and the count.
fn assert_the_pipelines_drops_are_named(file: &Path) {
    let info = record_info(file);
    assert!(info.contains("  pipeline  dropped "), "{info}");
    assert!(info.contains("  replay    NOT bit for bit: "), "{info}");
    assert!(info.contains("after the gate while recording (keyframes "), "{info}");
    let replay_path = format!("source.mcap.path=\"{}\"", file.display());
    let args = ["--set", "source.kind=mcap", "--set", "source.rate_hz=0", "--set", &replay_path];
    let stderr = run_to_end_with(&unique_prefix("rec-drop"), &args, &[]);
    assert!(
        stderr.contains("the pipeline dropped keyframes or results after the keyframe gate while this was recorded"),
        "{stderr}"
    );
    assert!(stderr.contains("queues=keyframes "), "{stderr}");
}

/// A recording whose recorder fell behind (the fixture copied by PyPI `mcap` with the drop
/// counts of `op3dsg.recorder` set, `tests/python/mcap_set_drops.py`): `record info` says it
/// will not replay bit for bit, naming the channel and count, and its replay warns with both.
#[test]
fn a_recording_with_recorder_drops_says_so_and_its_replay_warns() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/recording-json-ee322aa.mcap");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("dropped.mcap");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/mcap_set_drops.py");
    let output = Command::new(python())
        .arg(script)
        .arg(&fixture)
        .arg(&file)
        .args(["/camera/colour.dropped=3", "dropped_total=3"])
        .output()
        .expect("run mcap_set_drops.py");
    assert!(output.status.success(), "mcap_set_drops.py: {}", String::from_utf8_lossy(&output.stderr));
    let info = record_info(&file);
    assert!(info.contains("  recorder  finished; dropped 3 messages while recording"), "{info}");
    assert!(info.contains("NOT bit for bit: 3 messages dropped while recording: /camera/colour 3"), "{info}");
    let replay_path = format!("source.mcap.path=\"{}\"", file.display());
    let args = ["--set", "source.kind=mcap", "--set", "source.rate_hz=0", "--set", &replay_path];
    let stderr = run_to_end_with(&unique_prefix("rec-recorder-drop"), &args, &[]);
    assert!(stderr.contains("this recording dropped messages while recording"), "{stderr}");
    assert!(stderr.contains("channels=/camera/colour 3"), "{stderr}");
}

/// [`run_to_end`] with environment variables (the test fault hooks).
fn run_to_end_with(prefix: &str, args: &[&str], env: &[(&str, &str)]) -> String {
    let output = Command::new(binary("op3dsgd"))
        .arg("--prefix")
        .arg(prefix)
        .args(args)
        .arg("--exit-at-end")
        .env("OP3DSG_LOG", "warn")
        .envs(env.iter().copied())
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsgd");
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert!(output.status.success(), "op3dsgd {args:?} failed: {stderr}");
    stderr
}

#[test]
fn synthetic_kitchen_recorded_then_replayed_gives_the_identical_graph_five_times() {
    let dir = tempfile::tempdir().unwrap();
    let first_dir = dir.path().join("first");
    let first = first_dir.to_str().unwrap();
    // The default profile's queues (keyframes and graph latest_wins) and two workers. Paced below
    // what the recorder of a debug build keeps up with, and a deep frame queue: the recording
    // must hold every frame the pipeline used (checked below: no drops); every frame reaches the
    // gate (`queues.frames` blocks) so that all 45 are counted. The world frame is named as a
    // robot's navigation stack names it; the replays below keep the default.
    // Fusion is slowed to 100 ms a keyframe (the fault hook, as on a slower computer), the
    // detections queue holds one result and the frame pool has room to spare (so the capture
    // thread is not held back by it): at 8 Hz the robot keeps up, a replay as fast as it reads
    // overruns what the latest_wins queues hold.
    let mut args = vec!["--set", "source.synthetic.frame_count=45", "--record", first];
    args.extend_from_slice(&["--set", "source.rate_hz=8", "--set", "record.frame_queue=32"]);
    args.extend_from_slice(&["--set", "queues.frames.policy=block", "--set", "detector.workers=2"]);
    args.extend_from_slice(&["--set", "queues.detections.capacity=1", "--set", "world.frame_id=\"map\""]);
    args.extend_from_slice(&["--set", "source.pool_headroom=32"]);
    run_to_end_with(&unique_prefix("rec-a"), &args, SLOW_FUSION);
    let files = mcap_files(&first_dir);
    assert_eq!(files.len(), 1, "one file: {files:?}");
    let recorded = check(&files[0]);
    assert_eq!(recorded["error"], Value::Null, "{recorded}");

    // Channels, schemas and encodings.
    let channels = &recorded["channels"];
    for (topic, schema) in [
        ("/op3dsg/graph", "op3dsg.Graph"),
        ("/op3dsg/scene", "foxglove.SceneUpdate"),
        ("/tf", "foxglove.FrameTransform"),
        ("/camera/calibration", "foxglove.CameraCalibration"),
        ("/camera/colour", "foxglove.RawImage"),
        ("/camera/depth", "foxglove.RawImage"),
        ("/op3dsg/frame", "op3dsg.Frame"),
        ("/sim/instance_ids", "foxglove.RawImage"),
        ("/op3dsg/detections", "foxglove.ImageAnnotations"),
        ("/op3dsg/node_points", "foxglove.PointCloud"),
    ] {
        let channel = &channels[topic];
        assert_eq!(channel["schema"], schema, "{topic}: {channel}");
        // Foxglove's types as protobuf (the foxglove crate's), our own as JSON.
        let encoding = if schema.starts_with("foxglove.") { ["protobuf", "protobuf"] } else { ["jsonschema", "json"] };
        assert_eq!([&channel["schema_encoding"], &channel["message_encoding"]], encoding, "{topic}");
    }
    // Every frame the gate received, with colour, depth and instance ids; one calibration.
    for topic in ["/camera/colour", "/camera/depth", "/op3dsg/frame", "/sim/instance_ids"] {
        assert_eq!(channels[topic]["count"], 45, "{topic}: {channels}");
    }
    assert_eq!(channels["/camera/calibration"]["count"], 1);
    let keyframes = channels["/tf"]["count"].as_u64().unwrap();
    assert!(keyframes >= 3, "keyframes: {keyframes}");
    assert_eq!(channels["/op3dsg/graph"]["count"], channels["/op3dsg/scene"]["count"]);
    assert_eq!(recorded["log_time_ordered"], true);
    for (topic, ordered) in recorded["stamps_ordered"].as_object().unwrap() {
        assert_eq!(ordered, true, "{topic} stamps go backwards");
    }
    assert!(recorded["scene_versions_checked"].as_u64().unwrap() >= 1, "{recorded}");
    assert_eq!(recorded["scene_mismatches"], Value::Array(vec![]), "SceneUpdate boxes = graph oriented boxes");
    // Every foxglove.* message, decoded with the file's descriptors, against Foxglove's published
    // JSON schemas (npm @foxglove/schemas, applied strictly: no field they do not define); every
    // op3dsg.* message against the file's own JSON schema.
    assert_eq!(recorded["foxglove_errors"], Value::Array(vec![]), "Foxglove schema violations");
    for schema in [
        "foxglove.SceneUpdate",
        "foxglove.FrameTransform",
        "foxglove.CameraCalibration",
        "foxglove.RawImage",
        "foxglove.ImageAnnotations",
        "foxglove.PointCloud",
    ] {
        let n = recorded["foxglove_validated"][schema].as_u64().unwrap_or(0);
        assert!(n >= 1, "{schema}: {n} messages validated ({})", recorded["foxglove_validated"]);
    }
    assert_eq!(recorded["embedded_errors"], Value::Array(vec![]), "violations of the file's own schemas");
    let own = ["/op3dsg/frame", "/op3dsg/graph", "/op3dsg/health"].map(|t| channels[t]["count"].as_u64().unwrap());
    assert_eq!(recorded["embedded_validated"].as_u64().unwrap(), own.iter().sum::<u64>(), "{own:?}");
    // Detections per keyframe, stamped as the keyframes; node points matching their graph.
    assert_eq!(channels["/op3dsg/detections"]["count"], channels["/tf"]["count"], "one per keyframe");
    assert!(recorded["detections"].as_u64().unwrap() >= 3, "{}", recorded["detections"]);
    assert_eq!(recorded["detections_off_keyframes"], Value::Array(vec![]));
    assert!(recorded["point_clouds_checked"].as_u64().unwrap() >= 1, "{recorded}");
    assert_eq!(recorded["point_cloud_mismatches"], Value::Array(vec![]));
    // Per-channel drop counts of the finished file.
    let meta = &recorded["metadata"]["op3dsg.recorder"];
    for topic in ["/camera/colour", "/camera/depth", "/op3dsg/frame", "/op3dsg/scene", "/op3dsg/detections"] {
        assert_eq!(meta[format!("{topic}.dropped")], "0", "{topic}: {meta}");
    }
    assert_eq!(recorded["metadata"]["op3dsg.recorder"]["dropped_total"], "0");
    assert!(recorded["metadata"]["op3dsg.profile"].is_object());
    // The recording names the world frame as the profile does, as the graph header does.
    assert_world_frames(&recorded, "map");

    // record info's verdict: nothing lost by the recorder or by the pipeline after the gate.
    let info = record_info(&files[0]);
    assert!(info.contains("  pipeline  dropped nothing after the keyframe gate while recording"), "{info}");
    assert!(info.contains("  replay    bit for bit: "), "{info}");

    // The documented replay command (docs/recording.md), five runs at once so that they load the
    // machine (three at the recorded pace, two in the fast mode), with the recording's profile
    // (queues, detections capacity 1, two workers) and a slower fusion still: the profile's
    // latest_wins queues would drop; the replay blocks instead (source.mcap.lossless, the
    // default). Each records again, for its graph. A sixth, fast, with `source.mcap.lossless =
    // false` shows that the profile's policies do drop here.
    let outs = replays_at_once(&files[0], dir.path());
    // The control: the gate took the same keyframes, the pipeline dropped some after it; its own
    // recording says so, and a replay of that warns.
    let control_file = mcap_files(&outs[5]).remove(0);
    assert_the_pipelines_drops_are_named(&control_file);
    let control = check(&control_file);
    let version = |run: &Value| {
        let graph: Value = serde_json::from_str(run["last_graph"].as_str().expect("a last graph")).expect("JSON");
        graph["graph_version"].as_u64().expect("graph_version")
    };
    assert!(
        version(&control) < version(&recorded),
        "with the profile's latest_wins queues the fast replay drops keyframes (its last version {}, the \
         recording's {}): else this test shows nothing",
        version(&control),
        version(&recorded)
    );
    for out in &outs[..5] {
        let files = mcap_files(out);
        assert_eq!(files.len(), 1, "{files:?}");
        let replayed = check(&files[0]);
        assert_eq!(replayed["error"], Value::Null, "{replayed}");
        assert_eq!(replayed["channels"]["/op3dsg/frame"]["count"], 45, "every recorded frame replayed");
        assert_eq!(replayed["channels"]["/tf"]["count"], keyframes, "the recorded keyframes, no more, no fewer");
        assert_same_final_graph(&recorded, &replayed);
        // The world frame's name is the replaying profile's (here the default): it changes no graph.
        assert_world_frames(&replayed, "world");
    }
}

/// Replays of `file`, each recording into a folder under `dir` (returned): five at once, three
/// with the documented command as written (at the recorded pace) and two in the fast mode, then
/// alone a sixth, fast, with `source.mcap.lossless = false` (alone, so that nothing slows its
/// reading down to the pipeline's pace).
fn replays_at_once(file: &Path, dir: &Path) -> Vec<PathBuf> {
    let replay_path = format!("source.mcap.path=\"{}\"", file.display());
    let outs: Vec<PathBuf> = (0..6).map(|i| dir.join(format!("replay-{i}"))).collect();
    let replay = |i: usize, out: &Path| {
        let out = out.to_str().expect("utf-8 temp path");
        let mut args = vec!["--set", "source.kind=mcap", "--set", "source.rate_hz=0", "--set", &replay_path];
        // 0..=2 as the docs write the command (the default mode: at the recorded pace), the rest
        // as fast as the file reads.
        if i >= 3 {
            args.extend_from_slice(&["--set", "source.mcap.mode=\"fast\""]);
        }
        args.extend_from_slice(&["--set", "detector.workers=2", "--set", "queues.detections.capacity=1"]);
        args.extend_from_slice(&["--set", "source.pool_headroom=32"]);
        args.extend_from_slice(&["--record", out, "--set", "record.frame_queue=48"]);
        if i == 5 {
            args.extend_from_slice(&["--set", "source.mcap.lossless=false"]);
        }
        run_to_end_with(&unique_prefix(&format!("rec-b{i}")), &args, SLOWER_FUSION);
    };
    std::thread::scope(|scope| {
        for (i, out) in outs[..5].iter().enumerate() {
            scope.spawn(move || replay(i, out));
        }
    });
    replay(5, &outs[5]);
    outs
}

/// Every world frame name the recording uses (`/tf` parents, scene entities, node point clouds,
/// health records) is `expected`, and each of those channels has one.
fn assert_world_frames(summary: &Value, expected: &str) {
    let frames = summary["world_frames"].as_object().expect("mcap_check.py lists the world frames");
    for topic in ["/tf", "/op3dsg/scene", "/op3dsg/node_points", "/op3dsg/health"] {
        assert_eq!(frames.get(topic), Some(&serde_json::json!([expected])), "{topic}: {frames:?}");
    }
}

#[test]
fn kill_9_while_recording_leaves_a_file_readable_to_its_last_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = unique_prefix("rec-kill");
    let mut daemon = Daemon::start(
        &prefix,
        &[
            "--record",
            dir.path().to_str().unwrap(),
            "--set",
            "record.flush_interval_ms=100",
            "--set",
            "record.chunk_size_kib=256",
        ],
    );
    let mut health = daemon.health_subscriber("rec-kill-health");
    wait_for("the recorder to write 200 messages", Duration::from_secs(60), || {
        health.latest().ok().flatten().filter(|h| h.recorder.messages_written >= 200 && h.recorder.bytes_written > 0)
    });
    daemon.kill_9();
    let files = mcap_files(dir.path());
    assert_eq!(files.len(), 1, "{files:?}");
    let summary = check(&files[0]);
    // No summary or footer: the reader stops where the file ends, after whole chunks.
    assert!(summary["error"].is_string(), "a killed recording has no footer: {summary}");
    let frames = summary["channels"]["/op3dsg/frame"]["count"].as_u64().unwrap_or(0);
    let colour = summary["channels"]["/camera/colour"]["count"].as_u64().unwrap_or(0);
    assert!(frames >= 10, "frames read back: {frames} ({summary})");
    assert!(colour >= frames, "each frame's colour comes before its meta");
    assert!(summary["metadata"]["op3dsg.recorder"].is_null(), "not finished");
}

#[test]
fn a_failing_disk_stops_the_recording_not_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let prefix = unique_prefix("rec-full");
    let log = dir.path().join("daemon.log");
    // Files larger than 24 MiB cannot be written (RLIMIT_FSIZE; SIGXFSZ ignored, so the write
    // fails with EFBIG as a full disk fails with ENOSPC). Small graph samples keep the daemon's
    // own shared-memory files well under the limit.
    let script = format!(
        "trap '' XFSZ; ulimit -f {}; exec \"$0\" \"$@\"",
        24 * 1024 * 1024 / 512 // blocks of 512 bytes
    );
    let record_dir = dir.path().join("rec");
    let child = Command::new("sh")
        .arg("-c")
        .arg(script)
        .arg(binary("op3dsgd"))
        .args(["--prefix", &prefix, "--record", record_dir.to_str().unwrap()])
        .args(["--set", "ipc.max_nodes=1024", "--set", "ipc.max_edges=2048", "--set", "record.compression=none"])
        .args(["--set", "record.flush_interval_ms=100", "--set", "health.period_ms=100"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .expect("spawn op3dsgd under ulimit -f");
    let mut daemon = Daemon { child, prefix: prefix.clone() };
    let mut health = daemon.health_subscriber("rec-full-health");
    let failed = wait_for("the recorder to fail", Duration::from_secs(90), || {
        health.latest().ok().flatten().filter(|h| h.recorder.state == 2)
    });
    // The pipeline goes on: new graph versions and frames after the failure.
    let later =
        wait_for("graph versions after the failure", Duration::from_secs(60), || {
            health.latest().ok().flatten().filter(|h| {
                h.graph_version > failed.graph_version + 2 && h.frames_captured > failed.frames_captured + 30
            })
        });
    assert_eq!(later.recorder.state, 2, "stays failed");
    assert!(daemon.child.try_wait().unwrap().is_none(), "the daemon still runs");
    daemon.kill_9();
    let text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(text.matches("recording stopped").count(), 1, "one warning:\n{text}");
    // What was flushed before the failure reads back.
    let files = mcap_files(&record_dir);
    assert!(!files.is_empty());
    let summary = check(&files[0]);
    assert!(summary["channels"]["/op3dsg/frame"]["count"].as_u64().unwrap_or(0) >= 1, "{summary}");
}

/// The stand-in navigation stack (`op3dsg-test-nav`: the synthetic robot's true path at 10 Hz
/// through the client library's `PosePublisher`), killed on drop.
struct Navigation(std::process::Child);

impl Navigation {
    fn start(prefix: &str) -> Self {
        let child = Command::new(binary("op3dsg-test-nav"))
            .args(["--prefix", prefix, "--frame-rate-hz", "30", "--pose-rate-hz", "10"])
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .expect("spawn op3dsg-test-nav");
        Self(child)
    }
}

impl Drop for Navigation {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn a_recording_with_poses_from_the_pose_input_replays_with_them() {
    let dir = tempfile::tempdir().unwrap();
    let profile = format!("{}/../profiles/sim-clean.toml", env!("CARGO_MANIFEST_DIR"));
    // 46 frames at 30 Hz scene time: the last one is stamped at a 10 Hz pose, so every frame has
    // a pose after it; frames wait up to 3 s for it (the navigation stack follows the frames).
    let mut common = vec![
        "--profile",
        &profile,
        "--set",
        "source.synthetic.frame_count=46",
        "--set",
        "source.synthetic.intrinsics={ width = 320, height = 240, fx = 307.5, fy = 307.5, cx = 160.0, cy = 120.0 }",
        "--set",
        "pose.source=\"ipc\"",
        "--set",
        "pose.max_wait_ms=3000",
        "--set",
        "health.period_ms=100",
    ];
    common.extend_from_slice(DETERMINISTIC);
    let first_dir = dir.path().join("first");
    let mut args = common.clone();
    args.extend_from_slice(&["--set", "source.rate_hz=15", "--set", "record.frame_queue=32"]);
    args.extend_from_slice(&["--record", first_dir.to_str().unwrap(), "--exit-at-end"]);
    let prefix = unique_prefix("rec-pose-a");
    let mut daemon = Daemon::start(&prefix, &args);
    let _navigation = Navigation::start(&prefix);
    let status = daemon.wait_exit(Duration::from_secs(180)).expect("the recording run ends with its source");
    assert!(status.success(), "{status}");
    let files = mcap_files(&first_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let recorded = check(&files[0]);
    assert_eq!(recorded["error"], Value::Null, "{recorded}");
    let channels = &recorded["channels"];
    assert_eq!(channels["/op3dsg/input_pose"]["schema"], "op3dsg.InputPose", "{channels}");
    let poses = channels["/op3dsg/input_pose"]["count"].as_u64().unwrap_or(0);
    assert!(poses >= 16, "16 poses of 10 Hz over 1.5 s at least: {poses}");
    assert_eq!(channels["/op3dsg/frame"]["count"], 46);
    assert_eq!(recorded["embedded_errors"], Value::Array(vec![]));
    assert_eq!(recorded["metadata"]["op3dsg.recorder"]["dropped_total"], "0");
    assert_eq!(recorded["metadata"]["op3dsg.recorder"]["/op3dsg/input_pose.dropped"], "0");
    let keyframes = channels["/tf"]["count"].as_u64().unwrap();
    assert!(keyframes >= 3, "keyframes: {keyframes}");

    // The replay, with no navigation stack: the recorded poses reach the keyframe gate.
    let second_dir = dir.path().join("second");
    let replay_path = format!("source.mcap.path=\"{}\"", files[0].display());
    let mut args = common.clone();
    args.extend_from_slice(&["--set", "source.kind=mcap", "--set", &replay_path, "--set", "source.mcap.mode=fast"]);
    args.extend_from_slice(&["--record", second_dir.to_str().unwrap()]);
    run_to_end(&unique_prefix("rec-pose-b"), &args);
    let files = mcap_files(&second_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let replayed = check(&files[0]);
    assert_eq!(replayed["channels"]["/op3dsg/input_pose"]["count"], poses, "the gate got every recorded pose");
    assert_eq!(replayed["channels"]["/tf"]["count"], keyframes, "the same keyframes");
    assert_same_final_graph(&recorded, &replayed);
}

/// The schema check itself can fail: a file written with PyPI `mcap`'s writer, holding a
/// FrameTransform with an extra field and a missing one, and a `foxglove.*` name Foxglove does
/// not publish.
#[test]
fn the_foxglove_schema_check_finds_violations() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.mcap");
    let script = r#"
import json, sys
from mcap.writer import Writer
with open(sys.argv[1], "wb") as f:
    w = Writer(f)
    w.start(profile="op3dsg", library="test")
    sid = w.register_schema(name="foxglove.FrameTransform", encoding="jsonschema", data=b'{"type":"object"}')
    cid = w.register_channel(topic="/tf", message_encoding="json", schema_id=sid)
    good = {"timestamp": {"sec": 1, "nsec": 0}, "parent_frame_id": "world", "child_frame_id": "camera",
            "translation": {"x": 0, "y": 0, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0, "w": 1}}
    bad = dict(good, rotation={"x": 0, "y": 0, "z": 0, "w": 1, "colour": 2}, translation={"x": 0, "y": 0})
    for i, m in enumerate([good, bad]):
        w.add_message(channel_id=cid, log_time=i, publish_time=i, data=json.dumps(m).encode())
    sid2 = w.register_schema(name="foxglove.Scene", encoding="jsonschema", data=b'{"type":"object"}')
    cid2 = w.register_channel(topic="/scene", message_encoding="json", schema_id=sid2)
    w.add_message(channel_id=cid2, log_time=3, publish_time=3, data=b'{}')
    w.finish()
"#;
    let status = Command::new(python()).arg("-c").arg(script).arg(&file).status().expect("run the mcap writer");
    assert!(status.success());
    let summary = check(&file);
    assert_eq!(summary["foxglove_validated"]["foxglove.FrameTransform"], 2);
    assert_eq!(
        summary["foxglove_errors"],
        serde_json::json!([
            "/tf[1]: rotation: Additional properties are not allowed ('colour' was unexpected)",
            "/tf[1]: translation: 'z' is a required property",
            "/scene[0]: schema foxglove.Scene is not one Foxglove publishes"
        ])
    );

    // The same in protobuf: a FrameTransform whose descriptor (in the file) lacks the
    // translation and rotation and has a field Foxglove does not define.
    let file = dir.path().join("bad-protobuf.mcap");
    let script = r#"
import sys
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.writer import Writer
F = descriptor_pb2.FieldDescriptorProto
fd = descriptor_pb2.FileDescriptorProto(name="bad.proto", package="foxglove", syntax="proto3")
m = fd.message_type.add(name="FrameTransform")
for number, name, kind in [(2, "parent_frame_id", F.TYPE_STRING), (3, "child_frame_id", F.TYPE_STRING), (9, "colour", F.TYPE_INT32)]:
    m.field.add(name=name, number=number, type=kind, label=F.LABEL_OPTIONAL)
pool = descriptor_pool.DescriptorPool()
pool.Add(fd)
cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.FrameTransform"))
with open(sys.argv[1], "wb") as f:
    w = Writer(f)
    w.start(profile="op3dsg", library="test")
    data = descriptor_pb2.FileDescriptorSet(file=[fd]).SerializeToString()
    sid = w.register_schema(name="foxglove.FrameTransform", encoding="protobuf", data=data)
    cid = w.register_channel(topic="/tf", message_encoding="protobuf", schema_id=sid)
    msg = cls(parent_frame_id="world", child_frame_id="camera", colour=2)
    w.add_message(channel_id=cid, log_time=0, publish_time=0, data=msg.SerializeToString())
    w.finish()
"#;
    let status = Command::new(python()).arg("-c").arg(script).arg(&file).status().expect("run the mcap writer");
    assert!(status.success());
    let summary = check(&file);
    assert_eq!(summary["foxglove_validated"]["foxglove.FrameTransform"], 1);
    let errors: Vec<&str> =
        summary["foxglove_errors"].as_array().unwrap().iter().map(|e| e.as_str().unwrap()).collect();
    for expected in [
        "/tf[0]: (root): Additional properties are not allowed ('colour' was unexpected)",
        "/tf[0]: (root): 'rotation' is a required property",
    ] {
        assert!(errors.contains(&expected), "{expected} not in {errors:?}");
    }
}

/// Records the 45-frame kitchen with `record.colour = colour`, then replays it (fast, same
/// profile, recording the replay raw); returns both files' `mcap_check.py` summaries and the
/// first file.
fn record_and_replay(dir: &Path, colour: &str) -> (Value, Value, PathBuf) {
    let first_dir = dir.join(format!("{colour}-first"));
    let colour_set = format!("record.colour=\"{colour}\"");
    let mut args =
        vec!["--set", "source.synthetic.frame_count=45", "--record", first_dir.to_str().expect("utf-8 temp path")];
    args.extend_from_slice(DETERMINISTIC);
    // A frame queue deeper than the run: however slow png/jpeg encoding is in a debug build,
    // the recording must hold every frame (no drops, checked).
    args.extend_from_slice(&["--set", "source.rate_hz=8", "--set", "record.frame_queue=48", "--set", &colour_set]);
    run_to_end(&unique_prefix(&format!("rec-{colour}-a")), &args);
    let files = mcap_files(&first_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let recorded = check(&files[0]);
    let second_dir = dir.join(format!("{colour}-second"));
    let replay_path = format!("source.mcap.path=\"{}\"", files[0].display());
    let args =
        replay_args(&replay_path, second_dir.to_str().expect("utf-8 temp path"), &["--set", "record.frame_queue=48"]);
    run_to_end(&unique_prefix(&format!("rec-{colour}-b")), &args);
    let replays = mcap_files(&second_dir);
    assert_eq!(replays.len(), 1, "{replays:?}");
    (recorded, check(&replays[0]), files[0].clone())
}

fn record_info(file: &Path) -> String {
    let output =
        Command::new(binary("op3dsg")).args(["record", "info"]).arg(file).output().expect("op3dsg record info");
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8_lossy(&output.stdout).into_owned()
}

#[test]
fn compressed_colour_png_replays_bit_for_bit_and_jpeg_replays_lossy() {
    let dir = tempfile::tempdir().unwrap();
    for colour in ["png", "jpeg"] {
        let (recorded, replayed, file) = record_and_replay(dir.path(), colour);
        assert_eq!(recorded["error"], Value::Null, "{colour}: {recorded}");
        assert_eq!(replayed["error"], Value::Null, "{colour}: {replayed}");
        let channel = &recorded["channels"]["/camera/colour"];
        assert_eq!(channel["schema"], "foxglove.CompressedImage", "{colour}: {channel}");
        assert_eq!(channel["count"], 45, "{colour}: every frame's colour");
        // Validated against Foxglove's published CompressedImage schema (strictly) and the
        // file's own; format and the image bytes are the jpeg or png file.
        assert_eq!(recorded["foxglove_errors"], Value::Array(vec![]), "{colour}");
        assert_eq!(recorded["embedded_errors"], Value::Array(vec![]), "{colour}");
        assert_eq!(recorded["foxglove_validated"]["foxglove.CompressedImage"], 45, "{colour}");
        assert_eq!(recorded["compressed_formats"], serde_json::json!({ colour: 45 }), "{colour}: {recorded}");
        assert_eq!(recorded["metadata"]["op3dsg.recorder"]["dropped_total"], "0", "{colour}");
        // The replay ran every frame (its own recording, raw, has them all).
        assert_eq!(replayed["channels"]["/camera/colour"]["schema"], "foxglove.RawImage");
        assert_eq!(replayed["channels"]["/op3dsg/frame"]["count"], 45, "{colour}");
        let (a, b) = (recorded["last_graph"].as_str().unwrap(), replayed["last_graph"].as_str().unwrap());
        let nodes = |g: &str| serde_json::from_str::<Value>(g).unwrap()["nodes"].as_array().unwrap().len();
        assert!(nodes(b) >= 3, "{colour}: the replay's final graph has {} nodes", nodes(b));
        let info = record_info(&file);
        if colour == "png" {
            assert_eq!(a, b, "png is lossless: the replay's final graph JSON equals the recording run's");
            assert!(info.contains("colour    png (lossless"), "{info}");
        } else {
            // jpeg is lossy: the replay works, its graph is not expected to be byte-identical.
            assert!(info.contains("colour    jpeg (LOSSY"), "{info}");
        }
    }
}

/// A recording written before the `foxglove.*` channels became protobuf (JSON, base64 images):
/// `tests/fixtures/recording-json-ee322aa.mcap`, 20 frames of the synthetic kitchen at 212x120
/// written by the recorder of that commit (tests/fixtures/README.md). It still validates, and its
/// replay, recorded in today's format, ends with the graph the recording run published, to the
/// byte.
#[test]
fn a_recording_of_the_earlier_json_format_replays_bit_for_bit() {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/recording-json-ee322aa.mcap");
    assert!(fixture.is_file(), "{} missing", fixture.display());
    let recorded = check(&fixture);
    assert_eq!(recorded["error"], Value::Null, "{recorded}");
    for topic in ["/camera/colour", "/camera/depth", "/camera/calibration", "/op3dsg/scene", "/tf"] {
        assert_eq!(recorded["channels"][topic]["message_encoding"], "json", "{topic}: the earlier format");
    }
    assert_eq!(recorded["foxglove_errors"], Value::Array(vec![]));
    assert_eq!(recorded["channels"]["/op3dsg/frame"]["count"], 20);
    let info = record_info(&fixture);
    assert!(info.contains("/camera/colour         foxglove.RawImage            json"), "{info}");

    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("replay");
    let replay_path = format!("source.mcap.path=\"{}\"", fixture.display());
    let args =
        replay_args(&replay_path, out_dir.to_str().expect("utf-8 temp path"), &["--set", "record.frame_queue=48"]);
    run_to_end(&unique_prefix("rec-json"), &args);
    let files = mcap_files(&out_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let replayed = check(&files[0]);
    assert_eq!(replayed["error"], Value::Null, "{replayed}");
    assert_eq!(replayed["channels"]["/camera/colour"]["message_encoding"], "protobuf");
    assert_eq!(replayed["channels"]["/op3dsg/frame"]["count"], 20, "every recorded frame replayed");
    assert_eq!(replayed["foxglove_errors"], Value::Array(vec![]));
    assert_same_final_graph(&recorded, &replayed);
    assert!(record_info(&files[0]).contains("/camera/colour         foxglove.RawImage            protobuf"));
}
