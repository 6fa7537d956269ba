//! A replay whose files vanish while it plays: a folder of MCAP files the daemon recorded from
//! the synthetic kitchen (rotated every second), replayed at its recorded rate, with files
//! deleted mid-run. The daemon keeps publishing graphs from the files that are left, each
//! vanished file is a warning naming it and a capture error in health; when every file left is
//! gone the source ends, health says so and the daemon keeps serving its last graph.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_ipc_types::Health;
use op3dsg_tests::{Daemon, binary, health_where, health_with_frames_above, mcap_files, unique_prefix, wait_for};

/// Records `frames` synthetic frames into `dir`, a new file every second (at least 1 s per file
/// is the recorder's shortest rotation).
fn record(dir: &Path, frames: u32) -> Vec<PathBuf> {
    let frame_count = format!("source.synthetic.frame_count={frames}");
    let output = Command::new(binary("op3dsgd"))
        .arg("--prefix")
        .arg(unique_prefix("vanish-rec"))
        .args(["--record", dir.to_str().expect("utf-8 temp path"), "--exit-at-end"])
        .args(["--set", &frame_count, "--set", "source.rate_hz=8", "--set", "record.frame_queue=32"])
        // Scene time runs at 4 Hz: the replay (at the recorded rate) takes frames / 4 seconds.
        .args(["--set", "source.synthetic.frame_rate_hz=4", "--set", "record.max_file_s=1"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("run op3dsgd to record");
    assert!(output.status.success(), "recording failed: {}", String::from_utf8_lossy(&output.stderr));
    mcap_files(dir)
}

fn capture_errors(health: &Health) -> u32 {
    health.valid_stages().iter().find(|s| op3dsg_ipc_types::fixed_str(&s.name) == "capture").map_or(0, |s| s.errors)
}

#[test]
fn mcap_files_vanishing_mid_replay_are_skipped_named_and_counted_while_graphs_go_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let recording = dir.path().join("rec");
    let files = record(&recording, 80);
    assert!(files.len() >= 5, "the recording rotated into several files: {files:?}");

    let log_path = dir.path().join("replay.log");
    let log = std::fs::File::create(&log_path).expect("log file");
    let prefix = unique_prefix("vanish-replay");
    let mcap_path = format!("source.mcap.path={:?}", recording.display().to_string());
    let child = Command::new(binary("op3dsgd"))
        .arg("--prefix")
        .arg(&prefix)
        .args(["--set", "source.kind=\"mcap\"", "--set", &mcap_path, "--set", "source.mcap.mode=\"recorded\""])
        .args(["--set", "source.rate_hz=0", "--set", "health.period_ms=100"])
        .env("OP3DSG_LOG", "warn")
        .stdin(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("spawn the replaying op3dsgd");
    let mut daemon = Daemon { child, prefix };
    let mut health = daemon.health_subscriber("vanish-health");
    let read_log = || std::fs::read_to_string(&log_path).unwrap_or_default();

    // Playing the first file: delete the second and third (the replay has not opened them yet).
    let start = health_with_frames_above(&mut health, 1, Duration::from_secs(60));
    assert_eq!(capture_errors(&start), 0);
    let vanished = [&files[1], &files[2]];
    for file in vanished {
        std::fs::remove_file(file).expect("delete a recording file");
    }

    // Both are skipped, each named in a warning and counted; frames from the later files follow.
    let skipped =
        health_where(&mut health, "two vanished files counted", Duration::from_secs(60), |h| capture_errors(h) >= 2);
    assert_eq!(capture_errors(&skipped), 2, "each vanished file counts once");
    assert_eq!(skipped.source_connected, 1, "the source goes on");
    for file in vanished {
        let named = format!("path={}", file.display());
        wait_for(&format!("a warning naming {}", file.display()), Duration::from_secs(10), || {
            read_log()
                .lines()
                .any(|l| l.contains("recording file vanished during replay") && l.contains(&named))
                .then_some(())
        });
    }
    let later = health_with_frames_above(&mut health, skipped.frames_captured + 4, Duration::from_secs(60));
    assert!(
        later.graph_version > start.graph_version,
        "graphs keep coming from the files after the vanished ones: v{} then v{}",
        start.graph_version,
        later.graph_version
    );

    // Now every file but the one playing goes: the source ends, the daemon stays up and serves.
    for file in mcap_files(&recording) {
        std::fs::remove_file(&file).expect("delete a recording file");
    }
    let ended = health_where(&mut health, "the source to end", Duration::from_secs(60), |h| h.source_connected == 0);
    assert!(capture_errors(&ended) >= 3, "the files deleted last count too: {}", capture_errors(&ended));
    let after = health_where(&mut health, "health after the end", Duration::from_secs(10), |h| {
        h.stamp_ns > ended.stamp_ns + 500_000_000
    });
    assert_eq!(after.frames_captured, ended.frames_captured, "no frames after the end");
    let mut planner = daemon.graph_subscriber("vanish-late-planner");
    let graph = wait_for("the last graph for a late planner", Duration::from_secs(30), || {
        planner.latest().ok().flatten().map(|g| g.version())
    });
    assert_eq!(graph, after.graph_version, "the daemon serves the last graph");
    assert!(daemon.child.try_wait().expect("daemon status").is_none(), "the daemon keeps running: {}", read_log());
}
