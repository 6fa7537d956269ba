//! What the ROS 2 tests share: the Zenoh router standing in for `rmw_zenohd` or
//! zenoh-bridge-ros2dds, and the Python scripts' paths.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

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
