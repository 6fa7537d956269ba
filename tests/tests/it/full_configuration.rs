//! The robot's whole configuration as one run, with the clients people use at the far ends:
//! one `op3dsgd` on `profiles/stretch3-ros2.toml`, its source the ICL-NUIM living-room recording
//! paced like a camera, and every feature on at once —
//!
//! - poses from tf: `tests/python/ros2_tf_publisher.py` (PyPI `eclipse-zenoh` and `rosbags`)
//!   sends the recording's trajectory (at twice the frame rate) as a Stretch-like tf chain
//!   through a Zenoh router standing in for zenoh-bridge-ros2dds; the ROS output (markers,
//!   occupancy) on the same router;
//! - remote detection on two `op3dsg-detectd` workers (YOLOX-nano, CPU), one connecting to the
//!   daemon's `zenoh.listen`, one listening where the daemon's `zenoh.connect` points;
//! - the graph over Zenoh (`zenoh.enabled`, the same session) to an outside consumer
//!   (`tests/python/zenoh_consumer.py`, PyPI `eclipse-zenoh`);
//! - the live view with a Foxglove client connected the whole run
//!   (`tests/python/foxglove_client.py`, PyPI `websockets` and `protobuf`);
//! - the recorder and map snapshots on;
//! - a Python planner over iceoryx2 (`ipc_types/python/examples/planner.py`).
//!
//! At the end every consumer holds the graph version `op3dsg dump --json` gives (the Zenoh
//! consumer node for node, the planner its counts, the live view its scene); every keyframe was
//! answered by a worker (none to the fallback) and both workers answered; every frame got its
//! pose from tf; the only drops health counts are on `latest_wins` queues; the recorder dropped
//! nothing; the snapshot folder holds the map.
//!
//! The run lasts about `OP3DSG_FULL_RUN_S` seconds (default 60: the recording's 211 frames at
//! 211 / 60 frames a second). With `OP3DSG_FULL_RUN_BENCH=1` the same recording is then run by a
//! bare daemon (same profile and pacing; remote detection on the same workers, everything else
//! off) and one `full configuration:` line gives the CPU time of both over the run
//! (docs/benchmarks.md's row). Needs `.models/` and the shared development data (skips with a
//! message when absent, fails in CI).

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use op3dsg_tests::{Daemon, unique_prefix};
use serde_json::Value;

use crate::remote_common::{self, Status, StatusWatch, Worker, remote_args};
use crate::ros2_common::{publish, router, script, static_publisher, trajectory};
use crate::zenoh_common::{self, Consumer, assert_same_graph, python};

/// Frames of the ICL living-room recording.
const FRAMES: u64 = 211;

fn icl_dir() -> Option<PathBuf> {
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb.txt")?;
    op3dsg_shared_data::shared_data("rgbd/icl_livingroom1").map(|dir| dir.canonicalize().expect("canonical path"))
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path).display().to_string()
}

/// Four free loopback ports, all different (each held until all are picked).
fn distinct_ports() -> [u16; 4] {
    let held: Vec<std::net::TcpListener> =
        (0..4).map(|_| std::net::TcpListener::bind("127.0.0.1:0").expect("bind a free port")).collect();
    std::array::from_fn(|i| held[i].local_addr().expect("port").port())
}

/// How long the run lasts, seconds (`OP3DSG_FULL_RUN_S`, default 60).
fn run_seconds() -> f64 {
    std::env::var("OP3DSG_FULL_RUN_S").ok().and_then(|v| v.parse().ok()).filter(|s: &f64| *s > 0.0).unwrap_or(60.0)
}

/// CPU time (user + system) of process `pid` so far, seconds.
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("/proc/PID/stat");
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = &stat[stat.rfind(')').expect("stat") + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = fields[11].parse::<f64>().expect("utime") + fields[12].parse::<f64>().expect("stime");
    ticks / 100.0
}

/// The queues whose policy is `latest_wins` in the daemon's effective profile
/// (`op3dsgd --print-config`): the only ones allowed to drop.
fn latest_wins_queues(args: &[String]) -> Vec<String> {
    let output = Command::new(op3dsg_tests::binary("op3dsgd"))
        .args(args)
        .arg("--print-config")
        .output()
        .expect("op3dsgd --print-config");
    assert!(output.status.success(), "--print-config: {}", String::from_utf8_lossy(&output.stderr));
    let text = String::from_utf8_lossy(&output.stdout);
    let mut queue = None;
    let mut out = Vec::new();
    for line in text.lines() {
        if let Some(section) = line.strip_prefix('[') {
            queue = section.strip_suffix(']').and_then(|s| s.strip_prefix("queues.")).map(str::to_owned);
        } else if let (Some(name), Some(policy)) = (&queue, line.strip_prefix("policy = "))
            && policy.trim_matches('"') == "latest_wins"
        {
            out.push(name.clone());
        }
    }
    out
}

/// Hands every line of `stdout` to `each` on a thread of its own.
fn read_lines(name: &str, stdout: BufReader<std::process::ChildStdout>, mut each: impl FnMut(&str) + Send + 'static) {
    std::thread::Builder::new()
        .name(name.to_owned())
        .spawn(move || {
            for line in stdout.lines().map_while(Result::ok) {
                each(&line);
            }
        })
        .expect("spawn a reader thread");
}

/// The planner example over iceoryx2, its stdout read on a thread; killed on drop.
struct Planner {
    child: Child,
    last: Arc<Mutex<Option<(u64, String)>>>,
}

impl Planner {
    fn start(prefix: &str) -> Self {
        let mut child = Command::new(python())
            .arg(repo("ipc_types/python/examples/planner.py"))
            .args(["--prefix", prefix])
            .stdout(Stdio::piped())
            .spawn()
            .expect("run planner.py");
        let stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let last = Arc::new(Mutex::new(None));
        let seen = last.clone();
        read_lines("planner-stdout", stdout, move |line| {
            {
                // "version N objects A parts B edges C"
                if let Some(rest) = line.strip_prefix("version ") {
                    let version = rest.split_whitespace().next().and_then(|v| v.parse().ok()).unwrap_or(0);
                    *seen.lock().expect("lock") = Some((version, line.to_owned()));
                }
            }
        });
        Self { child, last }
    }

    /// The newest "version ..." line once it is of `version`.
    fn at(&self, version: u64) -> String {
        op3dsg_tests::wait_for("the planner at the dumped version", Duration::from_secs(60), || {
            self.last.lock().expect("lock").clone().filter(|(v, _)| *v == version).map(|(_, line)| line)
        })
    }
}

impl Drop for Planner {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A Foxglove WebSocket client connected to the live view for the whole run, printing every
/// scene update; the newest kept. Killed on drop.
struct LiveViewer {
    child: Child,
    last: Arc<Mutex<Option<Value>>>,
    count: Arc<Mutex<u64>>,
}

impl LiveViewer {
    /// Connects once the live view listens on `port` (the daemon starts it after the Zenoh
    /// session and before the first frame).
    fn start(port: u16) -> Self {
        op3dsg_tests::wait_for("the live view listening", Duration::from_secs(60), || {
            std::net::TcpStream::connect(("127.0.0.1", port)).ok()
        });
        let url = format!("ws://127.0.0.1:{port}");
        let mut child = Command::new(python())
            .arg(script("foxglove_client.py"))
            .args(["scene", "--url", &url, "--count", "1000000", "--timeout-s", "3600"])
            .stdout(Stdio::piped())
            .spawn()
            .expect("run foxglove_client.py");
        let stdout = BufReader::new(child.stdout.take().expect("stdout"));
        let (last, count) = (Arc::new(Mutex::new(None)), Arc::new(Mutex::new(0)));
        let (seen, counted) = (last.clone(), count.clone());
        read_lines("viewer-stdout", stdout, move |line| {
            if let Ok(update) = serde_json::from_str::<Value>(line) {
                *seen.lock().expect("lock") = Some(update);
                *counted.lock().expect("lock") += 1;
            }
        });
        Self { child, last, count }
    }

    /// The node entities of the newest scene once it is of graph `version`, and how many
    /// scenes came so far.
    fn scene_at(&self, version: u64) -> (usize, u64) {
        op3dsg_tests::wait_for("the live view's scene at the dumped version", Duration::from_secs(60), || {
            let last = self.last.lock().expect("lock").clone()?;
            (last["graph_version"].as_u64() == Some(version)).then(|| {
                let entities = last["entities"].as_array().map(Vec::as_slice).unwrap_or_default();
                let nodes =
                    entities.iter().filter(|e| e["id"].as_str().is_some_and(|id| id.starts_with("node/"))).count();
                (nodes, *self.count.lock().expect("lock"))
            })
        })
    }
}

impl Drop for LiveViewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The daemon's arguments: the Stretch's ROS 2 profile on the recording, paced at `rate_hz`,
/// with remote detection on the two workers and, with `everything`, every other feature.
struct Setup<'a> {
    icl: &'a Path,
    rate_hz: f64,
    router_port: u16,
    daemon_port: u16,
    worker_port: u16,
    key_prefix: &'a str,
    dir: &'a Path,
    live_port: u16,
}

impl Setup<'_> {
    fn args(&self, everything: bool) -> Vec<String> {
        let mut sets = vec![
            "source.kind=\"replay\"".to_owned(),
            format!("source.replay.path=\"{}\"", self.icl.display()),
            "source.replay.mode=\"fast\"".to_owned(),
            format!("source.rate_hz={}", self.rate_hz),
            "run.exit_at_end=false".to_owned(),
            "world.up_axis=\"y\"".to_owned(),
            format!("zenoh.connect=[\"tcp/127.0.0.1:{}\"]", self.worker_port),
            "detector.remote.timeout_ms=30000".to_owned(),
            // The recording's own keyframe and fusion settings (profiles/replay-icl.toml): its
            // camera moves slower than the Stretch's head.
            "keyframe.min_translation_m=0.05".to_owned(),
            "keyframe.min_rotation_deg=5.0".to_owned(),
            "fusion.object_nnr_radius_m=0.08".to_owned(),
            "fusion.min_mean_score=0.4".to_owned(),
        ];
        if everything {
            sets.extend([
                format!("ros2.connect=[\"tcp/127.0.0.1:{}\"]", self.router_port),
                "pose.max_wait_ms=5000".to_owned(),
                "pose.future_tolerance_ms=600000".to_owned(),
                "pose.buffer_len=1000".to_owned(),
                "ros2.tf.window_s=600.0".to_owned(),
                "zenoh.enabled=true".to_owned(),
                "live_view.enabled=true".to_owned(),
                format!("live_view.bind=\"127.0.0.1:{}\"", self.live_port),
                "record.enabled=true".to_owned(),
                format!("record.dir=\"{}\"", self.dir.join("record").display()),
                "snapshot.enabled=true".to_owned(),
                format!("snapshot.dir=\"{}\"", self.dir.join("snapshots").display()),
            ]);
        } else {
            sets.extend([
                "pose.source=\"frame\"".to_owned(),
                "ros2.out.markers=false".to_owned(),
                "ros2.out.occupancy=false".to_owned(),
            ]);
        }
        let sets: Vec<&str> = sets.iter().map(String::as_str).collect();
        let mut args = vec!["--profile".to_owned(), repo("profiles/stretch3-ros2.toml")];
        args.extend(remote_args(self.daemon_port, self.key_prefix, &["w1", "w2"], &sets));
        args
    }
}

fn health_json(prefix: &str) -> Value {
    zenoh_common::dump_with(&["--prefix", prefix, "health", "--json"])
}

/// Poses from tf for every frame; drops only where a queue's policy allows them; the recorder
/// dropped nothing and wrote a file; the snapshot folder holds the map.
fn assert_health(health: &Value, allowed_drops: &[String], dir: &Path) {
    assert_eq!(health["frames_without_pose"], 0, "{health}");
    for queue in health["queues"].as_array().expect("queues") {
        let name = queue["name"].as_str().unwrap_or_default();
        if queue["dropped"].as_u64().unwrap_or(0) > 0 {
            assert!(
                allowed_drops.iter().any(|q| q == name),
                "queue {name} dropped: {queue} (latest_wins: {allowed_drops:?})"
            );
        }
    }
    assert_eq!(health["recorder"]["messages_dropped"], 0, "{health}");
    assert!(!op3dsg_tests::mcap_files(&dir.join("record")).is_empty(), "a recording");
    let snapshots = std::fs::read_dir(dir.join("snapshots")).map(|d| d.count()).unwrap_or(0);
    assert!(snapshots > 0, "the snapshot folder holds the map");
}

/// The bare daemon on the same recording and pacing (remote detection on the same workers,
/// everything else off); prints the `full configuration:` row next to the full run's CPU.
fn bench_bare(setup: &Setup<'_>, seconds: f64, (cpu_full, wall): (f64, f64)) {
    let bare =
        Daemon::start(&unique_prefix("bare-run"), &setup.args(false).iter().map(String::as_str).collect::<Vec<_>>());
    let cpu_at_start = cpu_seconds(bare.child.id());
    let bare_started = Instant::now();
    remote_common::final_graph(&bare, FRAMES, Duration::from_secs_f64(seconds * 3.0 + 120.0));
    let cpu_bare = cpu_seconds(bare.child.id()) - cpu_at_start;
    let bare_wall = bare_started.elapsed().as_secs_f64();
    println!(
        "full configuration: everything on {cpu_full:.1} s CPU over {wall:.0} s ({:.1} % of one core), \
         bare {cpu_bare:.1} s CPU over {bare_wall:.0} s ({:.1} %), ratio {:.2}",
        100.0 * cpu_full / wall,
        100.0 * cpu_bare / bare_wall,
        (cpu_full / wall) / (cpu_bare / bare_wall),
    );
}

#[test]
fn the_stretch_configuration_with_every_feature_on_serves_one_graph_to_every_client() {
    let (Some(icl), Some(worker_profile)) = (icl_dir(), remote_common::profile()) else { return };
    let seconds = run_seconds();
    let dir = tempfile::tempdir().expect("tempdir");
    let traj = dir.path().join("trajectory.json");
    trajectory(&icl, &traj);
    let [router_port, daemon_port, worker_port, live_port] = distinct_ports();
    let key_prefix = format!("full{}", std::process::id());
    let setup = Setup {
        icl: &icl,
        rate_hz: FRAMES as f64 / seconds,
        router_port,
        daemon_port,
        worker_port,
        key_prefix: &key_prefix,
        dir: dir.path(),
        live_port,
    };

    let _router = router(router_port);
    let _statics = static_publisher(router_port, "bridge", &traj);
    let listening = format!("zenoh.listen=[\"tcp/127.0.0.1:{worker_port}\"]");
    let _w1 = Worker::start(&worker_profile, daemon_port, &key_prefix, "w1", &[]);
    let _w2 = Worker::start_with(&worker_profile, daemon_port, &key_prefix, "w2", &["zenoh.connect=[]", &listening]);

    let args = setup.args(true);
    let allowed_drops = latest_wins_queues(&args);
    let prefix = unique_prefix("full-run");
    let started = Instant::now();
    let daemon = Daemon::start(&prefix, &args.iter().map(String::as_str).collect::<Vec<_>>());
    let cpu_at_start = cpu_seconds(daemon.child.id());
    // The camera's poses at twice the frame rate, so tf stays ahead of the frames as a robot's
    // does (a burst of the whole trajectory would overrun the recorder's queue, which a robot's
    // tf never sends).
    let tf_rate = format!("{}", 2.0 * setup.rate_hz);
    let tf = {
        let traj = traj.clone();
        std::thread::Builder::new()
            .name("tf-publisher".to_owned())
            .spawn(move || publish(router_port, "bridge", &traj, &["--no-static", "--rate", &tf_rate]))
            .expect("spawn the tf publisher")
    };
    let watch = StatusWatch::start(Status::connect(daemon_port, &key_prefix));
    let mut consumer = Consumer::start(daemon_port, &key_prefix);
    let planner = Planner::start(&prefix);
    let viewer = LiveViewer::start(live_port);

    let dumped = remote_common::final_graph(&daemon, FRAMES, Duration::from_secs_f64(seconds * 3.0 + 120.0));
    let sent = tf.join().expect("tf publisher");
    assert_eq!(sent["published"].as_u64(), Some(FRAMES), "{sent}");
    let cpu_full = cpu_seconds(daemon.child.id()) - cpu_at_start;
    let wall = started.elapsed().as_secs_f64();
    let version = dumped["graph_version"].as_u64().expect("graph_version");
    let nodes = dumped["nodes"].as_array().expect("nodes").len();
    let labels: Vec<&str> =
        dumped["nodes"].as_array().expect("nodes").iter().filter_map(|n| n["label"].as_str()).collect();
    for label in ["chair", "tv"] {
        assert!(labels.contains(&label), "the recording's {label} is in the graph: {labels:?}");
    }
    let health = health_json(&prefix);
    let figures = watch.finish();

    // Every consumer at the dumped version, with the dumped graph.
    let instance_id = zenoh_common::instance_of(&daemon);
    let held = consumer.state(instance_id, version);
    assert_eq!(held["graph_version"].as_u64(), Some(version), "the Zenoh consumer at the dumped version");
    assert_same_graph(&dumped, &held);
    let planned = planner.at(version);
    let objects = dumped["nodes"].as_array().expect("nodes").iter().filter(|n| n["kind"] == "object").count();
    let edges = dumped["edges"].as_array().expect("edges").len();
    assert_eq!(
        planned,
        format!("version {version} objects {objects} parts {} edges {edges}", nodes - objects),
        "the planner over iceoryx2"
    );
    let (scene_nodes, scenes) = viewer.scene_at(version);
    assert_eq!(scene_nodes, nodes, "the live view's scene: one entity per node");

    // The workers answered every keyframe, both of them.
    assert_eq!(figures["fallback_keyframes"], 0, "no keyframe to the fallback: {figures}");
    for w in ["w1", "w2"] {
        let replies = figures["workers"][format!("{key_prefix}/detect/{w}")]["replies"].as_u64().unwrap_or(0);
        assert!(replies > 0, "worker {w} answered: {figures}");
    }
    assert_health(&health, &allowed_drops, dir.path());
    println!(
        "full run: {wall:.0} s, {FRAMES} frames at {:.2} Hz, graph version {version}, {nodes} nodes, \
         {scenes} live scenes, worker replies {}, {}",
        setup.rate_hz,
        figures["workers"][format!("{key_prefix}/detect/w1")]["replies"],
        figures["workers"][format!("{key_prefix}/detect/w2")]["replies"],
    );
    drop((viewer, planner, consumer, daemon));

    if std::env::var("OP3DSG_FULL_RUN_BENCH").as_deref() == Ok("1") {
        bench_bare(&setup, seconds, (cpu_full, wall));
    }
    let _ = std::io::stdout().flush();
}
