//! The real daemon on a real recording: `[source] kind = "replay"` over the ICL-NUIM sequence in
//! `../shared/data` (skipped with a message when absent), and bad data stopping or being skipped.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{binary, unique_prefix};

/// Longest a daemon run may take before the test kills it and fails (a watchdog, not a speed
/// requirement).
const WATCHDOG: Duration = Duration::from_secs(120);

/// The shared ICL-NUIM sequence; `None` (skip, said on stderr) without it, a failure in CI.
fn icl_dir() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1").map(|dir| dir.canonicalize().expect("canonical path"))
}

/// Runs `op3dsgd --profile <profile> <args>` at log level info; returns the exit code and stderr.
fn run_daemon(profile: &Path, args: &[&str]) -> (Option<i32>, String) {
    let log = tempfile::NamedTempFile::new().expect("log file");
    let mut child = Command::new(binary("op3dsgd"))
        .arg("--profile")
        .arg(profile)
        .arg("--prefix")
        .arg(unique_prefix("replay"))
        .args(args)
        .env("OP3DSG_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log.reopen().expect("log file"))
        .spawn()
        .expect("spawn op3dsgd");
    let deadline = Instant::now() + WATCHDOG;
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait op3dsgd") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "op3dsgd did not exit within {WATCHDOG:?}: {}",
                std::fs::read_to_string(log.path()).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    (status.code(), std::fs::read_to_string(log.path()).expect("read log"))
}

fn write_profile(dir: &Path, replay_table: &str) -> PathBuf {
    let path = dir.join("replay.toml");
    let text = format!("[source]\nkind = \"replay\"\nrate_hz = 0.0\n\n[source.replay]\n{replay_table}");
    std::fs::write(&path, text).expect("write profile");
    path
}

#[test]
fn daemon_consumes_the_icl_sequence_at_its_recorded_rate() {
    let Some(icl) = icl_dir() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let profile = write_profile(dir.path(), &format!("path = {:?}\n", icl.display().to_string()));
    let (code, log) = run_daemon(&profile, &["--max-frames", "50"]);
    assert_eq!(code, Some(0), "{log}");
    assert!(log.contains("replay opened") && log.contains("frames=211"), "{log}");
    assert!(log.contains("stopped frames=50 "), "{log}");
    // Frames carry poses: the keyframe gate accepted some (none dropped for lack of a pose).
    let keyframes: u64 = log
        .split("keyframes=")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .expect("the summary names keyframes");
    assert!(keyframes >= 2, "{log}");
    // The oracle cannot detect on real frames; it says so clearly instead of inventing objects.
    assert!(
        log.contains("frame has no instance ids: the oracle detector only works with the synthetic source"),
        "{log}"
    );
}

/// A copy of the first `n` ICL frames with frame 2's depth image cut short.
fn corrupt_copy(icl: &Path, n: usize) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = dir.path().join("rec");
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(rec.join(sub)).expect("mkdir");
    }
    std::fs::copy(icl.join("camera.json"), rec.join("camera.json")).expect("copy camera.json");
    for index in ["rgb.txt", "depth.txt", "groundtruth.txt"] {
        let text = std::fs::read_to_string(icl.join(index)).expect("read index");
        let lines: Vec<&str> = text.lines().take(2 + n).collect();
        if index != "groundtruth.txt" {
            for line in &lines[2..] {
                let file = line.split_whitespace().nth(1).expect("file name");
                std::fs::copy(icl.join(file), rec.join(file)).expect("copy image");
            }
        }
        std::fs::write(rec.join(index), lines.join("\n") + "\n").expect("write index");
    }
    let bad = rec.join("depth/00002.png");
    let bytes = std::fs::read(&bad).expect("read png");
    std::fs::write(&bad, &bytes[..bytes.len() / 3]).expect("corrupt png");
    dir
}

#[test]
fn bad_frame_stops_the_daemon_or_is_skipped_and_counted() {
    let Some(icl) = icl_dir() else { return };
    let dir = corrupt_copy(&icl, 5);
    // A relative path: resolved against the profile's folder, not the working directory.
    let profile = write_profile(dir.path(), "path = \"rec\"\nmode = \"fast\"\n");
    let (code, log) = run_daemon(&profile, &["--exit-at-end"]);
    assert_eq!(code, Some(1), "{log}");
    let rec = dir.path().join("rec");
    let named = format!("{}: cannot decode PNG", rec.join("depth/00002.png").display());
    assert!(log.contains(&named), "{log}");
    assert!(log.contains(&format!("listed at {}:5", rec.join("depth.txt").display())), "{log}");
    assert!(log.contains("stopped frames=2 "), "{log}");

    let profile = write_profile(dir.path(), "path = \"rec\"\nmode = \"fast\"\non_bad_frame = \"skip\"\n");
    let (code, log) = run_daemon(&profile, &["--exit-at-end"]);
    assert_eq!(code, Some(0), "{log}");
    assert!(log.contains("replay: bad data skipped") && log.contains(&named), "{log}");
    assert!(log.contains("stopped frames=4 ") && log.contains("bad_data_skipped=1"), "{log}");
}
