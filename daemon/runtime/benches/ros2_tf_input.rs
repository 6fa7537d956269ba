//! CPU of the tf input (`pose.source = "ros2"`) at a realistic `/tf` rate, end to end: the
//! thread `op3dsg-ros2-tf` as the daemon runs it (its Zenoh client session, the subscribers, CDR
//! decoding, the transform buffer and one lookup per stamp) against a robot in another process.
//!
//! The robot (this binary started again as a child) is a Zenoh peer on a free loopback port with
//! bridge keys: one `/tf_static` message of a 200-frame tree (a Stretch-like chain `map -> odom
//! -> base_link -> link_head_tilt -> camera_link -> camera_color_optical_frame` and 19 arms of 10
//! links), kept in its cache, then `/tf` at `--rate` messages per second, each with 30 dynamic
//! edges (the chain's three and 27 arm joints), for `--seconds`, then nothing for as long.
//!
//! This process's CPU time (user + system, all threads, from `/proc/self/stat`) is read over the
//! publishing window and over the quiet one in the same run: the difference is the subscription's
//! cost, also given per message.
//!
//! `cargo bench -p op3dsg-runtime --features zenoh --bench ros2_tf_input [-- --rate 100 --seconds 10]`

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::{DQuat, DVec3};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ros2::msg::builtin_interfaces::Time;
use op3dsg_ros2::msg::geometry_msgs::TransformStamped;
use op3dsg_ros2::msg::std_msgs::Header;
use op3dsg_ros2::msg::tf2_msgs::TFMessage;
use op3dsg_ros2::{RigidTransform, TfConfig, encode};
use op3dsg_runtime::ros2::{Ros2Config, TfInputCounters, TfInputThread};
use op3dsg_runtime::stats::PoseStats;
use zenoh::Wait;
use zenoh_ext::{AdvancedPublisherBuilderExt, CacheConfig};

/// Set in the child's environment: it is the robot, publishing on this port.
const ROBOT_ENV: &str = "OP3DSG_BENCH_TF_ROBOT";

fn edge(parent: &str, child: &str, stamp_ns: u64, angle: f64) -> TransformStamped {
    TransformStamped {
        header: Header { stamp: Time::from_ns(stamp_ns), frame_id: parent.to_string() },
        child_frame_id: child.to_string(),
        transform: RigidTransform::new(DQuat::from_rotation_z(angle), DVec3::new(0.1, angle.sin(), 0.2)).into(),
    }
}

fn arm_parent(arm: usize, link: usize) -> String {
    if link == 0 { "base_link".to_string() } else { format!("arm{arm}_link{}", link - 1) }
}

/// The 30 dynamic edges at a stamp: the chain's three and the first two joints of 19 arms.
fn dynamic(stamp_ns: u64) -> TFMessage {
    let t = stamp_ns as f64 * 1e-9;
    let mut transforms = vec![
        edge("map", "odom", stamp_ns, 0.01 * t),
        edge("odom", "base_link", stamp_ns, 0.3 * t),
        edge("base_link", "link_head_tilt", stamp_ns, 0.5 * t.sin()),
    ];
    'arms: for arm in 0..19 {
        for link in 0..2 {
            if transforms.len() == 30 {
                break 'arms;
            }
            transforms.push(edge(&arm_parent(arm, link), &format!("arm{arm}_link{link}"), stamp_ns, t + arm as f64));
        }
    }
    TFMessage { transforms }
}

/// The rest of the 200-frame tree, static.
fn statics() -> TFMessage {
    let mut transforms =
        vec![edge("link_head_tilt", "camera_link", 0, 0.1), edge("camera_link", "camera_color_optical_frame", 0, 0.2)];
    for child in ["laser", "imu", "wheel_left", "wheel_right"] {
        transforms.push(edge("base_link", child, 0, 0.0));
    }
    let dynamic_children: Vec<String> = dynamic(0).transforms.into_iter().map(|t| t.child_frame_id).collect();
    for arm in 0..19 {
        for link in 0..10 {
            let child = format!("arm{arm}_link{link}");
            if !dynamic_children.contains(&child) {
                transforms.push(edge(&arm_parent(arm, link), &child, 0, 0.05));
            }
        }
    }
    TFMessage { transforms }
}

/// The child: a Zenoh peer listening on `port`; statics once, then `/tf` at `rate` for
/// `seconds`, then quiet for `seconds`. Says `publishing`, `quiet` and `done` on stdout.
fn robot(port: u16, rate: f64, seconds: f64) {
    let mut config = zenoh::Config::default();
    for (key, value) in [
        ("mode", "\"peer\"".to_owned()),
        ("listen/endpoints", format!("[\"tcp/127.0.0.1:{port}\"]")),
        ("scouting/multicast/enabled", "false".to_owned()),
        // A publication cache orders its samples by timestamp.
        ("timestamping/enabled", "true".to_owned()),
    ] {
        config.insert_json5(key, &value).expect("zenoh config");
    }
    let session = zenoh::open(config).wait().expect("robot session");
    let tf_static = session
        .declare_publisher("tf_static")
        .cache(CacheConfig::default().max_samples(1))
        .publisher_detection()
        .wait()
        .expect("tf_static publisher");
    tf_static.put(encode(&statics())).wait().expect("put tf_static");
    let tf = session.declare_publisher("tf").wait().expect("tf publisher");
    let mut out = std::io::stdout();
    let mut line = String::new();
    // Wait for the parent's go (its subscribers are declared).
    std::io::stdin().read_line(&mut line).expect("go");
    let _ = writeln!(out, "publishing");
    let _ = out.flush();
    let period = Duration::from_secs_f64(1.0 / rate);
    let (start, messages) = (Instant::now(), (rate * seconds).round() as u64);
    let stamp0 = 1_000_000_000_000u64;
    for k in 0..messages {
        tf.put(encode(&dynamic(stamp0 + k * period.as_nanos() as u64))).wait().expect("put tf");
        let next = start + period * (k as u32 + 1);
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    let _ = writeln!(out, "quiet");
    let _ = out.flush();
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let _ = writeln!(out, "done {messages}");
    let _ = out.flush();
    let _ = session.close().wait();
}

/// This process's CPU time so far (user + system, every thread, live or ended), seconds.
fn cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
    // Fields after the command name (which may hold spaces) start at the state, field 3.
    let rest = &stat[stat.rfind(')').expect("stat format") + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| fields[i - 3].parse::<f64>().expect("ticks");
    // utime (14) and stime (15) in clock ticks of USER_HZ, 100 on Linux.
    (ticks(14) + ticks(15)) / 100.0
}

fn argument(args: &[String], name: &str, default: f64) -> f64 {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(|v| v.parse().unwrap_or_else(|_| panic!("{name}: a number, not {v:?}")))
        .unwrap_or(default)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (rate, seconds) = (argument(&args, "--rate", 100.0), argument(&args, "--seconds", 10.0));
    if let Ok(port) = std::env::var(ROBOT_ENV) {
        robot(port.parse().expect("port"), rate, seconds);
        return;
    }
    let port = TcpListener::bind("127.0.0.1:0").expect("a free port").local_addr().expect("port").port();
    let mut child = Command::new(std::env::current_exe().expect("this binary"))
        .args(["--rate", &rate.to_string(), "--seconds", &seconds.to_string()])
        .env(ROBOT_ENV, port.to_string())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start the robot");
    // The robot listens once its session is open; the client retries until then.
    std::thread::sleep(Duration::from_secs(1));

    let config = Ros2Config {
        connect: vec![format!("tcp/127.0.0.1:{port}")],
        key_style: "bridge".to_owned(),
        ..Ros2Config::default()
    };
    let (poses_tx, poses_rx) = crossbeam_channel::bounded(4096);
    let (ready_tx, ready_rx) = crossbeam_channel::bounded(1);
    let (_gate, gate_alive) = crossbeam_channel::bounded::<()>(0);
    let stop = Arc::new(AtomicBool::new(false));
    let counters = Arc::new(TfInputCounters::default());
    let thread = TfInputThread {
        config,
        world_frame: "map".to_owned(),
        camera_from_upright: Isometry::IDENTITY,
        buffer: TfConfig::default(),
        poses: poses_tx,
        pose_stats: Arc::new(PoseStats::default()),
        counters: counters.clone(),
        stop: stop.clone(),
        gate_alive,
        ready: ready_tx,
    };
    let tf_thread =
        std::thread::Builder::new().name("op3dsg-ros2-tf".into()).spawn(move || thread.run()).expect("spawn");
    ready_rx.recv().expect("ready").expect("the tf input's session and subscribers");
    // The keyframe gate's stand-in: takes the poses.
    let drain = std::thread::Builder::new()
        .name("keyframe-gate".into())
        .spawn(move || poses_rx.iter().count())
        .expect("spawn the pose drain");

    let mut stdin = child.stdin.take().expect("stdin");
    let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines().map_while(Result::ok);
    // Static transforms fetched before /tf starts.
    let waited = Instant::now();
    while counters.static_messages.load(Ordering::Relaxed) == 0 && waited.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(counters.static_messages.load(Ordering::Relaxed), 1, "the static tree from the robot's cache");
    writeln!(stdin, "go").expect("go");
    assert_eq!(lines.next().as_deref(), Some("publishing"));
    let (cpu0, wall0) = (cpu_s(), Instant::now());
    assert_eq!(lines.next().as_deref(), Some("quiet"));
    let (cpu1, wall1) = (cpu_s(), Instant::now());
    let received = counters.dynamic_messages.load(Ordering::Relaxed);
    let done = lines.next().unwrap_or_default();
    let (cpu2, wall2) = (cpu_s(), Instant::now());
    stop.store(true, Ordering::Relaxed);
    tf_thread.join().expect("tf thread");
    let poses = drain.join().expect("drain");
    let _ = child.wait();

    let busy = (cpu1 - cpu0) / (wall1 - wall0).as_secs_f64();
    let quiet = (cpu2 - cpu1) / (wall2 - wall1).as_secs_f64();
    let sent: u64 = done.trim_start_matches("done ").parse().unwrap_or(0);
    println!(
        "tf input: /tf at {rate} Hz, 30 transforms per message, a 200-frame tree, bridge keys, loopback TCP (Zenoh client)"
    );
    println!("  /tf messages sent {sent}, received {received}; poses handed on {poses}");
    println!("  CPU while /tf arrives: {:.2} % of one core ({:.1} s)", busy * 100.0, (wall1 - wall0).as_secs_f64());
    println!("  CPU with /tf quiet:    {:.2} % of one core ({:.1} s)", quiet * 100.0, (wall2 - wall1).as_secs_f64());
    println!(
        "  the subscription's cost: {:.2} % of one core, {:.0} us per message",
        (busy - quiet) * 100.0,
        (busy - quiet) / rate * 1e6
    );
}
