//! Poses as a navigation stack sends them, across processes: `op3dsgd` with
//! `pose.source = "ipc"` and a stand-in navigation stack in another process
//! (`op3dsg-test-nav`, the client library's `PosePublisher`) sending the synthetic robot's true
//! path at 10 Hz while the camera runs at 30 Hz (scene time).
//!
//! 1. The 10 Hz stream, interpolated by the daemon, gives the same graph as the source's own
//!    30 Hz poses: the same nodes (count, kind and label) with centres within a bound computed
//!    from the path (see `same_graph_within`).
//! 2. A future-stamped pose, NaN poses and out-of-order poses are each refused and counted in
//!    health under their reason, and fusing goes on with the good poses that follow.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::Duration;

use op3dsg_ipc_types::{Graph, Health, HealthSubscriber, PoseHealth};
use op3dsg_tests::{Daemon, binary, unique_prefix, wait_for};

/// Frames in the comparison run: scene time 0 .. 3 s at 30 Hz. The last frame (index 90) is
/// stamped exactly at a 10 Hz pose, so no frame needs a pose after the stream's end.
const FRAMES: u64 = 91;
/// Frame rate of the synthetic source (scene time) and pose rate of the navigation stack.
const FRAME_RATE_HZ: f64 = 30.0;
const POSE_RATE_HZ: f64 = 10.0;

fn profile() -> String {
    format!("{}/../profiles/sim-clean.toml", env!("CARGO_MANIFEST_DIR"))
}

/// The daemon's settings in both runs: the noise-free kitchen at 320x240, every posed frame a
/// keyframe, queues that block instead of dropping (so both runs fuse exactly the same frames),
/// short health periods.
fn common_args(profile: &str) -> Vec<String> {
    let mut args = vec!["--profile".to_owned(), profile.to_owned()];
    for set in [
        "source.rate_hz=15",
        "source.synthetic.intrinsics={ width = 320, height = 240, fx = 307.5, fy = 307.5, cx = 160.0, cy = 120.0 }",
        "keyframe.max_interval_s=0",
        "queues.frames={ capacity = 2, policy = \"block\" }",
        "queues.keyframes={ capacity = 2, policy = \"block\" }",
        "health.period_ms=100",
        "detector.workers=1",
    ] {
        args.push("--set".to_owned());
        args.push(set.to_owned());
    }
    args
}

/// The daemon with poses from `<prefix>/pose`; frames wait up to 3 s for the pose after them (the
/// stand-in navigation stack learns the scene time from health, every 100 ms).
fn ipc_args(profile: &str) -> Vec<String> {
    let mut args = common_args(profile);
    for set in ["pose.source=\"ipc\"", "pose.max_wait_ms=3000"] {
        args.push("--set".to_owned());
        args.push(set.to_owned());
    }
    args
}

/// The stand-in navigation stack, killed on drop.
struct Navigation {
    child: Child,
    stdin: Option<ChildStdin>,
    acks: Receiver<String>,
}

impl Navigation {
    fn start(prefix: &str) -> Self {
        let mut child = Command::new(binary("op3dsg-test-nav"))
            .args(["--prefix", prefix])
            .args(["--frame-rate-hz", &FRAME_RATE_HZ.to_string(), "--pose-rate-hz", &POSE_RATE_HZ.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("spawn op3dsg-test-nav");
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().expect("stdout");
        let (tx, acks) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("nav-stdout".to_owned())
            .spawn(move || {
                for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                    let _ = tx.send(line);
                }
            })
            .expect("reader thread");
        Self { child, stdin, acks }
    }

    /// Sends one command and waits for its `ok`.
    fn command(&mut self, line: &str) {
        let stdin = self.stdin.as_mut().expect("stdin open");
        writeln!(stdin, "{line}").expect("write command");
        stdin.flush().expect("flush");
        let ack = self.acks.recv_timeout(Duration::from_secs(30)).expect("the navigation stack answers");
        assert_eq!(ack, format!("ok {line}"));
    }
}

impl Drop for Navigation {
    fn drop(&mut self) {
        drop(self.stdin.take());
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn stage_processed(h: &Health, name: &str) -> u64 {
    h.valid_stages().iter().find(|s| op3dsg_ipc_types::fixed_str(&s.name) == name).map_or(0, |s| s.processed)
}

/// Waits until the daemon captured `frames` frames, fused every keyframe and published the
/// result; returns the last health record and the final graph.
fn finished_run(daemon: &Daemon, frames: u64, what: &str) -> (Health, Graph) {
    let mut health = daemon.health_subscriber(&format!("{what}-health"));
    let mut graphs = daemon.graph_subscriber(&format!("{what}-graph"));
    let mut stable_since: Option<(u64, std::time::Instant)> = None;
    let last = wait_for(&format!("{what}: {frames} frames fused and published"), Duration::from_secs(300), || {
        let h = health.latest().ok().flatten()?;
        let drained = h.frames_captured == frames
            && h.keyframes + h.frames_without_pose == frames
            && stage_processed(&h, "fusion") == h.keyframes;
        let version = h.graph_version;
        if !drained {
            stable_since = None;
            return None;
        }
        match stable_since {
            Some((v, since)) if v == version && since.elapsed() > Duration::from_millis(800) => Some(h),
            Some((v, _)) if v == version => None,
            _ => {
                stable_since = Some((version, std::time::Instant::now()));
                None
            }
        }
    });
    let graph = wait_for(&format!("{what}: graph version {}", last.graph_version), Duration::from_secs(30), || {
        graphs.latest().ok().flatten().filter(|g| g.version() == last.graph_version).cloned()
    });
    (last, graph)
}

/// The interpolation bound of the 10 Hz stream against the path (`op3dsg-test-nav
/// --interpolation-bound`): translation metres, rotation radians.
fn interpolation_bound() -> (f64, f64) {
    let output = Command::new(binary("op3dsg-test-nav"))
        .args(["--interpolation-bound", "--frames", &FRAMES.to_string()])
        .args(["--frame-rate-hz", &FRAME_RATE_HZ.to_string(), "--pose-rate-hz", &POSE_RATE_HZ.to_string()])
        .output()
        .expect("run op3dsg-test-nav --interpolation-bound");
    let text = String::from_utf8_lossy(&output.stdout);
    let words: Vec<&str> = text.split_whitespace().collect();
    match words.as_slice() {
        ["translation_m", t, "rotation_rad", r] => (t.parse().expect("number"), r.parse().expect("number")),
        _ => panic!("unexpected bound output: {text}"),
    }
}

/// "Same graph": the same number of nodes, the same (kind, label) multiset, and each node of
/// `reference` paired with a distinct node of `other` of its kind and label whose centre is
/// within `tolerance_m(kind)`. Pairing is greedy by distance, closest pairs first.
fn same_graph_within(reference: &Graph, other: &Graph, tolerance_m: impl Fn(bool) -> f64) -> Result<f64, String> {
    let describe = |g: &Graph| {
        let mut v: Vec<(bool, String)> = g.nodes().map(|n| (n.is_part(), n.label().to_owned())).collect();
        v.sort();
        v
    };
    if describe(reference) != describe(other) {
        return Err(format!(
            "nodes differ:\n  source poses: {:?}\n  ipc poses:    {:?}",
            describe(reference),
            describe(other)
        ));
    }
    let mut pairs = Vec::new();
    for a in reference.nodes() {
        for b in other.nodes().filter(|b| b.is_part() == a.is_part() && b.label() == a.label()) {
            let (ca, cb) = (a.centre_m(), b.centre_m());
            let d = ((ca[0] - cb[0]).powi(2) + (ca[1] - cb[1]).powi(2) + (ca[2] - cb[2]).powi(2)).sqrt();
            pairs.push((f64::from(d), a.id(), b.id(), a.is_part(), a.label().to_owned()));
        }
    }
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    let (mut used_a, mut used_b) = (std::collections::HashSet::new(), std::collections::HashSet::new());
    let mut worst = 0.0f64;
    for (d, a, b, is_part, label) in pairs {
        if used_a.contains(&a) || used_b.contains(&b) {
            continue;
        }
        used_a.insert(a);
        used_b.insert(b);
        if d > tolerance_m(is_part) {
            return Err(format!(
                "{label} (node {a} / {b}): centres {d:.4} m apart, tolerance {:.4} m",
                tolerance_m(is_part)
            ));
        }
        worst = worst.max(d);
    }
    Ok(worst)
}

#[test]
fn a_10_hz_pose_stream_gives_the_graph_of_the_sources_own_poses() {
    let profile = profile();
    let max_frames = format!("run.max_frames={FRAMES}");
    // Reference: the source's own 30 Hz poses.
    let prefix_frame = unique_prefix("poses-frame");
    let mut args = common_args(&profile);
    args.extend(["--set".to_owned(), max_frames.clone()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let reference_daemon = Daemon::start(&prefix_frame, &args);
    // The same scene, poses from the navigation stack at 10 Hz.
    let prefix_ipc = unique_prefix("poses-ipc");
    let mut args = ipc_args(&profile);
    args.extend(["--set".to_owned(), max_frames]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let ipc_daemon = Daemon::start(&prefix_ipc, &args);
    let _navigation = Navigation::start(&prefix_ipc);

    let (reference_health, reference) = finished_run(&reference_daemon, FRAMES, "poses-frame");
    let (ipc_health, interpolated) = finished_run(&ipc_daemon, FRAMES, "poses-ipc");
    assert_eq!(reference_health.frames_without_pose, 0);
    assert_eq!(ipc_health.frames_without_pose, 0, "every frame got an interpolated pose: {:?}", ipc_health.pose);
    assert_eq!(ipc_health.keyframes, reference_health.keyframes);
    let frames_per_pose = (FRAME_RATE_HZ / POSE_RATE_HZ) as u64;
    let expected_poses = (FRAMES - 1) / frames_per_pose + 1;
    assert!(ipc_health.pose.accepted >= expected_poses, "{:?}", ipc_health.pose);
    assert_eq!(
        ipc_health.pose,
        PoseHealth { accepted: ipc_health.pose.accepted, ..PoseHealth::default() },
        "a clean stream: nothing refused"
    );
    assert!(reference.node_count() >= 5, "a scene worth comparing: {} nodes", reference.node_count());

    // Tolerance: interpolating the 10 Hz poses puts a frame's pose at most e_t metres and e_r
    // radians off the path (the path's own accelerations bound it, with a factor 2 of margin),
    // which moves a point at the 6 m depth limit by at most e_t + 6 e_r. A node's centre is the
    // mean of its voxel-downsampled points; points near voxel borders may fall on the other side,
    // so one voxel edge (2.5 cm objects, 0.5 cm parts) is added.
    let (e_t, e_r) = interpolation_bound();
    let shift_m = e_t + 6.0 * e_r;
    let tolerance = |is_part: bool| shift_m + if is_part { 0.005 } else { 0.025 };
    eprintln!(
        "interpolation bound: {e_t:.5} m, {:.4} deg; centre tolerance objects {:.4} m, parts {:.4} m",
        e_r.to_degrees(),
        tolerance(false),
        tolerance(true)
    );
    match same_graph_within(&reference, &interpolated, tolerance) {
        Ok(worst_m) => eprintln!("{} nodes alike; largest centre difference {worst_m:.4} m", reference.node_count()),
        Err(e) => panic!("{e}"),
    }
}

/// Waits for a health record whose pose counters satisfy `ok`.
fn pose_counters(health: &mut HealthSubscriber, what: &str, ok: impl Fn(&Health) -> bool) -> Health {
    wait_for(what, Duration::from_secs(60), || health.latest().ok().flatten().filter(|h| ok(h)))
}

#[test]
fn future_nan_and_out_of_order_poses_are_refused_by_reason_and_fusing_goes_on() {
    let profile = profile();
    let prefix = unique_prefix("poses-bad");
    let args = ipc_args(&profile);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let daemon = Daemon::start(&prefix, &args);
    let mut navigation = Navigation::start(&prefix);
    let mut health = daemon.health_subscriber("poses-bad-health");
    let good = pose_counters(&mut health, "keyframes from good poses", |h| h.keyframes >= 10 && h.pose.accepted >= 4);
    let clean = PoseHealth { accepted: good.pose.accepted, ..PoseHealth::default() };
    assert_eq!(good.pose, clean, "nothing refused yet");

    navigation.command("future");
    let after_future = pose_counters(&mut health, "the future pose counted", |h| h.pose.future == 1);
    navigation.command("nan 3");
    let after_nan = pose_counters(&mut health, "3 NaN poses counted", |h| h.pose.non_finite == 3);
    navigation.command("out_of_order 3");
    let after_bad = pose_counters(&mut health, "3 out-of-order poses counted", |h| h.pose.out_of_order == 3);
    // Each reason counted exactly: the future pose was not adopted, so the good poses after it
    // were not out of order, and nothing else was refused.
    let refused = PoseHealth {
        accepted: after_bad.pose.accepted,
        future: 1,
        non_finite: 3,
        out_of_order: 3,
        ..PoseHealth::default()
    };
    assert_eq!(after_bad.pose, refused);
    assert!(
        after_future.pose.accepted <= after_nan.pose.accepted && after_nan.pose.accepted <= after_bad.pose.accepted
    );

    // Fusing goes on: more keyframes, good poses adopted, new graph versions, no frame without a
    // pose beyond those already counted.
    let resumed = pose_counters(&mut health, "fusing after the bad poses", |h| {
        h.keyframes >= after_bad.keyframes + 10
            && h.pose.accepted >= after_bad.pose.accepted + 3
            && h.graph_version > after_bad.graph_version
    });
    assert_eq!(resumed.pose, PoseHealth { accepted: resumed.pose.accepted, ..refused });
    assert_eq!(resumed.frames_without_pose, good.frames_without_pose, "no frame lost its pose");
}
