//! A stand-in navigation stack for the cross-process pose tests: it knows the synthetic robot's
//! true path (the synthetic source's camera path for a room and seed) and sends it to `op3dsgd`
//! as a navigation stack would, through the client library's `PosePublisher`, at a lower rate than
//! the camera: poses stamped every `1 / --pose-rate-hz` seconds of scene time, each sent once the
//! daemon's frames (read from `<prefix>/health`) have reached its stamp plus `--lead-ms`.
//!
//! ```text
//! op3dsg-test-nav --prefix P [--room kitchen] [--seed 1] [--frame-rate-hz 30] [--pose-rate-hz 10]
//!                 [--lead-ms 0]
//! op3dsg-test-nav --interpolation-bound --frames N [--room ...]   # prints the bound, exits
//! ```
//!
//! Lines on standard input inject faults, each answered with `ok <line>` on standard output once
//! sent: `future` (one pose 100 s ahead of the newest frame), `nan N` (N poses with a NaN
//! translation, written with a raw iceoryx2 publisher because the client library refuses them),
//! `out_of_order N` (N poses stamped before the last good one), `pause`, `resume`, `quit`.
//! Standard input closing also quits.
//!
//! `--interpolation-bound` prints `translation_m <e_t> rotation_rad <e_r>`: an upper estimate of
//! what interpolating the 10 Hz poses can be off the true path at a 30 Hz frame, from the path's
//! own second differences (`h^2 / 8` times the largest linear and angular acceleration over the
//! first N frames, with a factor 2 of margin), independent of the daemon's interpolation code.

use std::io::BufRead;
use std::ops::ControlFlow;
use std::time::{Duration, Instant};

use op3dsg_ipc_types::iceoryx2::prelude::{NodeBuilder, ServiceName};
use op3dsg_ipc_types::services::IpcService;
use op3dsg_ipc_types::{
    HealthSubscriber, Pose, PoseError, PoseKind, PosePublisher, PoseStamped, ServiceKind, check_pose,
};
use op3dsg_synthetic::{CameraPath, RoomKind, SyntheticConfig, SyntheticSource};

struct Args {
    prefix: String,
    room: RoomKind,
    seed: u64,
    frame_rate_hz: f64,
    pose_rate_hz: f64,
    lead_ns: u64,
    bound_frames: Option<u64>,
}

fn parse_args() -> Result<Args, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |flag: &str| args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).cloned();
    let number = |flag: &str, default: f64| -> Result<f64, String> {
        value(flag).map_or(Ok(default), |v| v.parse().map_err(|e| format!("{flag} {v}: {e}")))
    };
    let room_name = value("--room").unwrap_or_else(|| "kitchen".to_owned());
    let room = RoomKind::parse(&room_name).ok_or_else(|| format!("--room {room_name}: unknown room"))?;
    let bound_frames =
        if args.iter().any(|a| a == "--interpolation-bound") { Some(number("--frames", 300.0)? as u64) } else { None };
    let prefix = value("--prefix");
    if prefix.is_none() && bound_frames.is_none() {
        return Err("--prefix is required".to_owned());
    }
    Ok(Args {
        prefix: prefix.unwrap_or_default(),
        room,
        seed: number("--seed", 1.0)? as u64,
        frame_rate_hz: number("--frame-rate-hz", 30.0)?,
        pose_rate_hz: number("--pose-rate-hz", 10.0)?,
        lead_ns: (number("--lead-ms", 0.0)? * 1e6) as u64,
        bound_frames,
    })
}

/// The synthetic source's stamp of frame `k` (`drivers/synthetic/src/source.rs`).
fn frame_stamp_ns(k: u64, frame_rate_hz: f64) -> u64 {
    (k as f64 * 1e9 / frame_rate_hz) as u64
}

fn pose_of(path: &CameraPath, k: u64) -> Pose {
    let p = path.pose_at(k);
    Pose::new(p.translation.to_array(), p.rotation.to_array())
}

/// See the module docs.
fn interpolation_bound(path: &CameraPath, frames: u64, frame_rate_hz: f64, pose_rate_hz: f64) -> (f64, f64) {
    let dt = 1.0 / frame_rate_hz;
    let h = 1.0 / pose_rate_hz;
    let (mut accel, mut angular_accel) = (0.0f64, 0.0f64);
    for k in 1..frames.max(3) - 1 {
        let (a, b, c) = (path.pose_at(k - 1), path.pose_at(k), path.pose_at(k + 1));
        let second = a.translation - 2.0 * b.translation + c.translation;
        accel = accel.max(second.length() / (dt * dt));
        // Angular velocity over each step as a rotation vector (the short way round: q and -q are
        // the same rotation); its change is the acceleration.
        let (mut q1, mut q2) = (b.rotation * a.rotation.inverse(), c.rotation * b.rotation.inverse());
        if q1.w < 0.0 {
            q1 = -q1;
        }
        if q2.w < 0.0 {
            q2 = -q2;
        }
        let (w1, w2) = (q1.to_scaled_axis(), q2.to_scaled_axis());
        angular_accel = angular_accel.max((w2 - w1).length() / (dt * dt));
    }
    let margin = 2.0;
    (margin * h * h / 8.0 * accel, margin * h * h / 8.0 * angular_accel)
}

fn main() {
    if let Err(e) = run() {
        eprintln!("op3dsg-test-nav: {e}");
        std::process::exit(2);
    }
}

fn run() -> Result<(), String> {
    let args = parse_args()?;
    let config = SyntheticConfig {
        room: args.room,
        seed: args.seed,
        frame_rate_hz: args.frame_rate_hz,
        ..SyntheticConfig::default()
    };
    let source = SyntheticSource::new(&config).map_err(|e| e.to_string())?;
    let path = source.path();
    if let Some(frames) = args.bound_frames {
        let (e_t, e_r) = interpolation_bound(path, frames, args.frame_rate_hz, args.pose_rate_hz);
        println!("translation_m {e_t} rotation_rad {e_r}");
        return Ok(());
    }
    let frames_per_pose = frames_per_pose(&args)?;

    op3dsg_ipc_types::iceoryx2::prelude::set_log_level_from_env_or(
        op3dsg_ipc_types::iceoryx2::prelude::LogLevel::Error,
    );
    let poses = PosePublisher::open(&args.prefix, "op3dsg-test-nav").map_err(|e| e.to_string())?;
    let mut health = HealthSubscriber::open_wait(&args.prefix, "op3dsg-test-nav-health", Duration::from_secs(60))
        .map_err(|e| e.to_string())?;
    let raw = RawPoses::new(&args.prefix)?;
    let lines = stdin_lines()?;

    let mut nav = Nav {
        poses,
        raw,
        path,
        frame_rate_hz: args.frame_rate_hz,
        lead_ns: args.lead_ns,
        frames_per_pose,
        next_pose: 0,
        last_good_ns: 0,
        newest_frame_ns: None,
        paused: false,
        sent: 0,
    };
    let started = Instant::now();
    loop {
        if let Ok(Some(h)) = health.latest()
            && h.frames_captured > 0
        {
            nav.newest_frame_ns = Some(frame_stamp_ns(h.frames_captured - 1, args.frame_rate_hz));
        }
        nav.send_due_poses()?;
        match lines.try_recv() {
            Ok(line) => {
                if nav.command(&line)?.is_break() {
                    break;
                }
                println!("ok {line}");
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => std::thread::sleep(Duration::from_millis(5)),
            Err(std::sync::mpsc::TryRecvError::Disconnected) => break,
        }
    }
    eprintln!("op3dsg-test-nav: {} good poses in {:.1} s", nav.sent, started.elapsed().as_secs_f64());
    Ok(())
}

/// Frames of the path between two poses: `--frame-rate-hz` over `--pose-rate-hz`, which must be
/// a whole number (poses at frame stamps of the path).
fn frames_per_pose(args: &Args) -> Result<u64, String> {
    let ratio = args.frame_rate_hz / args.pose_rate_hz;
    if (ratio - ratio.round()).abs() > 1e-9 || ratio < 1.0 {
        return Err(format!(
            "--pose-rate-hz {} must divide --frame-rate-hz {} (poses at frame stamps of the path)",
            args.pose_rate_hz, args.frame_rate_hz
        ));
    }
    Ok(ratio.round() as u64)
}

/// The lines of standard input, read on a thread of their own; the channel closes with it.
fn stdin_lines() -> Result<std::sync::mpsc::Receiver<String>, String> {
    let (lines_tx, lines_rx) = std::sync::mpsc::channel::<String>();
    std::thread::Builder::new()
        .name("test-nav-stdin".to_owned())
        .spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if lines_tx.send(line).is_err() {
                    break;
                }
            }
        })
        .map_err(|e| e.to_string())?;
    Ok(lines_rx)
}

/// The stand-in navigation stack: the true path, sent as poses, and the faults it injects.
struct Nav<'a> {
    poses: PosePublisher,
    raw: RawPoses,
    path: &'a CameraPath,
    frame_rate_hz: f64,
    lead_ns: u64,
    frames_per_pose: u64,
    /// Index j of the next pose: the pose at frame j * frames_per_pose.
    next_pose: u64,
    /// Stamp of the last pose of the path sent.
    last_good_ns: u64,
    /// Stamp of the daemon's newest frame (`None`: no frame yet).
    newest_frame_ns: Option<u64>,
    paused: bool,
    /// Poses of the path sent.
    sent: u64,
}

impl Nav<'_> {
    /// Sends the path's poses up to the newest frame's stamp plus the lead, unless paused.
    fn send_due_poses(&mut self) -> Result<(), String> {
        let Some(frame_ns) = self.newest_frame_ns else { return Ok(()) };
        if self.paused {
            return Ok(());
        }
        loop {
            let k = self.next_pose * self.frames_per_pose;
            let stamp_ns = frame_stamp_ns(k, self.frame_rate_hz);
            if stamp_ns > frame_ns + self.lead_ns {
                return Ok(());
            }
            self.publish(stamp_ns, k)?;
            self.last_good_ns = stamp_ns;
            self.next_pose += 1;
            self.sent += 1;
        }
    }

    /// Publishes the path's pose at frame `k`, stamped `stamp_ns`, through the client library.
    fn publish(&self, stamp_ns: u64, k: u64) -> Result<(), String> {
        self.poses
            .publish(stamp_ns, PoseKind::WorldFromCamera, &pose_of(self.path, k), "camera_color_optical_frame")
            .map(|_| ())
            .map_err(|e| e.to_string())
    }

    /// Carries out one line of standard input (see the module docs); `Break` on `quit`.
    fn command(&mut self, line: &str) -> Result<ControlFlow<()>, String> {
        let mut words = line.split_whitespace();
        let command = words.next().unwrap_or("");
        let count: u64 = words.next().and_then(|w| w.parse().ok()).unwrap_or(1);
        match command {
            "future" => self.publish(self.newest_frame_ns.unwrap_or(0) + 100_000_000_000, 0)?,
            "nan" => self.send_nan(count)?,
            "out_of_order" => {
                for i in 0..count {
                    self.publish(self.last_good_ns.saturating_sub(50_000_000 + i * 1_000_000), 0)?;
                }
            }
            "pause" => self.paused = true,
            "resume" => self.paused = false,
            "quit" => return Ok(ControlFlow::Break(())),
            other => return Err(format!("unknown command {other:?}")),
        }
        Ok(ControlFlow::Continue(()))
    }

    /// Sends `count` poses with a NaN translation past the client library (which must refuse
    /// them), stamped just after the last good pose.
    fn send_nan(&self, count: u64) -> Result<(), String> {
        for i in 0..count {
            let mut pose = PoseStamped::new(
                self.last_good_ns + 1 + i,
                PoseKind::WorldFromCamera,
                [0.0; 3],
                [0.0, 0.0, 0.0, 1.0],
                "camera_color_optical_frame",
            )
            .map_err(|e| e.to_string())?;
            pose.translation_m[0] = f64::NAN;
            // The client library refuses to send it, naming the reason.
            match self.poses.publish_stamped(&pose) {
                Err(e) if matches!(check_pose(&pose), Err(PoseError::NonFiniteTranslation { .. })) => {
                    eprintln!("op3dsg-test-nav: the client refuses it: {e}");
                }
                other => return Err(format!("the client library sent a NaN pose: {other:?}")),
            }
            self.raw.send(pose)?;
        }
        Ok(())
    }
}

/// A publisher on `<prefix>/pose` without the client library's checks, for the poses a broken
/// navigation stack would send.
struct RawPoses {
    publisher: op3dsg_ipc_types::iceoryx2::port::publisher::Publisher<IpcService, PoseStamped, ()>,
    _service:
        op3dsg_ipc_types::iceoryx2::service::port_factory::publish_subscribe::PortFactory<IpcService, PoseStamped, ()>,
    _node: op3dsg_ipc_types::iceoryx2::node::Node<IpcService>,
}

impl RawPoses {
    fn new(prefix: &str) -> Result<Self, String> {
        let node = NodeBuilder::new()
            .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
            .create::<IpcService>()
            .map_err(|e| format!("raw node: {e:?}"))?;
        let name = ServiceName::new(&ServiceKind::Pose.name(prefix)).map_err(|e| format!("service name: {e:?}"))?;
        let service = node
            .service_builder(&name)
            .publish_subscribe::<PoseStamped>()
            .open()
            .map_err(|e| format!("open {prefix}/pose: {e:?}"))?;
        let publisher = service.publisher_builder().create().map_err(|e| format!("raw publisher: {e:?}"))?;
        Ok(Self { publisher, _service: service, _node: node })
    }

    fn send(&self, pose: PoseStamped) -> Result<(), String> {
        self.publisher.send_copy(pose).map(|_| ()).map_err(|e| format!("raw send: {e:?}"))
    }
}
