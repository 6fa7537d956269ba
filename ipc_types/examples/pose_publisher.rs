//! A stand-in navigation stack: sends `world_from_base` at 10 Hz for a base driving a 1 m circle
//! (facing along it), stamped with the wall clock.
//!
//! The wall clock is the camera source's clock (librealsense global time), so this suits a daemon
//! on the camera with `pose.source = "ipc"` and a `pose.base_from_camera`. The built-in synthetic
//! source stamps frames with scene time from 0 instead: there the daemon refuses these poses as
//! `future` and warns that the clocks differ.
//!
//! `cargo run -p op3dsg-ipc-types --example pose_publisher -- [--prefix P] [--seconds S]`
//! The prefix is `--prefix`, else `$OP3DSG_PREFIX`, else `op3dsg`; `--seconds` defaults to 10.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use op3dsg_ipc_types::iceoryx2;
use op3dsg_ipc_types::services::DEFAULT_PREFIX;
use op3dsg_ipc_types::{Pose, PoseKind, PosePublisher};

const RATE_HZ: u32 = 10;
const RADIUS_M: f64 = 1.0;
/// One lap every 20 s.
const ANGULAR_SPEED_RAD_PER_S: f64 = std::f64::consts::TAU / 20.0;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |flag: &str| args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).cloned();
    let prefix =
        arg("--prefix").or_else(|| std::env::var("OP3DSG_PREFIX").ok()).unwrap_or_else(|| DEFAULT_PREFIX.to_owned());
    let seconds: f64 = arg("--seconds").map(|s| s.parse()).transpose()?.unwrap_or(10.0);

    // iceoryx2 warns at start when it finds no config file and uses its defaults (fine here).
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    // Works before the daemon starts; poses sent while nobody listens are lost.
    let poses = PosePublisher::open(&prefix, "op3dsg-example-nav")?;
    let period = Duration::from_secs(1) / RATE_HZ;
    let start = Instant::now();
    let mut next_tick = start;
    while start.elapsed().as_secs_f64() < seconds {
        let angle_rad = start.elapsed().as_secs_f64() * ANGULAR_SPEED_RAD_PER_S;
        let translation_m = [RADIUS_M * angle_rad.cos(), RADIUS_M * angle_rad.sin(), 0.0];
        let world_from_base = Pose::from_translation_yaw(translation_m, angle_rad + std::f64::consts::FRAC_PI_2);
        let stamp_ns = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64);
        let reached = poses.publish(stamp_ns, PoseKind::WorldFromBase, &world_from_base, "base_link")?;
        println!("stamp_ns {stamp_ns} x {:.3} y {:.3} m, subscribers {reached}", translation_m[0], translation_m[1]);
        next_tick += period;
        std::thread::sleep(next_tick.saturating_duration_since(Instant::now()));
    }
    Ok(())
}
