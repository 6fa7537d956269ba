//! `op3dsg health`: the daemon's latest health record, read with the client library's
//! [`HealthSubscriber`] (the `health` service alone, so it works when every graph subscriber
//! slot is taken), as text or as [`HealthReport`] JSON.

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use op3dsg_ipc_types::HealthSubscriber;
use op3dsg_runtime::ipc::HealthReport;
use op3dsg_runtime::ipc::health_report::{RecorderReport, RefinerReport, RemoteReport, SnapshotReport, TfReport};

use super::{connect_error, node_name, poll_until, write_output};

/// `op3dsg health`: waits up to `timeout` for the daemon and a record, then prints it.
pub(super) fn health(prefix: &str, json: bool, timeout: Duration) -> Result<()> {
    let deadline = Instant::now() + timeout;
    let mut healths =
        HealthSubscriber::open_wait(prefix, &node_name(), timeout).map_err(|e| connect_error(prefix, timeout, e))?;
    let remaining = deadline.saturating_duration_since(Instant::now());
    let Some(record) =
        poll_until(remaining, || healths.latest()).with_context(|| format!("reading service {prefix}/health"))?
    else {
        bail!("no health record received on service {prefix}/health within {:.1} s", timeout.as_secs_f64());
    };
    print_report(&HealthReport::from(&record), json)
}

/// `op3dsg health --zenoh`: the newest record from the queryable `<key_prefix>/health` of a
/// daemon on another computer, printed as `op3dsg health` prints it.
#[cfg(feature = "zenoh")]
pub(super) fn remote(endpoint: &str, key_prefix: &str, json: bool, timeout: Duration) -> Result<()> {
    let remote = op3dsg_ipc_types::client::RemoteRequester::connect(endpoint, key_prefix)?;
    let (_, record) = remote.health(timeout)?;
    let report: HealthReport = serde_json::from_str(&record).with_context(|| {
        format!("{} on {endpoint}: the health record is not the expected JSON", remote.key("health"))
    })?;
    print_report(&report, json)
}

/// Prints a health report as `op3dsg health` does: pretty JSON or the text form.
fn print_report(report: &HealthReport, json: bool) -> Result<()> {
    let text = if json {
        let mut text = serde_json::to_string_pretty(report).context("serialising the health JSON")?;
        text.push('\n');
        text
    } else {
        health_text(report)
    };
    write_output(None, &text)
}

fn health_text(h: &HealthReport) -> String {
    let mut s = String::new();
    write_counters(&mut s, h);
    write_stages_and_queues(&mut s, h);
    if h.recorder.state != "off" {
        write_recorder(&mut s, &h.recorder);
    }
    if h.snapshot.state != "off" {
        write_snapshot(&mut s, &h.snapshot);
    }
    if h.refiner.state != "off" {
        write_refiner(&mut s, &h.refiner);
    }
    if let Some(tf) = &h.tf {
        write_tf(&mut s, tf);
    }
    if let Some(remote) = &h.remote {
        write_remote(&mut s, remote);
    }
    s
}

/// Remote detection: the fallback, then a line per worker.
fn write_remote(s: &mut String, r: &RemoteReport) {
    let _ = writeln!(
        s,
        "remote detection  fallback {}  fallback keyframes {}  switches to it {}",
        if r.fallback_active { "ACTIVE" } else { "off" },
        r.fallback_keyframes,
        r.fallback_switches
    );
    if r.workers.is_empty() {
        let _ = writeln!(s, "  no worker seen yet");
    }
    for w in &r.workers {
        let rejected: u64 = w.rejections.values().sum();
        let reasons: Vec<String> =
            w.rejections.iter().filter(|(_, n)| **n > 0).map(|(reason, n)| format!("{reason} {n}")).collect();
        let reasons = if reasons.is_empty() { String::new() } else { format!(" ({})", reasons.join(", ")) };
        let _ = writeln!(
            s,
            "  {}  {}  requests {}  replies {}  timeouts {}  late {}  unreachable {}  rejected {rejected}{reasons}  \
             in flight {}  round trip p50 {:.1} ms p99 {:.1} ms  {:.0} kB/keyframe",
            w.key,
            if w.alive { "alive" } else { "GONE" },
            w.requests,
            w.replies,
            w.timeouts,
            w.late,
            w.unreachable,
            w.in_flight,
            w.round_trip_p50_ms,
            w.round_trip_p99_ms,
            w.bytes_per_keyframe as f64 / 1e3
        );
    }
    if r.workers_not_reported > 0 {
        let _ = writeln!(
            s,
            "  and {} more workers (op3dsg's Zenoh key <prefix>/detect_status lists them)",
            r.workers_not_reported
        );
    }
}

/// The tf input: the last chain and the age of its data, then its message counters.
fn write_tf(s: &mut String, tf: &TfReport) {
    let path = if tf.path.is_empty() { "no lookup yet" } else { tf.path.as_str() };
    let age = match tf.data_age_s {
        Some(age) => format!("data age {age:.3} s"),
        None if tf.path.is_empty() => String::new(),
        None => "static chain".to_owned(),
    };
    let _ = writeln!(s, "tf  {path}  {age}");
    let _ = writeln!(
        s,
        "tf messages  /tf {}  /tf_static {}  refused transforms {}  jumps back in time {}",
        tf.dynamic_messages, tf.static_messages, tf.transforms_refused, tf.time_jumps
    );
}

/// The daemon's counters: uptime, source, graph and map, frames, planners, poses, models.
fn write_counters(s: &mut String, h: &HealthReport) {
    let _ = writeln!(
        s,
        "uptime {:.1} s  source {} {}  world frame {}  graph version {}  map nodes {} ({:.1} MiB)",
        h.uptime_s,
        h.source_kind,
        if h.source_connected { "connected" } else { "disconnected" },
        h.world_frame,
        h.graph_version,
        h.map_node_count,
        op3dsg_runtime::stats::mib(h.map_memory_bytes)
    );
    let _ = writeln!(
        s,
        "frames {}  keyframes {}  without pose {}  detections fused {}",
        h.frames_captured, h.keyframes, h.frames_without_pose, h.detections_fused
    );
    let _ = writeln!(
        s,
        "planners {} connected  dead processes cleaned up by the daemon {} (an attaching planner cleans up too)",
        h.graph_subscribers, h.dead_nodes_cleaned
    );
    let _ = writeln!(s, "poses  {}", pose_line(h));
    for m in &h.models {
        let fallback = if m.provider == m.requested_provider {
            String::new()
        } else {
            format!(" (asked for {})", m.requested_provider)
        };
        let _ = writeln!(s, "model {} on {}{} ({} sessions)", m.name, m.provider, fallback, m.sessions);
    }
}

/// The pose input's line: what it received by outcome, or why it receives nothing.
pub(super) fn pose_line(h: &HealthReport) -> String {
    let poses: Vec<String> = h.poses.iter().filter(|(_, n)| **n > 0).map(|(k, n)| format!("{k} {n}")).collect();
    if h.pose_source == "frame" {
        return "not read: pose.source = \"frame\" takes the pose each frame carries, so poses sent to \
                <prefix>/pose are ignored (pose.source = \"ipc\" uses them)"
            .to_owned();
    }
    if poses.is_empty() { "none received".to_owned() } else { poses.join("  ") }
}

/// A table of the stages and one of the queues.
fn write_stages_and_queues(s: &mut String, h: &HealthReport) {
    let _ = writeln!(
        s,
        "{:<16} {:>10} {:>9} {:>10} {:>10} {:>7}",
        "stage", "processed", "rate_hz", "p50_us", "p99_us", "errors"
    );
    for st in &h.stages {
        let _ = writeln!(
            s,
            "{:<16} {:>10} {:>9.2} {:>10.0} {:>10.0} {:>7}",
            st.name, st.processed, st.rate_hz, st.latency_p50_us, st.latency_p99_us, st.errors
        );
    }
    let _ = writeln!(s, "{:<16} {:>7} {:>9} {:>10} {:>10}", "queue", "depth", "capacity", "dropped", "pushed");
    for q in &h.queues {
        let _ = writeln!(s, "{:<16} {:>7} {:>9} {:>10} {:>10}", q.name, q.depth, q.capacity, q.dropped, q.pushed);
    }
}

fn write_recorder(s: &mut String, rec: &RecorderReport) {
    let _ = writeln!(
        s,
        "recorder {}  files {}  written {}  dropped {}  {:.1} MiB on disk",
        rec.state,
        rec.files,
        rec.messages_written,
        rec.messages_dropped,
        rec.bytes_written as f64 / (1 << 20) as f64
    );
}

fn write_snapshot(s: &mut String, snap: &SnapshotReport) {
    let age = if snap.last_written_unix_ms == 0 {
        "none written yet".to_owned()
    } else {
        let now_ms =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64);
        format!("last written {} s ago", now_ms.saturating_sub(snap.last_written_unix_ms) / 1000)
    };
    let _ = writeln!(
        s,
        "snapshots {} (restored version {})  {}  version {}  {:.1} KiB  written {}  failed {}  skipped {}",
        snap.state,
        snap.restored_version,
        age,
        snap.version,
        snap.last_bytes as f64 / 1024.0,
        snap.written,
        snap.failures,
        snap.skipped
    );
}

fn write_refiner(s: &mut String, r: &RefinerReport) {
    let _ = writeln!(
        s,
        "llm refiner {}{}  refreshes {}  calls {}  failures {} (timeouts {}, 429 {}, last {})  accepted {}  last latency {:.0} ms  last graph version {}  format {}",
        r.state,
        if r.breaker_open { " (breaker open)" } else { "" },
        r.refreshes,
        r.calls,
        r.failures,
        r.timeouts,
        r.rate_limited,
        r.last_error,
        r.accepted,
        f64::from(r.last_latency_us) / 1000.0,
        r.last_graph_version,
        r.response_format
    );
    // In the wire order (malformed ... implausible_affordance), not alphabetically.
    let rejections: Vec<String> = op3dsg_ipc_types::REFINER_REJECTIONS
        .iter()
        .map(|k| format!("{k} {}", r.rejections.get(*k).copied().unwrap_or(0)))
        .collect();
    let _ = writeln!(s, "llm rejections  {}", rejections.join("  "));
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::Health;

    use super::*;

    #[test]
    fn health_text_shows_the_llm_refiner_only_when_configured() {
        let mut health = Health::default();
        assert!(!health_text(&HealthReport::from(&health)).contains("llm"));
        health.refiner.state = 4;
        health.refiner.breaker_open = 1;
        health.refiner.calls = 6;
        health.refiner.failures = 6;
        health.refiner.rejections[1] = 2;
        health.refiner.last_error = 2;
        health.refiner.rejections[6] = 3;
        health.refiner.response_format = 2;
        health.pose.accepted = 5;
        health.pose.out_of_order = 1;
        let text = health_text(&HealthReport::from(&health));
        assert!(text.contains("poses  accepted 5  out_of_order 1\n"), "{text}");
        assert!(text.contains("llm refiner breaker_open (breaker open)  refreshes 0  calls 6  failures 6"), "{text}");
        assert!(text.contains("unknown_node 2"), "{text}");
        assert!(
            text.contains("llm rejections  malformed 0  unknown_node 2  wrong_kind 0  non_canonical 0  stale 0  implausible_geometry 0  implausible_relation 3  implausible_affordance 0\n"),
            "every reason, in the wire order: {text}"
        );
        assert!(text.contains("format json_object_fallback"), "{text}");
        assert!(text.contains("failures 6 (timeouts 0, 429 0, last refused)"), "{text}");
        let json = serde_json::to_value(HealthReport::from(&health)).unwrap();
        assert_eq!(json["refiner"]["rejections"]["unknown_node"], 2);
    }

    #[test]
    fn health_text_says_why_no_pose_arrives_when_the_frames_carry_them() {
        // pose.source = "frame": what a PosePublisher sends is not read, and the line says so.
        let mut health = Health { pose_source: 1, ..Health::default() };
        let text = health_text(&HealthReport::from(&health));
        assert!(text.contains("poses  not read: pose.source = \"frame\" takes the pose each frame carries"), "{text}");
        assert!(!text.contains("none received"), "{text}");
        // From the pose input: what it received, or that nothing came yet.
        health.pose_source = 2;
        assert!(health_text(&HealthReport::from(&health)).contains("poses  none received\n"));
        health.pose.accepted = 3;
        assert!(health_text(&HealthReport::from(&health)).contains("poses  accepted 3\n"));
        let json = serde_json::to_value(HealthReport::from(&health)).unwrap();
        assert_eq!(json["pose_source"], "ipc");
    }

    #[test]
    fn health_text_says_what_the_source_is_and_the_world_frame() {
        let mut health = Health { source_connected: 1, source_kind: 1, ..Health::default() };
        op3dsg_ipc_types::write_fixed_str(&mut health.world_frame, "map");
        let text = health_text(&HealthReport::from(&health));
        assert!(
            text.starts_with("uptime 0.0 s  source live_camera connected  world frame map  graph version 0"),
            "{text}"
        );
        // A kind this build does not know reads as unknown, not as a failure.
        health.source_kind = 99;
        let json = serde_json::to_value(HealthReport::from(&health)).unwrap();
        assert_eq!(
            (&json["source_kind"], &json["world_frame"]),
            (&serde_json::json!("unknown"), &serde_json::json!("map"))
        );
    }

    #[test]
    fn health_text_shows_the_tf_chain_and_its_age_only_with_the_tf_input() {
        let mut health = Health { stamp_ns: 10_250_000_000, ..Health::default() };
        assert!(!health_text(&HealthReport::from(&health)).contains("tf "), "no tf input, no tf lines");
        health.tf.active = 1;
        assert!(health_text(&HealthReport::from(&health)).contains("tf  no lookup yet  \n"));
        op3dsg_ipc_types::write_fixed_str(&mut health.tf.path, "map -> odom -> camera");
        (health.tf.lookup_stamp_ns, health.tf.newest_data_ns, health.tf.static_messages) =
            (10_000_000_000, 10_000_000_000, 1);
        let text = health_text(&HealthReport::from(&health));
        assert!(text.contains("tf  map -> odom -> camera  data age 0.250 s\n"), "{text}");
        assert!(text.contains("/tf_static 1  refused transforms 0"), "{text}");
        let json = serde_json::to_value(HealthReport::from(&health)).unwrap();
        assert_eq!(json["tf"]["data_age_s"], 0.25);
        // A chain of static links only: no age.
        health.tf.newest_data_ns = 0;
        assert!(health_text(&HealthReport::from(&health)).contains("camera  static chain\n"));
    }

    #[test]
    fn health_text_shows_each_remote_worker_only_with_remote_detection() {
        let mut health = Health::default();
        assert!(!health_text(&HealthReport::from(&health)).contains("remote detection"));
        health.remote.active = 1;
        assert!(health_text(&HealthReport::from(&health)).contains("no worker seen yet"));
        health.remote.fallback_active = 1;
        health.remote.worker_count = 1;
        let w = &mut health.remote.workers[0];
        op3dsg_ipc_types::write_fixed_str(&mut w.key, "robot/op3dsg/detect/gpu");
        (w.requests, w.replies, w.timeouts, w.bytes_out, w.bytes_in) = (10, 8, 1, 9_000_000, 1_000_000);
        w.rejections[1] = 1;
        w.round_trip_p50_us = 120_000.0;
        let text = health_text(&HealthReport::from(&health));
        assert!(text.contains("remote detection  fallback ACTIVE"), "{text}");
        assert!(text.contains("robot/op3dsg/detect/gpu  GONE  requests 10  replies 8  timeouts 1"), "{text}");
        assert!(text.contains("rejected 1 (wrong_id 1)"), "{text}");
        assert!(text.contains("p50 120.0 ms") && text.contains("1000 kB/keyframe"), "{text}");
        let json = serde_json::to_value(HealthReport::from(&health)).unwrap();
        assert_eq!(json["remote"]["workers"][0]["rejections"]["wrong_id"], 1);
        assert_eq!(json["remote"]["workers"][0]["bytes_per_keyframe"], 1_000_000);
    }
}
