//! The real daemon in one process, real iceoryx2 subscribers in this one.

use std::time::Duration;

use op3dsg_tests::{Daemon, health_with_frames_above, unique_prefix, wait_for};

/// A fast synthetic kitchen: 60 Hz and short health periods so the tests move quickly.
const FAST: &[&str] = &["--set", "source.rate_hz=60", "--set", "health.period_ms=100"];

#[test]
fn subscriber_sees_graph_versions_increase() {
    let prefix = unique_prefix("versions");
    let daemon = Daemon::start(&prefix, FAST);
    let mut graphs = daemon.graph_subscriber("versions-client");
    let first = wait_for("a first graph", Duration::from_secs(60), || graphs.latest().ok().flatten().cloned());
    let later = wait_for("a later graph version", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().filter(|g| g.version() > first.version() + 2).cloned()
    });
    assert!(later.version() > first.version());
    assert!(later.node_count() >= first.node_count(), "the kitchen map only grows while exploring");
    assert!(later.nodes().any(|n| n.kind() == op3dsg_ipc_types::NodeKind::Object));
}

#[test]
fn late_subscriber_gets_the_current_graph_at_once() {
    let prefix = unique_prefix("late");
    // The source stops after 120 frames; the daemon keeps serving its last graph.
    let daemon = Daemon::start(
        &prefix,
        &["--set", "source.rate_hz=0", "--set", "run.max_frames=120", "--set", "health.period_ms=100"],
    );
    let mut early = daemon.health_subscriber("late-early");
    // Settled: the source has ended and the graph version no longer changes between two records.
    let mut previous = None;
    let final_version = wait_for("the map to settle", Duration::from_secs(120), || {
        let h = early.latest().ok().flatten()?;
        if h.frames_captured < 120 || h.source_connected != 0 {
            return None;
        }
        let settled = previous == Some(h.graph_version);
        previous = Some(h.graph_version);
        std::thread::sleep(Duration::from_millis(300));
        settled.then_some(h.graph_version)
    });
    // A subscriber attaching now, with nothing new being published, gets the current graph at once.
    let mut late = daemon.graph_subscriber("late-late");
    let graph = wait_for("the history sample", Duration::from_secs(2), || late.latest().ok().flatten().cloned());
    assert_eq!(graph.version(), final_version);
    assert!(graph.node_count() > 0);
}

#[test]
fn a_subscriber_that_never_reads_does_not_hold_the_daemon_back() {
    let prefix = unique_prefix("stalled");
    let daemon = Daemon::start(&prefix, FAST);
    // This client subscribes to the graph and never reads it; its buffer fills at once.
    let _stalled = daemon.graph_subscriber("stalled-reader");
    let mut watcher = daemon.health_subscriber("stalled-watcher");
    let first = health_with_frames_above(&mut watcher, 0, Duration::from_secs(60));
    let later = health_with_frames_above(&mut watcher, first.frames_captured + 60, Duration::from_secs(60));
    assert!(later.graph_version > first.graph_version, "graph versions keep coming");
}

#[test]
fn restarted_daemon_serves_again_after_kill_9() {
    let prefix = unique_prefix("restart");
    let mut daemon = Daemon::start(&prefix, FAST);
    let mut graphs = daemon.graph_subscriber("restart-client-1");
    // A planner that stays attached across the restart, as a real one would.
    let mut planner = daemon.graph_subscriber("restart-planner");
    let first = wait_for("a graph from the first daemon", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().map(|g| (g.instance_id(), g.version()))
    });
    let (first_instance, _) = first;
    assert_ne!(first_instance, 0, "an instance id is never 0");
    // The planner's bookkeeping: the newest version it has seen, well beyond the new daemon's
    // first versions.
    let seen = wait_for("the planner's first graph", Duration::from_secs(60), || {
        planner.latest_if_newer(0).ok().flatten().map(|g| (g.instance_id(), g.version()))
    });
    assert_eq!(seen.0, first_instance);
    assert!(!planner.restarted());
    drop(graphs);
    daemon.kill_9();

    let second = Daemon::start(&prefix, FAST);
    let mut graphs = second.graph_subscriber("restart-client-2");
    let mut health = second.health_subscriber("restart-health-2");
    let first_health = health_with_frames_above(&mut health, 0, Duration::from_secs(60));
    health_with_frames_above(&mut health, first_health.frames_captured + 10, Duration::from_secs(60));
    let (second_instance, version) = wait_for("a graph from the restarted daemon", Duration::from_secs(60), || {
        graphs.latest().ok().flatten().filter(|g| g.node_count() > 0).map(|g| (g.instance_id(), g.version()))
    });
    assert!(version >= 1);
    assert_ne!(second_instance, 0);
    assert_ne!(second_instance, first_instance, "a restart draws a new instance id");

    // The planner attached to the old daemon takes the new daemon's graphs even though it asks
    // for versions newer than the old daemon's, and is told that the daemon restarted.
    let taken = wait_for("the attached planner to take the new daemon's graph", Duration::from_secs(60), || {
        let _ = planner.wait_for_update(Duration::from_millis(100));
        let graph = planner.latest_if_newer(seen.1).ok().flatten()?;
        (graph.instance_id() == second_instance).then(|| (graph.version(), graph.restarted()))
    });
    assert!(planner.restarted(), "the subscriber reports the restart");
    assert!(taken.1, "the graph reports the restart");
}
