//! The MCAP recorder in the real daemon, read back by an independent reader (PyPI `mcap` in the
//! project venv, `tests/python/mcap_check.py`): channels, schemas, counts, order, SceneUpdates
//! equal to their graph versions; record-then-replay through `source.kind = "mcap"` gives the
//! identical final graph; kill -9 leaves a readable file; a failing disk stops the recording,
//! not the daemon.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, unique_prefix, wait_for};
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

fn mcap_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|entries| entries.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.retain(|p| p.extension().is_some_and(|e| e == "mcap"));
    files.sort();
    files
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

fn run_to_end(prefix: &str, args: &[&str]) {
    let output = Command::new(binary("op3dsgd"))
        .arg("--prefix")
        .arg(prefix)
        .args(args)
        .arg("--exit-at-end")
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsgd");
    assert!(output.status.success(), "op3dsgd {args:?} failed: {}", String::from_utf8_lossy(&output.stderr));
}

#[test]
fn synthetic_kitchen_recorded_then_replayed_gives_the_identical_graph() {
    let dir = tempfile::tempdir().unwrap();
    let first_dir = dir.path().join("first");
    let first = first_dir.to_str().unwrap();
    let mut args = vec!["--set", "source.synthetic.frame_count=45", "--record", first];
    args.extend_from_slice(DETERMINISTIC);
    // Paced below what the recorder of a debug build keeps up with, and a deep frame queue: the
    // recording must hold every frame the pipeline used (checked below: no drops).
    args.extend_from_slice(&["--set", "source.rate_hz=8", "--set", "record.frame_queue=32"]);
    run_to_end(&unique_prefix("rec-a"), &args);
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
    ] {
        let channel = &channels[topic];
        assert_eq!(channel["schema"], schema, "{topic}: {channel}");
        assert_eq!(channel["schema_encoding"], "jsonschema", "{topic}");
        assert_eq!(channel["message_encoding"], "json", "{topic}");
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
    assert_eq!(recorded["scene_mismatches"], Value::Array(vec![]), "SceneUpdate boxes = graph boxes");
    assert_eq!(recorded["metadata"]["op3dsg.recorder"]["dropped_total"], "0");
    assert!(recorded["metadata"]["op3dsg.profile"].is_object());

    // Replay through source.kind = "mcap" with the same profile and detector, recording again.
    let second_dir = dir.path().join("second");
    let replay_path = format!("source.mcap.path=\"{}\"", files[0].display());
    let mut args = vec![
        "--set",
        "source.kind=mcap",
        "--set",
        &replay_path,
        "--set",
        "source.mcap.mode=fast",
        "--set",
        "source.synthetic.frame_count=45",
        "--record",
        second_dir.to_str().unwrap(),
    ];
    args.extend_from_slice(DETERMINISTIC);
    run_to_end(&unique_prefix("rec-b"), &args);
    let files = mcap_files(&second_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let replayed = check(&files[0]);
    assert_eq!(replayed["error"], Value::Null, "{replayed}");
    let (a, b) = (recorded["last_graph"].as_str().unwrap(), replayed["last_graph"].as_str().unwrap());
    let nodes = serde_json::from_str::<Value>(a).unwrap()["nodes"].as_array().unwrap().len();
    assert!(nodes >= 3, "the kitchen's final graph has {nodes} nodes");
    assert_eq!(a, b, "final graph JSON of the replay differs from the recording run's");
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
