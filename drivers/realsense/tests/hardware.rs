//! Tests on a real camera: `#[ignore]`d (CI has none), built with the feature. On the robot:
//!
//! ```sh
//! PKG_CONFIG_PATH=... cargo test -p op3dsg-realsense --features librealsense --test hardware -- --ignored --nocapture --test-threads 1
//! ```
//!
//! They read `[source.realsense]` of `profiles/stretch3-d435i.toml` (another file with
//! `OP3DSG_REALSENSE_PROFILE=path`). `reconnect_after_unplug_and_replug` asks for the cable to
//! be pulled and put back (it waits 60 s for each).
#![cfg(feature = "librealsense")]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use op3dsg_realsense::{RealsenseConfig, RealsenseSource};

fn profile_path() -> PathBuf {
    std::env::var_os("OP3DSG_REALSENSE_PROFILE")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../profiles/stretch3-d435i.toml"))
}

fn config() -> RealsenseConfig {
    let path = profile_path();
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let table: toml::Table = toml::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let section =
        table.get("source").and_then(|s| s.get("realsense")).cloned().unwrap_or(toml::Value::Table(toml::Table::new()));
    let config: RealsenseConfig =
        section.try_into().unwrap_or_else(|e| panic!("{}: [source.realsense]: {e}", path.display()));
    assert!(!config.is_playback(), "{}: sets source.realsense.bag; the hardware tests need a camera", path.display());
    config
}

fn host_now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).expect("clock after 1970").as_nanos() as u64
}

/// Frames delivered within `window`, with their stamps.
fn collect(source: &mut RealsenseSource, window: Duration) -> Vec<(u64, f32)> {
    let mut frame = Frame::new(source.intrinsics());
    let mut out = Vec::new();
    let end = Instant::now() + window;
    while Instant::now() < end {
        if source.next_frame(&mut frame).expect("next_frame") == SourceStatus::Frame {
            let valid = frame.depth.iter().filter(|d| **d > 0).count() as f32 / frame.depth.len() as f32;
            out.push((frame.stamp_ns, valid));
        }
    }
    out
}

#[test]
#[ignore = "needs a RealSense camera"]
fn camera_is_present_and_streams_at_the_profile_rate() {
    let config = config();
    let mut source = RealsenseSource::open(&config, None).expect("open the camera");
    let k = source.intrinsics();
    let camera = source.camera_intrinsics();
    println!("{}: camera intrinsics {camera:?}, delivered {k:?}", source.describe());
    assert_eq!(
        (camera.width, camera.height),
        (config.colour.width, config.colour.height),
        "colour mode of the profile (USB 2 fallback?)"
    );
    assert_eq!(k, config.rotate.intrinsics(&camera));
    assert!(camera.fx > 100.0 && camera.fy > 100.0, "a factory calibration");
    // Warm-up, then 5 s.
    collect(&mut source, Duration::from_secs(2));
    let window = Duration::from_secs(5);
    let frames = collect(&mut source, window);
    let rate = frames.len() as f64 / window.as_secs_f64();
    let fps = f64::from(config.colour.fps);
    println!("{} frames in {window:?}: {rate:.1} Hz (profile {fps} Hz)", frames.len());
    assert!((rate - fps).abs() <= 0.15 * fps, "frame rate {rate:.1} Hz, profile {fps} Hz");
    // Stamps in the host clock (global time): increasing, about a period apart, near now.
    assert!(frames.windows(2).all(|w| w[0].0 < w[1].0), "stamps increase");
    let now = host_now_ns();
    let last = frames.last().expect("frames").0;
    assert!(now.abs_diff(last) < 1_000_000_000, "last stamp {last} ns vs host clock {now} ns: not global time?");
    // Depth present on most of the image (point the camera at a room, not the sky).
    let valid = frames.iter().map(|f| f.1).sum::<f32>() / frames.len() as f32;
    println!("valid depth: {:.0} % of pixels", valid * 100.0);
    assert!(valid > 0.2, "only {:.0} % of pixels have depth", valid * 100.0);
}

#[test]
#[ignore = "needs a RealSense camera and someone to unplug it"]
fn reconnect_after_unplug_and_replug() {
    let mut source = RealsenseSource::open(&config(), None).expect("open the camera");
    let mut frame = Frame::new(source.intrinsics());
    assert!(!collect(&mut source, Duration::from_secs(2)).is_empty(), "frames before the unplug");
    println!(">>> unplug the camera now (60 s)");
    let deadline = Instant::now() + Duration::from_secs(60);
    while source.connected() {
        assert!(Instant::now() < deadline, "the camera was not seen unplugged within 60 s");
        let _ = source.next_frame(&mut frame);
    }
    println!("seen unplugged; >>> plug it back in (60 s)");
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        assert!(Instant::now() < deadline, "no frame within 60 s of waiting for the replug");
        match source.next_frame(&mut frame) {
            Ok(SourceStatus::Frame) => break,
            Ok(_) => {}
            Err(e) => println!("while reconnecting: {e}"),
        }
    }
    assert!(source.connected());
    assert_eq!(frame.intrinsics, source.intrinsics(), "same frames as before the unplug");
    println!("reconnected: frame {} at {} ns", frame.seq, frame.stamp_ns);
}
