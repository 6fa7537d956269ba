//! What the ROS 2 tests share: the Zenoh router standing in for `rmw_zenohd` or
//! zenoh-bridge-ros2dds, the Python scripts' paths, and the tf publisher of a recording's
//! trajectory.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use serde_json::Value;

use super::zenoh_common::python;

/// A child process killed on drop.
pub struct Killed(pub Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python").join(name)
}

/// The router on `port`, once it listens.
pub fn router(port: u16) -> Killed {
    let mut child = Command::new(python())
        .arg(script("zenoh_router.py"))
        .arg(port.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start zenoh_router.py");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout")).read_line(&mut line).expect("router output");
    assert_eq!(line.trim(), "ready", "zenoh_router.py did not start");
    Killed(child)
}

/// The ground truth of the recording as the publisher's trajectory (`world_from_camera` per
/// stamp), written from the TUM `groundtruth.txt` format.
pub fn trajectory(icl: &Path, out: &Path) {
    let text = std::fs::read_to_string(icl.join("groundtruth.txt")).expect("groundtruth.txt");
    let poses: Vec<Value> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split_whitespace().collect();
            let (sec, frac) = v[0].split_once('.').unwrap_or((v[0], "0"));
            let stamp_ns = sec.parse::<u64>().expect("seconds") * 1_000_000_000
                + format!("{frac:0<9}")[..9].parse::<u64>().expect("fraction");
            let f = |i: usize| v[i].parse::<f64>().expect("number");
            serde_json::json!({"stamp_ns": stamp_ns, "translation_m": [f(1), f(2), f(3)], "rotation_xyzw": [f(4), f(5), f(6), f(7)]})
        })
        .collect();
    std::fs::write(out, serde_json::to_string(&poses).expect("JSON")).expect("write the trajectory");
}

/// A static broadcaster started before the daemon: publishes `/tf_static` once and keeps it in
/// its cache (transient local) until dropped; the daemon must fetch it when it subscribes.
pub fn static_publisher(port: u16, style: &str, traj: &Path) -> Killed {
    let mut child = Command::new(python())
        .arg(script("ros2_tf_publisher.py"))
        .args(["--key-style", style, "--distro", "humble", "--static-only", "--linger-s", "600"])
        .args(["--connect", &format!("tcp/127.0.0.1:{port}")])
        .arg("--trajectory")
        .arg(traj)
        .stdout(Stdio::piped())
        .spawn()
        .expect("start ros2_tf_publisher.py --static-only");
    let stdout = BufReader::new(child.stdout.take().expect("stdout"));
    let done = stdout.lines().map_while(Result::ok).any(|line| line.contains("\"done\""));
    assert!(done, "ros2_tf_publisher.py --static-only ended before publishing");
    Killed(child)
}

/// Runs the publisher to the end of the trajectory; its last line.
pub fn publish(port: u16, style: &str, traj: &Path, faults: &[&str]) -> Value {
    let output = Command::new(python())
        .arg(script("ros2_tf_publisher.py"))
        .args(["--key-style", style, "--distro", "humble", "--rate", "0", "--linger-s", "1"])
        .args(["--connect", &format!("tcp/127.0.0.1:{port}")])
        .arg("--trajectory")
        .arg(traj)
        .args(faults)
        .output()
        .expect("run ros2_tf_publisher.py");
    assert!(output.status.success(), "ros2_tf_publisher.py: {}", String::from_utf8_lossy(&output.stderr));
    let text = String::from_utf8_lossy(&output.stdout);
    serde_json::from_str(text.lines().last().unwrap_or_default()).expect("publisher JSON")
}
