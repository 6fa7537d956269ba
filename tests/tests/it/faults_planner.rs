//! Planner faults the daemon must survive: planners (real `op3dsg watch` processes reading the
//! graph) killed with SIGKILL while reading, more of them than the graph service has subscriber
//! slots, and a planner that attaches and never reads. The daemon keeps publishing (health
//! frames and graph versions keep rising), health shows the planners connected and the dead
//! ones it cleaned up, and a new planner can still attach.
//!
//! The test runs in its own iceoryx2 root (`in_own_ipc_root`): in a shared root, the daemon of a
//! test running beside this one could clean up the killed planners first and this one count none.

use std::process::{Command, Stdio};
use std::time::Duration;

use op3dsg_tests::{Daemon, binary, health_with_frames_above, in_own_ipc_root, unique_prefix, wait_for};

#[test]
fn planners_killed_mid_read_and_one_that_never_reads_do_not_stop_the_daemon() {
    if !in_own_ipc_root("faults_planner::planners_killed_mid_read_and_one_that_never_reads_do_not_stop_the_daemon") {
        return;
    }
    let prefix = unique_prefix("planner-faults");
    // Three subscriber slots, one held by a planner that never reads: three planners killed in
    // turn are more than the two slots left, so a dead planner's slot must come back.
    let daemon = Daemon::start(
        &prefix,
        &["--set", "source.rate_hz=60", "--set", "health.period_ms=100", "--set", "ipc.max_subscribers=3"],
    );
    let mut health = daemon.health_subscriber("faults-health");
    let _never_reads = daemon.graph_subscriber("faults-never-reads");
    let start = health_with_frames_above(&mut health, 0, Duration::from_secs(60));

    for round in 0..3 {
        let mut planner = Command::new(binary("op3dsg"))
            .args(["--prefix", &prefix, "watch", "--interval-ms", "10"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start a planner (op3dsg watch)");
        // Reading: it printed graph lines.
        let mut stdout = planner.stdout.take().expect("planner stdout");
        let mut buffer = [0u8; 4096];
        let read = std::io::Read::read(&mut stdout, &mut buffer).expect("read the planner's output");
        assert!(read > 0, "planner {round} printed nothing");
        planner.kill().expect("SIGKILL the planner");
        let _ = planner.wait();
    }

    let after = health_with_frames_above(&mut health, start.frames_captured + 60, Duration::from_secs(60));
    assert!(after.graph_version > start.graph_version, "graph versions keep coming after the killed planners");
    // The faults show in health: the killed planners' nodes were cleaned up (at least the last
    // one: no later planner could have done it), and the one that never reads is still
    // counted as connected.
    let cleaned = wait_for("health counting the killed planners cleaned up", Duration::from_secs(30), || {
        health.latest().ok().flatten().filter(|h| h.dead_nodes_cleaned >= 1)
    });
    assert!(cleaned.graph_subscribers >= 1, "the planner that never reads is connected: {cleaned:?}");
    assert!(
        usize::from(cleaned.graph_subscribers) <= 3,
        "a killed planner's slot is not counted after its cleanup: {} subscribers",
        cleaned.graph_subscribers
    );
    // A new planner still gets a subscriber slot and the current graph.
    let mut late = daemon.graph_subscriber("faults-late");
    let graph =
        wait_for("a graph for the late planner", Duration::from_secs(30), || late.latest().ok().flatten().cloned());
    assert!(graph.version() >= after.graph_version);
}
