//! The client library's example planner (`ipc_types/examples/planner.rs`, built against
//! `op3dsg-ipc-types` alone) reads a live graph from a running `op3dsgd` in another process.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, binary, unique_prefix};

/// Watchdog of the example's run (not a speed requirement).
const WATCHDOG: Duration = Duration::from_secs(120);

#[test]
fn the_example_planner_prints_live_graph_versions_with_parts_and_parents() {
    let prefix = unique_prefix("planner");
    let _daemon = Daemon::start(&prefix, &["--set", "source.rate_hz=60"]);
    // Examples are built next to the binaries, in `target/<profile>/examples/`.
    let planner = binary("examples/planner");
    let mut child = Command::new(&planner)
        .args(["--prefix", &prefix, "--versions", "12"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn the example planner");
    let started = Instant::now();
    while child.try_wait().expect("poll the planner").is_none() {
        if started.elapsed() > WATCHDOG {
            let _ = child.kill();
            panic!("the example planner did not print 12 graph versions within {WATCHDOG:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().expect("planner output");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "planner failed: {}\n{stdout}", String::from_utf8_lossy(&output.stderr));
    let versions: Vec<u64> =
        stdout.lines().filter_map(|l| l.strip_prefix("version ")?.split_whitespace().next()?.parse().ok()).collect();
    assert_eq!(versions.len(), 12, "{stdout}");
    assert!(versions.windows(2).all(|w| w[0] < w[1]), "each version is newer than the last: {versions:?}");
    // The kitchen's graph grows parts with their parent objects as the robot looks around.
    assert!(stdout.lines().any(|l| l.trim_start().starts_with("part ") && !l.contains("of \"(none)\"")), "{stdout}");
}
